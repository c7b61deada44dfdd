"""Tests for torch_modulo.metrics: exact-k, PSNR (linear, log, PU21) and tone-mapped SSIM."""

from __future__ import annotations

import math

import kornia
import numpy as np
import pytest
import torch

from torch_modulo.metrics import (
    PSNR,
    PSNRPU21,
    PU21_PARAMETERS,
    ExactKShare,
    PSNRLog,
    PU21Encode,
    SSIMToneMapped,
    exact_k_map,
    exact_k_share,
    log_relative_tonemap,
    psnr,
    psnr_log,
    psnr_pu21,
    pu21_encode,
    ssim_tonemapped,
)

SHAPES = [((5, 6), (1,)), ((3, 5, 6), (1,)), ((2, 3, 5, 6), (2,)), ((1, 1, 1, 1), (1,))]


def _counts(shape: tuple[int, ...], seed: int, high: int = 4096) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randint(0, high, shape, generator=g).double()


def _radiance(shape: tuple[int, ...], seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.exp2(torch.rand(shape, generator=g, dtype=torch.float64) * 12)  # 1 .. 4096, 12 stops


def _exact_k_reference(restored: np.ndarray, truth: np.ndarray, bits: int) -> np.ndarray:
    """Loop reference for (B, C, H, W) arrays: per channel mode of the k difference (smallest on ties)."""
    d = np.floor(restored / 2**bits) - np.floor(truth / 2**bits)
    out = []
    for item in d:
        right = 0
        for channel in item:
            values, counts = np.unique(channel, return_counts=True)
            right += int(np.sum(channel == values[np.argmax(counts)]))
        out.append(right / item.size)
    return np.array(out)


# Published PU21 parameters (Mantiuk and Azimi 2021, authors' reference encoder), typed here independently of the
# module so that a wrong constant there fails the tests.
PUBLISHED_PU21 = {
    "banding": (1.070275272, 0.4088273932, 0.153224308, 0.2520326168, 1.063512885, 1.14115047, 521.4527484),
    "banding_glare": (
        0.353487901,
        0.3734658629,
        8.277049286e-05,
        0.9062562627,
        0.09150303166,
        0.9099517204,
        596.3148142,
    ),
}


def _pu21_reference(y: float, variant: str) -> float:
    """PU21 (Mantiuk and Azimi 2021) straight from the published formula, in Python floats."""
    p1, p2, p3, p4, p5, p6, p7 = PUBLISHED_PU21[variant]
    y = min(max(y, 0.005), 10000.0)
    return max(p7 * (((p1 + p2 * y**p4) / (1 + p3 * y**p4)) ** p5 - p6), 0.0)


class TestExactKShare:
    def test_smoke(self, device: torch.device, dtype: torch.dtype) -> None:
        truth = _counts((2, 3, 8, 8), 0).to(device, dtype)
        out = exact_k_share(truth, truth)
        assert out.shape == (2,)
        assert torch.equal(out, torch.ones(2, device=device, dtype=dtype))

    @pytest.mark.parametrize(("shape", "out_shape"), SHAPES)
    def test_cardinality(self, shape: tuple[int, ...], out_shape: tuple[int, ...]) -> None:
        truth = _counts(shape, 1)
        assert exact_k_share(truth, truth).shape == out_shape
        assert exact_k_map(truth, truth).shape == shape
        assert exact_k_map(truth, truth).dtype == torch.bool

    def test_empty_batch(self) -> None:
        truth = torch.zeros(0, 3, 4, 4)
        assert exact_k_share(truth, truth).shape == (0,)

    def test_one_wrong_k_in_2x2(self) -> None:
        truth = torch.tensor([[10.0, 300.0], [600.0, 20.0]])
        restored = truth.clone()
        restored[1, 0] += 256  # k 2 -> 3
        assert exact_k_share(restored, truth).tolist() == [0.75]
        assert exact_k_map(restored, truth).tolist() == [[True, True], [False, True]]

    def test_modulus_error_within_same_k_counts_as_right(self) -> None:
        truth = torch.tensor([[10.0, 300.0], [600.0, 20.0]])
        restored = torch.tensor([[200.0, 257.0], [767.0, 0.0]])  # same k everywhere, other moduli
        assert exact_k_share(restored, truth).tolist() == [1.0]

    def test_global_offset_is_aligned_per_channel(self) -> None:
        truth = torch.tensor([[[10.0, 300.0], [600.0, 20.0]], [[5.0, 5.0], [900.0, 260.0]]])
        restored = truth.clone()
        restored[0] += 512  # channel 0 two rollovers high
        restored[1] += 256  # channel 1 one rollover high
        restored[0, 0, 1] += 256  # and one value of channel 0 wrong on top
        assert exact_k_share(restored, truth).tolist() == [7 / 8]
        assert exact_k_share(restored, truth, align=False).tolist() == [0.0]
        assert exact_k_share(truth, truth, align=False).tolist() == [1.0]

    def test_offset_mode_not_mean(self) -> None:
        # differences 0, 0, 0, 5: mode 0, mean 1.25: three right
        truth = torch.zeros(2, 2)
        restored = torch.tensor([[0.0, 0.0], [0.0, 5 * 256.0]])
        assert exact_k_share(restored, truth).tolist() == [0.75]

    def test_tie_picks_smallest_difference(self) -> None:
        truth = torch.zeros(1, 4)
        restored = torch.tensor([[3 * 256.0, 256.0, 3 * 256.0, 256.0]])  # d = 3, 1, 3, 1
        assert exact_k_map(restored, truth).tolist() == [[False, True, False, True]]

    def test_bits(self) -> None:
        truth = torch.tensor([[1.0, 1.0]])
        restored = torch.tensor([[1.0, 17.0]])
        assert exact_k_share(restored, truth, bits=4).tolist() == [0.5]
        assert exact_k_share(restored, truth, bits=5).tolist() == [1.0]

    def test_matches_loop_reference(self) -> None:
        truth = _counts((3, 2, 6, 7), 2)
        g = torch.Generator().manual_seed(3)
        wrong = torch.randint(-1, 3, truth.shape, generator=g).double() * 256
        restored = (truth + wrong + 512).clamp_min(0)
        expected = _exact_k_reference(restored.numpy(), truth.numpy(), 8)
        np.testing.assert_allclose(exact_k_share(restored, truth).numpy(), expected)
        assert expected.min() < 1  # the test data has wrong counts to find

    def test_integer_inputs(self) -> None:
        truth = torch.tensor([[10, 300], [600, 20]])
        restored = torch.tensor([[10, 300], [856, 20]])
        out = exact_k_share(restored, truth)
        assert out.dtype == torch.get_default_dtype()
        assert out.tolist() == [0.75]

    def test_exceptions(self) -> None:
        truth = torch.zeros(2, 2)
        with pytest.raises(TypeError, match="list"):
            exact_k_share([[0.0]], truth)  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="torch.bool"):
            exact_k_share(truth.bool(), truth)
        with pytest.raises(ValueError, match=r"\(2, 2\) and \(2, 3\)"):
            exact_k_share(truth, torch.zeros(2, 3))
        with pytest.raises(ValueError, match=r"\(5,\)"):
            exact_k_share(torch.zeros(5), torch.zeros(5))
        with pytest.raises(ValueError, match="1 NaN"):
            exact_k_share(torch.tensor([[0.0, math.nan]]), torch.zeros(1, 2))
        with pytest.raises(ValueError, match="-3.0"):
            exact_k_share(torch.zeros(1, 2), torch.tensor([[0.0, -3.0]]))
        with pytest.raises(ValueError, match="bits must be >= 1; got 0"):
            exact_k_share(truth, truth, bits=0)
        with pytest.raises(TypeError, match="1.5"):
            exact_k_share(truth, truth, bits=1.5)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match=r"\(1, 0, 3\)"):
            exact_k_share(torch.zeros(1, 0, 3), torch.zeros(1, 0, 3))
        with pytest.raises(TypeError, match="align"):
            ExactKShare(align=1)  # type: ignore[arg-type]

    def test_module_equals_function(self) -> None:
        truth = _counts((2, 3, 5, 5), 4)
        restored = truth + _counts((2, 3, 5, 5), 5, high=3) * 16
        assert torch.equal(ExactKShare(bits=4)(restored, truth), exact_k_share(restored, truth, bits=4))
        assert "bits=4" in repr(ExactKShare(bits=4))

    def test_contract(self, device: torch.device, dtype: torch.dtype) -> None:
        truth = _counts((3, 2, 5, 6), 6).to(device, dtype)
        restored = (truth + _counts((3, 2, 5, 6), 7, high=2) * 256).to(device, dtype)
        before = restored.clone(), truth.clone()
        out = exact_k_share(restored, truth)
        assert torch.equal(restored, before[0]) and torch.equal(truth, before[1])
        assert out.dtype == dtype and out.device == device
        per_image = torch.cat([exact_k_share(r, t) for r, t in zip(restored, truth, strict=True)])
        assert torch.equal(out, per_image)
        assert torch.equal(exact_k_map(restored, truth)[1], exact_k_map(restored[1], truth[1]))


