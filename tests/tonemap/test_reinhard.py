"""Tests for torch_modulo/tonemap/reinhard.py: Reinhard et al. 2002, global operator.

colour-hdri (test-only dependency; tests skip without it) gives ``log_average`` and
``tonemapping_operator_simple`` for the operator without a white point; the white point (Reinhard's Eq. 4) is
checked against a NumPy reference written here (OpenCV's TonemapReinhard and colour-hdri's Reinhard2004 are a
different operator, Reinhard and Devlin 2005).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tonemap_cases import LUMA
from tonemap_cases import hdr as _hdr

from torch_modulo.tonemap import (
    ReinhardToneMap,
    tonemap_reinhard,
)


def reinhard_reference(rgb: np.ndarray, key: float, white: float | None, delta: float) -> np.ndarray:
    """Reinhard et al. 2002, Eqs. 1, 2 and 4, for one (C, H, W) image."""
    y = rgb[0] if rgb.shape[0] == 1 else np.tensordot(LUMA, rgb, axes=1)
    log_avg = np.exp(np.mean(np.log(delta + y)))
    big_l = key / log_avg * y
    l_white = big_l.max() if white is None else white
    ld = big_l * (1 + big_l / l_white**2) / (1 + big_l)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(y > 0, ld / y, 0.0)
    return np.clip(rgb * ratio, 0, 1)


class TestReinhard:
    def test_unit_hand_computed(self, device: torch.device, dtype: torch.dtype) -> None:
        x = torch.tensor([[1.0, 4.0], [16.0, 64.0]], device=device, dtype=dtype)  # log average 8
        # key 0.5: L = x / 16 = 1/16, 1/4, 1, 4.
        simple = tonemap_reinhard(x, key=0.5, white=float("inf"), delta=1e-12)
        assert torch.allclose(
            simple.cpu().double(), torch.tensor([[1 / 17, 0.2], [0.5, 0.8]], dtype=torch.float64), atol=1e-6
        )
        # white = 2: Ld = L (1 + L / 4) / (1 + L).
        white = tonemap_reinhard(x, key=0.5, white=2.0, delta=1e-12)
        expected = [[65 / (64 * 17), 0.25 * (1 + 1 / 16) / 1.25], [1.25 / 2, 1.0]]
        assert torch.allclose(white.cpu().double(), torch.tensor(expected, dtype=torch.float64), atol=1e-6)
        # white = None: the maximum, L = 4, maps to exactly 1; L = 1 to (1 + 1/16) / 2.
        auto = tonemap_reinhard(x, key=0.5, delta=1e-12)
        assert float(auto[1, 1]) == pytest.approx(1.0, abs=1e-6)
        assert float(auto[1, 0]) == pytest.approx(17 / 32, abs=1e-6)

    @pytest.mark.parametrize("white", [None, 3.0, float("inf")])
    def test_matches_numpy_reference(self, white: float | None) -> None:
        x = _hdr((2, 3, 17, 23), seed=41, stops=18)
        x[0, :, 0, :5] = 0.0
        out = tonemap_reinhard(x, key=0.36, white=white, delta=1e-4)
        for i in range(2):
            assert np.allclose(out[i].numpy(), reinhard_reference(x[i].numpy(), 0.36, white, 1e-4), atol=1e-9)

    def test_matches_colour_hdri_simple_operator(self) -> None:
        colour_hdri = pytest.importorskip("colour_hdri")
        from colour.constants import EPSILON
        from colour_hdri.tonemapping.global_operators.operators import log_average

        grey = _hdr((1, 1, 20, 30), seed=42, stops=14)
        a = 0.18
        scaled = a / log_average(grey.numpy(), EPSILON) * grey.numpy()
        ref = colour_hdri.tonemapping_operator_simple(scaled)
        for dtype, tol in [(torch.float64, 1e-6), (torch.float32, 1e-4)]:
            out = tonemap_reinhard(grey.to(dtype), key=a, white=float("inf"), delta=EPSILON)
            assert np.abs(out.double().numpy() - ref).max() < tol

    def test_gradcheck(self) -> None:
        x = _hdr((1, 3, 4, 5), seed=43, stops=8).requires_grad_(True)
        assert torch.autograd.gradcheck(lambda v: tonemap_reinhard(v, white=5.0), (x,))
        g = _hdr((1, 1, 4, 5), seed=44, stops=8).requires_grad_(True)
        assert torch.autograd.gradcheck(lambda v: tonemap_reinhard(v, key=0.09), (g,))  # through the maximum

    def test_module_equals_function(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _hdr((2, 3, 9, 8), seed=45, dtype=dtype).to(device)
        module = ReinhardToneMap(key=0.36, white=4.0, delta=1e-3)
        assert torch.equal(module(x), tonemap_reinhard(x, 0.36, 4.0, delta=1e-3))
        assert "key=0.36" in repr(module)

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"key": 0.0}, ValueError, "key must be a positive finite number; got 0.0"),
            ({"key": "0.18"}, TypeError, "key must be a number; got '0.18'"),
            ({"white": -1.0}, ValueError, "white must be a positive number; got -1.0"),
            ({"delta": float("nan")}, ValueError, "delta must be a positive finite number; got nan"),
        ],
    )
    def test_bad_arguments(self, kwargs: dict, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            ReinhardToneMap(**kwargs)
        with pytest.raises(error, match=match):
            tonemap_reinhard(torch.ones(1, 3, 4, 4), **kwargs)


class TestReinhardPrecision:
    """Regression: dim half-precision input came out white (or NaN), and so did float32 at tiny scales.

    The chunked path formed ``scale * scale / L_white**2`` in the input's dtype: ``scale**2`` overflowed float16 for
    an image as dim as x 3e-3, and ``1 / y_max**2`` overflowed float32 for one as dim as x 1e-20.
    """

    @pytest.mark.parametrize("grad", [False, True], ids=["chunked", "autograd"])
    @pytest.mark.parametrize(("narrow", "tol"), [(torch.float16, 2e-3), (torch.bfloat16, 8e-3)])
    @pytest.mark.parametrize("scale", [1e-4, 3e-3, 1.0, 100.0])
    def test_half_equals_float32(self, scale: float, narrow: torch.dtype, tol: float, grad: bool) -> None:
        x = (_hdr((2, 3, 24, 40), seed=46, stops=16) * scale).to(narrow)  # 2**-8 .. 2**8 times the scale
        x[0, :, 0, :5] = 0.0
        expected = tonemap_reinhard(x.float())
        out = tonemap_reinhard(x.clone().requires_grad_(grad))
        assert out.dtype == narrow and out.shape == x.shape
        assert torch.isfinite(out).all()
        assert float((out.detach().float() - expected).abs().max()) < tol
        assert float(expected.mean()) < 0.9  # not the degenerate all-white answer

    def test_half_real_scene(self, shared_hdr) -> None:  # noqa: ANN001
        from torch_modulo.io import read_image

        x = read_image(shared_hdr / "polyhaven-cc0" / "apartment.exr")[None].clamp_min(0.0) * 1e-3
        half = x.half()
        out = tonemap_reinhard(half)
        assert out.dtype == torch.float16
        assert float((out.float() - tonemap_reinhard(half.float())).abs().max()) < 2e-3
        assert abs(float(out.float().mean()) - float(tonemap_reinhard(x).mean())) < 2e-3

    @pytest.mark.parametrize("grad", [False, True], ids=["chunked", "autograd"])
    @pytest.mark.parametrize("scale", [1e-20, 1e-30])
    def test_float32_tiny_scale_matches_numpy_reference(self, scale: float, grad: bool) -> None:
        # The default delta (1e-6) dominates the log average of so dim an image: not scale invariant, but defined.
        x = torch.rand((2, 3, 17, 23), generator=torch.Generator().manual_seed(47), dtype=torch.float64) * scale
        x[0, :, 0, :5] = 0.0
        out = tonemap_reinhard(x.float().requires_grad_(grad)).detach()
        assert torch.isfinite(out).all()
        for i in range(2):
            assert np.abs(out[i].double().numpy() - reinhard_reference(x[i].numpy(), 0.18, None, 1e-6)).max() < 1e-5

    @pytest.mark.parametrize("grad", [False, True], ids=["chunked", "autograd"])
    @pytest.mark.parametrize("white", [None, 3.0, float("inf")])
    @pytest.mark.parametrize("scale", [1e-20, 1e-30, 1e20, 1e30])
    def test_float32_invariant_to_scale_with_delta(self, scale: float, white: float | None, grad: bool) -> None:
        # delta is in the input's units: scaling radiance and delta together leaves the output unchanged.
        x = _hdr((2, 3, 17, 23), seed=48, stops=18, dtype=torch.float32)
        x[0, :, 0, :5] = 0.0
        expected = tonemap_reinhard(x, white=white, delta=1e-4)
        out = tonemap_reinhard((x * scale).requires_grad_(grad), white=white, delta=1e-4 * scale).detach()
        assert torch.isfinite(out).all()
        assert float((out - expected).abs().max()) < 1e-5
