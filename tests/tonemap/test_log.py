"""Tests for torch_modulo/tonemap/log.py: logarithmic mapping of luminance.

colour-hdri (test-only dependency; tests skip without it) gives ``tonemapping_operator_logarithmic``; it computes
luminance from the sRGB primaries (0.21264, 0.71517, 0.07219), which differs from the rounded Rec.709 weights at
1e-5.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from tonemap_cases import hdr as _hdr

from torch_modulo.tonemap import (
    LogToneMap,
    tonemap_log,
)


class TestLog:
    def test_unit_hand_computed(self, device: torch.device, dtype: torch.dtype) -> None:
        x = torch.tensor([[0.0, 1.0], [3.0, 15.0]], device=device, dtype=dtype)
        assert torch.allclose(tonemap_log(x).cpu(), torch.tensor([[0.0, 0.25], [0.5, 1.0]], dtype=dtype))
        # exposure +1 doubles L: log(1 + 2x) / log(31).
        expected = torch.log1p(2 * x.cpu().double()) / math.log(31.0)
        assert torch.allclose(tonemap_log(x, exposure=1.0).cpu().double(), expected, atol=1e-6)
        # q = 3, k = 1: log(1 + 3x) / log(16), clipped at 1.
        expected = (torch.log1p(3 * x.cpu().double()) / math.log(16.0)).clamp(max=1.0)
        assert torch.allclose(tonemap_log(x, q=3.0).cpu().double(), expected, atol=1e-6)

    def test_matches_colour_hdri(self) -> None:
        colour_hdri = pytest.importorskip("colour_hdri")
        x = _hdr((1, 3, 12, 14), seed=61, stops=14) * 10
        for q, k in [(1.0, 1.0), (1.0, 4.0), (2.0, 8.0)]:
            ref = colour_hdri.tonemapping_operator_logarithmic(x[0].numpy().transpose(1, 2, 0), q, k)
            ref = np.clip(ref, 0, 1)
            out = tonemap_log(x, q, k)[0].numpy().transpose(1, 2, 0)
            assert np.abs(out - ref).max() < 1e-4  # luminance weights differ at 1e-5
            out32 = tonemap_log(x.float(), q, k)[0].double().numpy().transpose(1, 2, 0)
            assert np.abs(out32 - ref).max() < 2e-4

    def test_gradcheck(self) -> None:
        x = _hdr((1, 3, 4, 4), seed=62, stops=10).requires_grad_(True)
        assert torch.autograd.gradcheck(lambda v: tonemap_log(v, q=1.0, k=2.0, exposure=1.0), (x,))

    def test_module_equals_function(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _hdr((2, 3, 9, 8), seed=63, dtype=dtype).to(device)
        module = LogToneMap(q=2.0, k=3.0, exposure=-2.0)
        assert torch.equal(module(x), tonemap_log(x, 2.0, 3.0, -2.0))
        assert "q=2.0" in repr(module)

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"q": 0.0}, ValueError, "q must be a positive finite number; got 0.0"),
            ({"k": -2}, ValueError, "k must be a positive finite number; got -2"),
            ({"exposure": float("nan")}, ValueError, "exposure must be finite; got nan"),
            ({"q": True}, TypeError, "q must be a number; got True"),
        ],
    )
    def test_bad_arguments(self, kwargs: dict, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            LogToneMap(**kwargs)
        with pytest.raises(error, match=match):
            tonemap_log(torch.ones(1, 3, 4, 4), **kwargs)


class TestLogExposureRange:
    """Regression: ``exposure=2000`` raised a bare OverflowError; scales beyond float32 gave NaN or black."""

    @pytest.mark.parametrize("exposure", [2000.0, -2000.0])
    def test_exposure_beyond_float64_names_the_value(self, exposure: float) -> None:
        match = rf"exposure must be within \[-1022, 1023\] stops; got {exposure}"
        with pytest.raises(ValueError, match=match):
            tonemap_log(torch.ones(1, 3, 4, 4), exposure=exposure)
        with pytest.raises(ValueError, match=match):
            LogToneMap(exposure=exposure)

    def test_scaled_steepness_beyond_float64_names_it(self) -> None:
        with pytest.raises(ValueError, match=r"q \* 2\*\*exposure = 1e\+20 \* 2\*\*1023.0 is beyond float64"):
            tonemap_log(torch.ones(1, 3, 4, 4), q=1e20, exposure=1023.0)

    @pytest.mark.parametrize("exposure", [-1000.0, -200.0, 0.0, 200.0, 1000.0])
    @pytest.mark.parametrize("grad", [False, True])
    def test_float32_matches_float64_at_any_exposure(self, exposure: float, grad: bool) -> None:
        x = torch.tensor([[[[0.0, 1e-30, 1.0, 5.0, 1e30]]]]).expand(1, 3, 1, 5).contiguous()
        want = tonemap_log(x.double(), exposure=exposure).float()
        got = tonemap_log(x.clone().requires_grad_(grad), exposure=exposure).detach()
        assert got.dtype == torch.float32 and torch.isfinite(got).all()
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-7)


def test_batch_equals_images_when_one_needs_float64() -> None:
    a = torch.rand(1, 3, 8, 8) * 100
    b = torch.full((1, 3, 8, 8), 3e38)  # its scaled luminance leaves float32: mapped in float64
    batch = tonemap_log(torch.cat([a, b]), k=4.0)
    assert torch.equal(batch[:1], tonemap_log(a, k=4.0)) and torch.equal(batch[1:], tonemap_log(b, k=4.0))