class TestPSNR:
    def test_known_mse(self, device: torch.device, dtype: torch.dtype) -> None:
        y = torch.zeros(1, 1, 2, 2, device=device, dtype=dtype)
        x = torch.tensor([[[[0.0, 0.0], [0.0, 2.0]]]], device=device, dtype=dtype)  # MSE = 4 / 4 = 1
        out = psnr(x, y, peak=10.0)
        assert out.dtype == dtype and out.device == device
        torch.testing.assert_close(out, torch.tensor([20.0], device=device, dtype=dtype))
        torch.testing.assert_close(
            psnr(x, y, 4095.0), torch.tensor([20 * math.log10(4095)], device=device, dtype=dtype)
        )

    def test_batched_items_are_separate(self) -> None:
        y = torch.zeros(2, 3, 2, 2)
        x = torch.zeros(2, 3, 2, 2)
        x[0, 0, 0, 0] = 12.0  # MSE 144 / 12 = 12
        x[1] = 1.0  # MSE 1
        torch.testing.assert_close(psnr(x, y, 1.0), torch.tensor([-10 * math.log10(12), 0.0]))

    def test_identical_is_inf(self) -> None:
        x = _radiance((2, 3, 4, 4), 0)
        assert torch.isinf(psnr(x, x, 1.0)).all()
        assert (psnr(x, x, 1.0) > 0).all()

    @pytest.mark.parametrize(("shape", "out_shape"), SHAPES)
    def test_cardinality(self, shape: tuple[int, ...], out_shape: tuple[int, ...]) -> None:
        assert psnr(_radiance(shape, 1), _radiance(shape, 2), 4096.0).shape == out_shape

    def test_exceptions(self) -> None:
        x = torch.zeros(2, 2)
        for bad in (0.0, -1.0, math.inf, math.nan):
            with pytest.raises(ValueError, match="peak"):
                psnr(x, x, bad)
        for bad in ("1", None, True):
            with pytest.raises(TypeError, match="peak"):
                psnr(x, x, bad)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match=r"\(2, 2\) and \(1, 2, 2\)"):
            psnr(x, torch.zeros(1, 2, 2), 1.0)
        with pytest.raises(ValueError, match="1 Inf"):
            psnr(torch.tensor([[0.0, math.inf]]), torch.zeros(1, 2), 1.0)
        with pytest.raises(TypeError, match="ndarray"):
            psnr(np.zeros((2, 2)), x, 1.0)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="peak"):
            PSNR(peak=0.0)

    def test_gradcheck(self) -> None:
        x = _radiance((2, 1, 3, 3), 3).requires_grad_()
        y = _radiance((2, 1, 3, 3), 4).requires_grad_()
        assert torch.autograd.gradcheck(lambda a, b: psnr(a, b, 4096.0), (x, y))

    def test_module_equals_function(self) -> None:
        x, y = _radiance((2, 3, 4, 4), 5), _radiance((2, 3, 4, 4), 6)
        assert torch.equal(PSNR(4096.0)(x, y), psnr(x, y, 4096.0))

    def test_contract(self) -> None:
        x, y = _radiance((3, 2, 4, 5), 7), _radiance((3, 2, 4, 5), 8)
        x0 = x.clone()
        out = psnr(x, y, 4096.0)
        assert torch.equal(x, x0)
        torch.testing.assert_close(out, torch.cat([psnr(a, b, 4096.0) for a, b in zip(x, y, strict=True)]))
        assert psnr(x[:0], y[:0], 1.0).shape == (0,)


