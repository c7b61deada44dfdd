"""Tests for torch_modulo/tonemap/clahe.py: CLAHE of log luminance through Kornia."""

from __future__ import annotations

import pytest
import torch
from tonemap_cases import hdr as _hdr

import torch_modulo.tonemap as tmo
from torch_modulo.tonemap import (
    ClaheToneMap,
    tonemap_clahe,
)


class TestClahe:
    def test_unit_equals_kornia_on_normalised_log_luminance(self, device: torch.device, dtype: torch.dtype) -> None:
        import kornia

        x = _hdr((2, 3, 24, 20), seed=71, stops=16, dtype=dtype).to(device)
        y = tmo.luminance(x)
        b = torch.log(y)
        lo = b.amin(dim=(1, 2, 3), keepdim=True)
        hi = b.amax(dim=(1, 2, 3), keepdim=True)
        level = ((b - lo) / (hi - lo)).clamp(0, 1)
        eq = kornia.enhance.equalize_clahe(level, 3.0, (4, 4))
        expected = (x * eq / y).clamp(0, 1)
        assert torch.allclose(tonemap_clahe(x, 3.0, (4, 4)), expected, atol=1e-6)

    def test_global_grid_is_monotonic(self) -> None:
        values = torch.exp2(torch.linspace(-12, 12, 400, dtype=torch.float64))
        x = values[torch.randperm(400, generator=torch.Generator().manual_seed(72))].reshape(1, 1, 20, 20)
        out = tonemap_clahe(x, clip_limit=2.0, grid_size=(1, 1)).flatten()
        assert float(out[torch.argsort(x.flatten())].diff().min()) >= 0.0

    def test_scale_invariant(self) -> None:
        x = _hdr((1, 3, 32, 32), seed=73, stops=16)
        assert torch.allclose(tonemap_clahe(x * 1e3), tonemap_clahe(x), atol=1e-9)

    def test_black_pixels_take_the_equalised_value_as_grey(self) -> None:
        x = _hdr((1, 3, 16, 16), seed=74)
        x[0, :, 2, 3] = 0.0
        out = tonemap_clahe(x, grid_size=(2, 2))
        assert torch.equal(out[0, 0, 2, 3], out[0, 1, 2, 3]) and torch.equal(out[0, 1, 2, 3], out[0, 2, 2, 3])

    def test_differentiable_path(self) -> None:
        x = _hdr((1, 3, 12, 12), seed=75, stops=10).requires_grad_(True)
        out = tonemap_clahe(x, grid_size=(2, 2), differentiable=True)
        out.sum().backward()
        assert x.grad is not None and torch.isfinite(x.grad).all() and float(x.grad.abs().sum()) > 0

    def test_module_equals_function(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _hdr((2, 3, 20, 24), seed=76, dtype=dtype).to(device)
        module = ClaheToneMap(clip_limit=4.0, grid_size=(3, 4), srgb=True)
        assert torch.equal(module(x), tonemap_clahe(x, 4.0, (3, 4), srgb=True))
        assert "grid_size=(3, 4)" in repr(module)

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"clip_limit": -1.0}, ValueError, "clip_limit must be >= 0 \\(0 disables clipping\\); got -1.0"),
            ({"grid_size": (0, 8)}, ValueError, "grid_size\\[0\\] must be >= 1; got 0"),
            ({"grid_size": 8}, TypeError, "grid_size must be a pair of integers \\(rows, columns\\); got 8"),
            ({"differentiable": 1}, TypeError, "differentiable must be a bool; got 1"),
        ],
    )
    def test_bad_arguments(self, kwargs: dict, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            ClaheToneMap(**kwargs)
        with pytest.raises(error, match=match):
            tonemap_clahe(torch.ones(1, 3, 16, 16), **kwargs)

    def test_image_smaller_than_grid(self) -> None:
        with pytest.raises(ValueError, match="larger than grid_size=\\(8, 8\\) along each axis; got 8x20"):
            tonemap_clahe(torch.ones(1, 3, 8, 20))


class TestClaheHalfPrecision:
    """Regression: float16 and bfloat16 input came out up to 105 of 255 display levels away from float64."""

    @pytest.mark.parametrize("precision", [torch.float16, torch.bfloat16])
    @pytest.mark.parametrize("channels", [1, 3])
    def test_half_precision_matches_float64_on_the_same_values(self, precision: torch.dtype, channels: int) -> None:
        x = _hdr((2, channels, 32, 40), seed=90, stops=16).to(precision)
        out = tonemap_clahe(x, grid_size=(2, 2))
        want = tonemap_clahe(x.double(), grid_size=(2, 2))
        assert out.dtype == precision and out.shape == x.shape
        assert float((out.double() - want).abs().max()) * 255 <= 2.0
        module = ClaheToneMap(grid_size=(2, 2))(x)
        assert torch.equal(module, out)
