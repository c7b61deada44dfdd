"""Tests for torch_modulo/tonemap/gamma.py: exposure and gamma per channel.

colour-hdri (test-only dependency; tests skip without it) gives ``tonemapping_operator_gamma``; agreement within
1e-4 absolute (float32) / 1e-6 (float64).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tonemap_cases import hdr as _hdr

import torch_modulo.tonemap as tmo
from torch_modulo.tonemap import (
    GammaToneMap,
    tonemap_gamma,
)


class TestGamma:
    def test_unit_hand_computed(self, device: torch.device, dtype: torch.dtype) -> None:
        x = torch.tensor([[0.0, 0.25], [1.0, 8.0]], device=device, dtype=dtype)
        assert tonemap_gamma(x, gamma=2.0).cpu().tolist() == [[0.0, 0.5], [1.0, 1.0]]
        assert torch.allclose(
            tonemap_gamma(x, 2.0, exposure=-2.0).cpu(), torch.tensor([[0.0, 0.25], [0.5, 1.0]], dtype=dtype)
        )
        # percentile=100: the maximum luminance (8) reaches 1.
        auto = tonemap_gamma(x, gamma=1.0, percentile=100.0).cpu()
        assert torch.allclose(auto, torch.tensor([[0.0, 1 / 32], [1 / 8, 1.0]], dtype=dtype))

    def test_percentile_is_per_image(self) -> None:
        x = _hdr((1, 3, 10, 10), seed=51)
        x = torch.cat([x, x * 1000.0])
        out = tonemap_gamma(x, gamma=1.0, percentile=50.0)
        assert torch.allclose(out[0], out[1], atol=1e-12)
        assert float((tmo.luminance(out) >= 1.0 - 1e-12).double().mean()) <= 0.51

    def test_matches_colour_hdri(self) -> None:
        colour_hdri = pytest.importorskip("colour_hdri")
        x = _hdr((1, 3, 12, 14), seed=52, stops=10)
        for gamma, ev in [(2.2, -3.0), (1.0, 0.0), (1.8, -1.5)]:
            ref = np.clip(colour_hdri.tonemapping_operator_gamma(x[0].numpy().transpose(1, 2, 0), gamma, ev), 0, 1)
            out = tonemap_gamma(x, gamma, ev)[0].numpy().transpose(1, 2, 0)
            assert np.abs(out - ref).max() < 1e-9
            out32 = tonemap_gamma(x.float(), gamma, ev)[0].double().numpy().transpose(1, 2, 0)
            assert np.abs(out32 - ref).max() < 1e-4

    def test_gradcheck(self) -> None:
        x = torch.rand(1, 3, 4, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(53)) * 0.9 + 0.05
        x.requires_grad_(True)
        assert torch.autograd.gradcheck(lambda v: tonemap_gamma(v, 2.2), (x,))
        assert torch.autograd.gradcheck(lambda v: tonemap_gamma(v, 2.2, percentile=100.0), (x,))

    def test_module_equals_function(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _hdr((2, 3, 9, 8), seed=54, dtype=dtype).to(device)
        module = GammaToneMap(gamma=1.8, exposure=-1.0, percentile=95.0)
        assert torch.equal(module(x), tonemap_gamma(x, 1.8, -1.0, percentile=95.0))
        assert "percentile=95.0" in repr(module)

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"gamma": 0.0}, ValueError, "gamma must be a positive finite number; got 0.0"),
            ({"exposure": float("inf")}, ValueError, "exposure must be finite; got inf"),
            ({"percentile": 0.0}, ValueError, "percentile must be in \\(0, 100\\]; got 0.0"),
            ({"percentile": 101}, ValueError, "percentile must be in \\(0, 100\\]; got 101"),
            ({"exposure": None}, TypeError, "exposure must be a number; got None"),
        ],
    )
    def test_bad_arguments(self, kwargs: dict, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            GammaToneMap(**kwargs)
        with pytest.raises(error, match=match):
            tonemap_gamma(torch.ones(1, 3, 4, 4), **kwargs)


class TestGammaExposureRange:
    """Regression: ``exposure=2000`` raised a bare OverflowError, and ``exposure=200`` on float32 a RuntimeError."""

    @pytest.mark.parametrize("exposure", [2000.0, -2000.0, 1024.0])
    def test_exposure_beyond_float64_names_the_value(self, exposure: float) -> None:
        match = rf"exposure must be within \[-1022, 1023\] stops; got {exposure}"
        with pytest.raises(ValueError, match=match):
            tonemap_gamma(torch.ones(1, 3, 4, 4), exposure=exposure)
        with pytest.raises(ValueError, match=match):
            GammaToneMap(exposure=exposure)

    @pytest.mark.parametrize("precision", [torch.float16, torch.float32, torch.float64])
    @pytest.mark.parametrize("percentile", [None, 50.0])
    def test_exposure_beyond_the_dtype_clips_finitely(self, precision: torch.dtype, percentile: float | None) -> None:
        x = torch.tensor([[0.0, 1e-3, 1.0, 5.0]], dtype=precision)
        up = tonemap_gamma(x, exposure=1000.0, percentile=percentile)
        assert up.dtype == precision and up.tolist() == [[0.0, 1.0, 1.0, 1.0]]
        down = tonemap_gamma(x, exposure=-1000.0, percentile=percentile)
        assert torch.isfinite(down).all() and float(down[0, 0]) == 0.0 and float(down.max()) < 1e-100
        grad = tonemap_gamma(x.clone().requires_grad_(True), exposure=1000.0, percentile=percentile)
        assert torch.equal(grad.detach(), up)


@pytest.mark.parametrize("half", [torch.float16, torch.bfloat16])
def test_dim_half_precision_radiance_reaches_white(half: torch.dtype) -> None:
    # The scale of dim radiance (2**17 for 2**-17) is beyond float16's range: the mapping works in float32.
    dim = torch.full((1, 1, 2, 2), 2.0**-17, dtype=half)
    assert torch.equal(tmo.tonemap_gamma(dim, gamma=1.0, exposure=17), torch.ones_like(dim))
    ramp = torch.linspace(0, 1.1e-5, 16).reshape(1, 1, 4, 4).to(half)
    out = tmo.tonemap_gamma(ramp, gamma=1.0, percentile=100)
    assert out.dtype == half and float(out.max()) == 1.0