class TestPSNRLog:
    def test_hand_value(self) -> None:
        y = torch.tensor([[1.0, 4.0], [0.0, 8.0]], dtype=torch.float64)
        x = torch.tensor([[2.0, 4.0], [1.0, 8.0]], dtype=torch.float64)
        eps = 1 / 64
        m = 8.0

        def v(z: float) -> float:
            return math.log2(z / m + eps)

        mse = ((v(2) - v(1)) ** 2 + (v(1) - v(0)) ** 2) / 4
        peak = math.log2((1 + eps) / eps)
        expected = 10 * math.log10(peak**2 / mse)
        torch.testing.assert_close(psnr_log(x, y, eps=eps), torch.tensor([expected], dtype=torch.float64))

    def test_scale_invariant(self) -> None:
        x, y = _radiance((2, 3, 4, 4), 0), _radiance((2, 3, 4, 4), 1)
        torch.testing.assert_close(psnr_log(1000 * x, 1000 * y), psnr_log(x, y))

    def test_closer_is_higher(self) -> None:
        y = _radiance((1, 3, 4, 4), 2)
        assert psnr_log(1.1 * y, y) > psnr_log(2 * y, y)
        assert torch.isinf(psnr_log(y, y)).all()

    def test_black_reference_uses_unit_peak(self) -> None:
        y = torch.zeros(1, 1, 1, 2, dtype=torch.float64)
        x = torch.tensor([[[[0.0, 1.0]]]], dtype=torch.float64)
        eps = 0.25
        mse = (math.log2(1 + eps) - math.log2(eps)) ** 2 / 2
        expected = 10 * math.log10(math.log2((1 + eps) / eps) ** 2 / mse)
        torch.testing.assert_close(psnr_log(x, y, eps), torch.tensor([expected], dtype=torch.float64))

    def test_exceptions(self) -> None:
        x = torch.ones(2, 2)
        with pytest.raises(ValueError, match="-1.0"):
            psnr_log(torch.tensor([[1.0, -1.0]]), torch.ones(1, 2))
        with pytest.raises(ValueError, match="NaN"):
            psnr_log(torch.ones(1, 2), torch.tensor([[1.0, math.nan]]))
        for bad in (0.0, 1.0, -0.5):
            with pytest.raises(ValueError, match="eps"):
                psnr_log(x, x, bad)
        with pytest.raises(TypeError, match="eps"):
            PSNRLog(eps="small")  # type: ignore[arg-type]
        with pytest.raises(ValueError, match=r"\(2, 2\) and \(2, 3\)"):
            psnr_log(x, torch.ones(2, 3))

    def test_gradcheck(self) -> None:
        x = _radiance((2, 1, 3, 3), 3).requires_grad_()
        y = _radiance((2, 1, 3, 3), 4).requires_grad_()
        assert torch.autograd.gradcheck(lambda a, b: psnr_log(a, b, 2.0**-8), (x, y))

    def test_module_equals_function_and_contract(self, device: torch.device, dtype: torch.dtype) -> None:
        x, y = _radiance((3, 2, 4, 4), 5).to(device, dtype), _radiance((3, 2, 4, 4), 6).to(device, dtype)
        out = PSNRLog(eps=2.0**-10)(x, y)
        assert torch.equal(out, psnr_log(x, y, 2.0**-10))
        assert out.dtype == dtype and out.device == device
        per_image = torch.cat([psnr_log(a, b, 2.0**-10) for a, b in zip(x, y, strict=True)])
        torch.testing.assert_close(out, per_image)


class TestPU21:
    @pytest.mark.parametrize("variant", ["banding_glare", "banding"])
    def test_matches_published_formula(self, variant: str) -> None:
        lum = [0.001, 0.005, 0.1, 1.0, 10.0, 100.0, 1000.0, 10000.0, 20000.0]
        expected = torch.tensor([_pu21_reference(v, variant) for v in lum], dtype=torch.float64)
        got = pu21_encode(torch.tensor(lum, dtype=torch.float64), variant)
        torch.testing.assert_close(got, expected, rtol=1e-12, atol=1e-9)

    def test_parameters_are_the_published_ones(self) -> None:
        assert PU21_PARAMETERS == PUBLISHED_PU21

    def test_known_anchor(self) -> None:
        # the PU21 encoders map 100 cd/m^2 to about 256 and 10000 cd/m^2 to about 600
        v = pu21_encode(torch.tensor([100.0, 10000.0]))
        assert 250 < v[0] < 262 and 520 < v[1] < 600

    @pytest.mark.parametrize("variant", ["banding_glare", "banding"])
    def test_monotonic_and_clamped(self, variant: str) -> None:
        lum = torch.logspace(math.log10(0.005), 4, 500, dtype=torch.float64)
        v = pu21_encode(lum, variant)
        assert (v[1:] > v[:-1]).all()
        outside = pu21_encode(torch.tensor([0.0, 0.001, 0.005, 10000.0, 1e6], dtype=torch.float64), variant)
        assert outside[0] == outside[1] == outside[2] and outside[3] == outside[4]

    def test_exceptions(self) -> None:
        with pytest.raises(ValueError, match="-2.0"):
            pu21_encode(torch.tensor([1.0, -2.0]))
        with pytest.raises(ValueError, match="'peaks'"):
            pu21_encode(torch.ones(2), "peaks")
        with pytest.raises(TypeError, match="variant"):
            PU21Encode(variant=1)  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="list"):
            pu21_encode([1.0])  # type: ignore[arg-type]

    def test_gradcheck(self) -> None:
        lum = torch.tensor([0.01, 1.0, 50.0, 3000.0], dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(pu21_encode, (lum,))

    def test_module_equals_function_and_contract(self, device: torch.device, dtype: torch.dtype) -> None:
        lum = _radiance((2, 3, 4, 4), 0).to(device, dtype)
        before = lum.clone()
        out = PU21Encode("banding")(lum)
        assert torch.equal(out, pu21_encode(lum, "banding"))
        assert torch.equal(lum, before) and out.dtype == dtype and out.device == device and out.shape == lum.shape


class TestPSNRPU21:
    def test_matches_formula(self) -> None:
        y = torch.tensor([[1.0, 0.5], [0.01, 0.0]], dtype=torch.float64)
        x = torch.tensor([[0.9, 0.5], [0.02, 0.1]], dtype=torch.float64)
        s = 1000.0  # reference max 1 -> 1000 cd/m^2
        sq = [
            (_pu21_reference(a * s, "banding_glare") - _pu21_reference(b * s, "banding_glare")) ** 2
            for a, b in zip(x.flatten().tolist(), y.flatten().tolist(), strict=True)
        ]
        expected = 10 * math.log10(256**2 / (sum(sq) / 4))
        got = psnr_pu21(x, y, peak_luminance=1000.0)
        torch.testing.assert_close(got, torch.tensor([expected], dtype=torch.float64))
        torch.testing.assert_close(psnr_pu21(x * s, y * s, peak_luminance=None), got)

    def test_relative_input_is_scale_free(self) -> None:
        x, y = _radiance((2, 3, 4, 4), 1), _radiance((2, 3, 4, 4), 2)
        torch.testing.assert_close(psnr_pu21(7 * x, 7 * y), psnr_pu21(x, y))

    def test_identical_and_ordering(self) -> None:
        y = _radiance((1, 3, 4, 4), 3)
        assert torch.isinf(psnr_pu21(y, y)).all()
        assert psnr_pu21(1.05 * y, y) > psnr_pu21(1.5 * y, y)

    def test_exceptions(self) -> None:
        x = torch.ones(2, 2)
        with pytest.raises(ValueError, match="peak_luminance"):
            psnr_pu21(x, x, peak_luminance=-5.0)
        with pytest.raises(ValueError, match="variant"):
            psnr_pu21(x, x, variant="bandings")
        with pytest.raises(ValueError, match="peak must be positive"):
            psnr_pu21(x, x, peak=0.0)
        with pytest.raises(ValueError, match=r"\(2, 2\) and \(3, 2, 2\)"):
            psnr_pu21(x, torch.ones(3, 2, 2))
        with pytest.raises(ValueError, match="-1.0"):
            psnr_pu21(-x, x)

    def test_gradcheck(self) -> None:
        x = _radiance((1, 1, 3, 3), 4).requires_grad_()
        y = _radiance((1, 1, 3, 3), 5)
        assert torch.autograd.gradcheck(lambda a: psnr_pu21(a, y, 100.0), (x,))

    def test_module_equals_function_and_contract(self, device: torch.device, dtype: torch.dtype) -> None:
        x, y = _radiance((3, 2, 4, 4), 6).to(device, dtype), _radiance((3, 2, 4, 4), 7).to(device, dtype)
        out = PSNRPU21(peak_luminance=1000.0, variant="banding")(x, y)
        assert torch.equal(out, psnr_pu21(x, y, 1000.0, variant="banding"))
        assert out.dtype == dtype and out.device == device
        per_image = torch.cat([psnr_pu21(a, b, 1000.0, variant="banding") for a, b in zip(x, y, strict=True)])
        torch.testing.assert_close(out, per_image)


class TestSSIMToneMapped:
    def test_identical_is_one(self, device: torch.device, dtype: torch.dtype) -> None:
        y = _radiance((2, 3, 16, 16), 0).to(device, dtype)
        out = ssim_tonemapped(y, y)
        assert out.dtype == dtype and out.device == device and out.shape == (2,)
        torch.testing.assert_close(out, torch.ones(2, device=device, dtype=dtype))

    def test_default_tonemap_matches_kornia_on_stated_curve(self) -> None:
        x, y = _radiance((2, 3, 12, 12), 1), _radiance((2, 3, 12, 12), 2)
        eps = 2.0**-16
        m = y.flatten(1).amax(1).view(-1, 1, 1, 1)

        def t(z: torch.Tensor) -> torch.Tensor:
            return ((torch.log2(z / m + eps) - math.log2(eps)) / math.log2((1 + eps) / eps)).clamp(0, 1)

        expected = kornia.metrics.ssim(t(x), t(y), 7, max_val=1.0, eps=0.0).mean(dim=(1, 2, 3))
        torch.testing.assert_close(ssim_tonemapped(x, y, window_size=7), expected)
        torch.testing.assert_close(log_relative_tonemap(x, y), t(x))

    def test_custom_tonemap(self) -> None:
        x, y = _radiance((1, 1, 9, 9), 3), _radiance((1, 1, 9, 9), 4)

        def tm(z: torch.Tensor) -> torch.Tensor:
            return z / 4096.0

        expected = kornia.metrics.ssim(tm(x), tm(y), 5, max_val=1.0, eps=0.0).mean()
        torch.testing.assert_close(ssim_tonemapped(x, y, tm, window_size=5), expected.reshape(1))
        assert ssim_tonemapped(x, y, tm, 5) < 1

    def test_tone_map_is_the_references(self) -> None:
        # the default curve is fixed by the reference: a brighter estimate is not normalised away
        y = _radiance((1, 1, 8, 8), 5)
        assert ssim_tonemapped(4 * y, y, window_size=5) < 0.99

    @pytest.mark.parametrize(("shape", "out_shape"), SHAPES[:3])
    def test_cardinality(self, shape: tuple[int, ...], out_shape: tuple[int, ...]) -> None:
        assert ssim_tonemapped(_radiance(shape, 6), _radiance(shape, 7), window_size=3).shape == out_shape

    def test_exceptions(self) -> None:
        x = torch.ones(1, 1, 8, 8)
        with pytest.raises(ValueError, match="window_size must be an odd positive integer; got 4"):
            ssim_tonemapped(x, x, window_size=4)
        with pytest.raises(TypeError, match="window_size"):
            SSIMToneMapped(window_size=3.0)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match=r"window_size // 2 = 5"):
            ssim_tonemapped(torch.ones(1, 1, 5, 20), torch.ones(1, 1, 5, 20))
        with pytest.raises(TypeError, match="callable"):
            ssim_tonemapped(x, x, tonemap="reinhard")  # type: ignore[arg-type]
        with pytest.raises(ValueError, match=r"\(1, 1, 4, 4\)"):
            ssim_tonemapped(x, x, tonemap=lambda z: z[..., :4, :4], window_size=3)
        with pytest.raises(ValueError, match="-1.0"):
            ssim_tonemapped(-x, x)
        with pytest.raises(ValueError, match=r"\(1, 1, 8, 8\) and \(1, 8, 8\)"):
            ssim_tonemapped(x, x[0])

    def test_gradcheck(self) -> None:
        x = _radiance((1, 1, 5, 5), 8).requires_grad_()
        y = _radiance((1, 1, 5, 5), 9)
        assert torch.autograd.gradcheck(lambda a: ssim_tonemapped(a, y, window_size=3), (x,))

    def test_module_equals_function_and_contract(self) -> None:
        x, y = _radiance((3, 2, 8, 8), 10), _radiance((3, 2, 8, 8), 11)
        x0 = x.clone()
        out = SSIMToneMapped(window_size=5)(x, y)
        assert torch.equal(out, ssim_tonemapped(x, y, window_size=5))
        assert torch.equal(x, x0)
        per_image = torch.cat([ssim_tonemapped(a, b, window_size=5) for a, b in zip(x, y, strict=True)])
        torch.testing.assert_close(out, per_image)
        assert ssim_tonemapped(x[:0], y[:0]).shape == (0,)


class TestPSNRExtremeValues:
    """Regression: ``psnr`` in float32 gave NaN near 1e20 and +-inf for tiny or huge values that differ."""

    @pytest.mark.parametrize(
        ("x", "y", "peak"),
        [
            ([[1e20, 3e20]], [[2e20, 1e20]], 1e20),  # squares overflow float32
            ([[1e-30, 0.0]], [[0.0, 0.0]], 1.0),  # squares underflow float32
            ([[3e38, -3e38]], [[-3e38, 3e38]], 1.0),  # even the differences overflow float32
            ([[1e-45, 0.0]], [[0.0, 0.0]], 1e38),
        ],
    )
    def test_float32_scores_are_finite_and_match_float64(self, x: list, y: list, peak: float) -> None:
        xt, yt = torch.tensor(x), torch.tensor(y)
        got = psnr(xt, yt, peak)
        want = psnr(xt.double(), yt.double(), peak)
        assert got.dtype == torch.float32 and torch.isfinite(got).all()
        torch.testing.assert_close(got, want.float(), rtol=1e-6, atol=1e-4)

    def test_float64_beyond_squaring_range_is_finite(self) -> None:
        x = torch.tensor([[1e200, 0.0]], dtype=torch.float64)
        y = torch.tensor([[1e-300, 0.0]], dtype=torch.float64)
        got = psnr(x, torch.zeros_like(x), 1.0)
        assert math.isclose(float(got[0]), -10 * (400 - math.log10(2)), rel_tol=1e-12)
        assert math.isclose(float(psnr(y, torch.zeros_like(y), 1.0)[0]), 10 * (600 + math.log10(2)), rel_tol=1e-12)

    def test_identical_images_still_score_inf(self) -> None:
        x = torch.tensor([[1e20, 3e20]])
        assert psnr(x, x.clone(), 1.0).tolist() == [math.inf]


class TestExactKIntegerInputs:
    """Regression: ``exact_k_map`` on uint8 tensors raised ZeroDivisionError (the period 256 wrapped to 0)."""

    @pytest.mark.parametrize("integer", [torch.uint8, torch.int16, torch.int32, torch.int64])
    def test_integer_counts_give_the_float_result(self, integer: torch.dtype) -> None:
        truth = torch.tensor([[10.0, 100.0], [20.0, 127.0]])
        restored = torch.tensor([[10.0, 100.0], [20.0, 126.0]])
        want = exact_k_map(restored, truth, bits=4)
        got = exact_k_map(restored.to(integer), truth.to(integer), bits=4)
        assert torch.equal(got, want)
        assert torch.equal(
            exact_k_map(restored.to(integer), truth.to(integer), bits=8), torch.ones(2, 2, dtype=torch.bool)
        )
        assert exact_k_share(restored.to(integer), truth.to(integer), bits=8).tolist() == [1.0]

    @pytest.mark.parametrize("flag", ["no", 0, 1, None])
    def test_align_must_be_a_bool(self, flag: object) -> None:
        x = torch.zeros(2, 2)
        with pytest.raises(TypeError, match=f"align must be a bool; got {flag!r}"):
            exact_k_map(x, x, align=flag)  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="align must be a bool"):
            exact_k_share(x, x, align=flag)  # type: ignore[arg-type]


def test_ssim_of_nearly_identical_images_is_at_most_one() -> None:
    g = torch.Generator().manual_seed(2)
    worst = 0.0
    for _ in range(50):  # float32 cancellation once gave 1 + 2e-6 here
        y = torch.rand(1, 1, 8, 8, generator=g) * 1e3
        x = y * (1 + 1e-7 * torch.rand(1, 1, 8, 8, generator=g))
        worst = max(worst, float(ssim_tonemapped(x, y, window_size=3)))
    assert 0.999 < worst <= 1.0
