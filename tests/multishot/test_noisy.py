"""Tests for torch_modulo/multishot/noisy.py: noise-aware decoding through unwrap_multi(..., noise=...)."""

from __future__ import annotations

import warnings

import pytest
import torch

import torch_modulo as tm
from torch_modulo.sensors import NoiseModel, SimulatedIntensitySensor, SimulatedModuloSensor

PHOTON = NoiseModel()  # one electron per count, 1 e- read noise
STOPS = 16


def _scene(seed: int = 0, shape: tuple[int, ...] = (2, 3, 24, 24)) -> torch.Tensor:
    """Radiance from 16 counts at exposure 1 (as protocol N's darkest) up to 2**STOPS counts."""
    gen = torch.Generator().manual_seed(seed)
    return torch.exp2(4 + torch.rand(shape, generator=gen, dtype=torch.float64) * (STOPS - 4))


def _plan(noise: NoiseModel) -> list[float]:
    # The per-pixel plan: these scenes are independent draws per pixel (texture throughout), where no neighbour
    # agrees, so the spatial plan's larger ratios would leave pixels decoding as alone (tests/multishot/test_spatial.py)
    plan = tm.plan_exposures(STOPS, 8, noise=noise, spatial=False)
    return [t / plan[-1] for t in plan]


def _gross(estimate: torch.Tensor, truth: torch.Tensor) -> float:
    return float((((estimate - truth).abs() / truth) > 0.5).double().mean())


class TestNoisyDecoding:
    @pytest.mark.parametrize("noise", [PHOTON, NoiseModel.preset("q16")], ids=["q1", "q16"])
    def test_regression_no_gross_errors_where_eqs_6_7_fail(self, noise: NoiseModel) -> None:
        # On the frames of a noise-aware plan the new decoder is no more often 50% off than the oracle (the longest
        # frame with its true rollover count); Eqs. 6-7 (paper), and the robust rule on a noise-blind plan, are
        # far more often.
        radiance = _scene()
        taus = _plan(noise)
        moduli = SimulatedModuloSensor(8, noise, seed=3)(radiance, taus).moduli
        oracle = SimulatedIntensitySensor(53, noise, seed=3)(radiance, taus).frames[:, -1] / taus[-1]
        decoded = _gross(tm.unwrap_multi(moduli, taus, 8, noise=noise), radiance)
        assert decoded <= _gross(oracle, radiance) + 1e-3
        assert _gross(tm.unwrap_multi(moduli, taus, 8, method="paper"), radiance) > decoded + 0.02
        if noise != PHOTON:
            return
        blind = [t / 2.0 ** (STOPS - 8) for t in tm.plan_exposures(STOPS, 8)]
        blind_moduli = SimulatedModuloSensor(8, noise, seed=3)(radiance, blind).moduli
        assert _gross(tm.unwrap_multi(blind_moduli, blind, 8), radiance) > decoded + 0.02

    def test_matches_the_oracle(self) -> None:
        # Median relative error within 1.5x of the longest frame read with its true rollover count (same draws).
        radiance = _scene(1)
        taus = _plan(PHOTON)
        moduli = SimulatedModuloSensor(8, PHOTON, seed=5)(radiance, taus).moduli
        counts = SimulatedIntensitySensor(53, PHOTON, seed=5)(radiance, taus).frames[:, -1]
        assert torch.equal(counts % 256, moduli[:, -1])
        estimate = tm.unwrap_multi(moduli, taus, 8, noise=PHOTON)
        error = ((estimate - radiance).abs() / radiance).median()
        oracle = ((counts / taus[-1] - radiance).abs() / radiance).median()
        assert float(error) <= 1.5 * float(oracle)

    def test_variance_is_calibrated(self) -> None:
        radiance = _scene(2, (1, 1, 64, 64))
        taus = _plan(PHOTON)
        moduli = SimulatedModuloSensor(8, PHOTON, seed=7)(radiance, taus).moduli
        estimate, variance = tm.unwrap_multi(moduli, taus, 8, noise=PHOTON, return_variance=True)
        z = (estimate - radiance) / variance.sqrt()
        assert 0.8 < float(z.std()) < 1.25
        assert abs(float(z.mean())) < 0.1

    @pytest.mark.parametrize("spatial", [True, False], ids=["spatial", "alone"])
    @pytest.mark.parametrize("preset", ["photon-counting", "q16"])
    def test_flat_fields_are_unbiased(self, preset: str, spatial: bool) -> None:
        # Flat fields decoded from the plan for 15 stops: the mean is no further from the truth than that of the
        # longest frame alone with its rollover known, (c + 1/2) / tau, plus 0.1 + 0.5% (the clip at zero biases
        # every non-negative estimate near zero). The old estimate put black at 1.4 counts (photon-counting). 96 x 96
        # values per level keep each mean's sampling spread (about 0.02 at 4 counts) well inside the margin.
        noise = NoiseModel.preset(preset)
        taus = tm.plan_exposures(15, 8, noise=noise, longest=1.0, spatial=spatial)
        levels = torch.tensor([0.0, 0.25, 1.0, 4.0, 16.0, 100.0, 1000.0], dtype=torch.float64)
        radiance = levels.view(-1, 1, 1, 1).expand(-1, 1, 96, 96)
        moduli = SimulatedModuloSensor(8, noise, seed=11)(radiance, taus).moduli
        decoded = tm.unwrap_multi(moduli, taus, 8, noise=noise, spatial=spatial).mean(dim=(1, 2, 3))
        alone = SimulatedIntensitySensor(53, noise, seed=12)(radiance, [1.0]).frames[:, 0]
        reference = (alone + 0.5).mean(dim=(1, 2, 3))
        allowed = (reference - levels).abs() + 0.1 + 0.005 * levels
        assert bool(((decoded - levels).abs() <= allowed).all()), (decoded, reference)

    def test_flat_field_variance_is_calibrated(self) -> None:
        # Where the counts are many, the reported variance matches the spread of the estimate.
        taus = _plan(PHOTON)
        radiance = torch.full((1, 1, 96, 96), 300.0, dtype=torch.float64)
        moduli = SimulatedModuloSensor(8, PHOTON, seed=13)(radiance, taus).moduli
        estimate, variance = tm.unwrap_multi(moduli, taus, 8, noise=PHOTON, return_variance=True)
        assert 0.9 < float(estimate.std() / variance.sqrt().mean()) < 1.1
        assert float(((estimate - radiance).abs() > 3 * variance.sqrt()).double().mean()) < 0.01

    def test_float32_moduli_decode_like_float64(self) -> None:
        # float32 moduli are decoded in float32: the same rollover decisions, the radiance to float32 rounding.
        radiance = _scene(8)
        taus = _plan(PHOTON)
        moduli = SimulatedModuloSensor(8, PHOTON, seed=9)(radiance, taus).moduli
        wide = tm.unwrap_multi(moduli, taus, 8, noise=PHOTON)
        narrow = tm.unwrap_multi(moduli.float(), taus, 8, noise=PHOTON)
        assert narrow.dtype == torch.float32
        torch.testing.assert_close(narrow.double(), wide, rtol=1e-5, atol=1e-5)

    def test_without_noise_nothing_changes(self) -> None:
        radiance = _scene(3) * 0.5
        taus = [1.0, 100.0, 10000.0]
        moduli = SimulatedModuloSensor(8, None)(radiance / 2**STOPS * 255, taus).moduli
        assert torch.equal(tm.unwrap_multi(moduli, taus, 8), tm.unwrap_multi(moduli, taus, 8, noise=None))

    def test_quiet_model_is_exact_to_a_count(self) -> None:
        # With little noise the ratios of the noise-free rule decode, and the estimate is the cell centre.
        quiet = NoiseModel(read_noise=0.1, shot_noise=False)
        radiance = _scene(4, (1, 1, 16, 16)) / 2 ** (STOPS - 8) * 0.9
        taus = [1.0, 100.0, 10000.0]
        moduli = SimulatedModuloSensor(8, None)(radiance, taus).moduli
        counts = tm.unwrap_multi(moduli, taus, 8, noise=quiet, return_counts=True)
        assert float((counts - radiance * taus[-1]).abs().max()) <= 1.0

    def test_batched_equals_per_image_and_device(self, device: torch.device) -> None:
        radiance = _scene(5)
        taus = _plan(PHOTON)
        moduli = SimulatedModuloSensor(8, PHOTON, seed=1)(radiance, taus).moduli.to(device)
        batched = tm.unwrap_multi(moduli, taus, 8, noise=PHOTON)
        assert batched.device == moduli.device and batched.dtype == moduli.dtype
        for i in range(moduli.shape[0]):
            assert torch.equal(batched[i], tm.unwrap_multi(moduli[i], taus, 8, noise=PHOTON))
        empty = tm.unwrap_multi(moduli[:0], taus, 8, noise=PHOTON)
        assert empty.shape == (0, *moduli.shape[2:])

    def test_module_equals_function_and_presets(self) -> None:
        radiance = _scene(6)
        taus = _plan(PHOTON)
        moduli = SimulatedModuloSensor(8, "photon-counting", seed=1)(radiance, taus).moduli
        layer = tm.MultiExposureUnwrap(bits=8, noise="photon-counting")
        assert torch.equal(layer(moduli, taus), tm.unwrap_multi(moduli, taus, 8, noise=PHOTON))
        assert "noise=NoiseModel" in repr(layer)

    def test_unsafe_exposures_warn_and_say_what_to_use(self) -> None:
        moduli = torch.zeros(3, 1, 2, 2)
        with pytest.warns(UserWarning, match=r"exposure ratio 256 is unsafe.*plan_exposures\(24, bits=8"):
            tm.unwrap_multi(moduli, [1.0, 256.0, 65536.0], 8, noise=PHOTON)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            tm.unwrap_multi(moduli, [1.0, 4.0, 16.0], 8, noise=PHOTON)  # safe ratios: no warning

    def test_regression_exposures_that_require_grad(self) -> None:
        taus = torch.tensor([1.0, 16.0], requires_grad=True)
        moduli = torch.tensor([[[[3.0]]], [[[52.0]]]])
        assert tm.unwrap_multi(moduli, taus, 8, return_counts=True).item() == 52.0
        with pytest.warns(UserWarning, match="exposure ratio 16 is unsafe"):
            assert tm.unwrap_multi(moduli, taus, 8, noise=PHOTON).requires_grad is False

    def test_bad_noise_input(self) -> None:
        moduli = torch.zeros(2, 1, 2, 2)
        with pytest.raises(TypeError, match="noise must be a NoiseModel or None; got dict"):
            tm.unwrap_multi(moduli, [1.0, 2.0], 8, noise={"read_noise": 1.0})
        with pytest.raises(ValueError, match="noise preset must be one of .*; got 'loud'"):
            tm.unwrap_multi(moduli, [1.0, 2.0], 8, noise="loud")
        with pytest.raises(ValueError, match="method='paper' .* takes no noise model"):
            tm.unwrap_multi(moduli, [1.0, 2.0], 8, method="paper", noise=PHOTON)
        with pytest.raises(ValueError, match="return_variance=True needs a noise model"):
            tm.unwrap_multi(moduli, [1.0, 2.0], 8, return_variance=True)
        with pytest.raises(ValueError, match="sigmas must be finite and > 0; got 0.0"):
            tm.unwrap_multi(moduli, [1.0, 2.0], 8, noise=PHOTON, sigmas=0)
        with pytest.raises(TypeError, match="return_counts must be a bool; got 'no'"):
            tm.unwrap_multi(moduli, [1.0, 2.0], 8, return_counts="no")


class TestNoisyDecodingExtremes:
    @pytest.mark.parametrize("unit", [1e155, 1e-300, 2.0**-1000])
    def test_regression_exposures_in_extreme_units_are_finite(self, unit: float) -> None:
        # In units of 1e155 the weights tau^2 overflowed to inf, in units of 1e-300 they underflowed to 0: all NaN,
        # while the noise-free path was finite. The same frames decode to the same radiance in any unit.
        radiance = _scene(7, (1, 1, 8, 8))
        taus = _plan(NoiseModel.preset("q16"))
        moduli = SimulatedModuloSensor(8, "q16", seed=2)(radiance, taus).moduli
        reference, variance = tm.unwrap_multi(moduli, taus, 8, noise="q16", return_variance=True)
        scaled = tm.unwrap_multi(moduli, [t * unit for t in taus], 8, noise="q16")
        assert bool(torch.isfinite(scaled).all())
        assert torch.allclose(scaled * unit, reference, rtol=1e-12, atol=0.0)
        counts = tm.unwrap_multi(moduli, [t * unit for t in taus], 8, noise="q16", return_counts=True)
        assert torch.allclose(counts, reference * taus[-1], rtol=1e-12, atol=0.0)
        if unit > 1:  # the variance, 1 / unit^2 of the reference's, is within float64's range only here
            _, var = tm.unwrap_multi(moduli, [t * unit for t in taus], 8, noise="q16", return_variance=True)
            assert torch.allclose(var * unit * unit, variance, rtol=1e-9, atol=0.0)

    @pytest.mark.parametrize("unit", [2.0**134, 2.0**100, 2.0**-100])
    def test_float32_moduli_in_extreme_units(self, unit: float) -> None:
        # float32 moduli decode in float32, in a power-of-two unit of their own: exposures beyond float32's range
        # (2**134) decode to the radiance the float64 decoder gives, wherever it is a normal float32 number.
        radiance = _scene(10, (1, 1, 8, 8))
        taus = _plan(NoiseModel.preset("q16"))
        moduli = SimulatedModuloSensor(8, "q16", seed=2)(radiance, taus).moduli.float()
        reference = tm.unwrap_multi(moduli, taus, 8, noise="q16").double()
        scaled = tm.unwrap_multi(moduli, [t * unit for t in taus], 8, noise="q16")
        assert scaled.dtype == torch.float32 and bool(torch.isfinite(scaled).all())
        normal = reference / unit >= torch.finfo(torch.float32).tiny
        assert bool(normal.any())
        torch.testing.assert_close(scaled.double()[normal] * unit, reference[normal], rtol=1e-6, atol=0.0)

    def test_power_of_two_units_round_nothing(self) -> None:
        # The decoder works in a power-of-two unit near the exposures' middle: results scale exactly with the unit.
        radiance = _scene(9, (1, 1, 8, 8))
        taus = _plan(PHOTON)
        moduli = SimulatedModuloSensor(8, PHOTON, seed=2)(radiance, taus).moduli
        reference = tm.unwrap_multi(moduli, taus, 8, noise=PHOTON)
        for k in (-60, 7, 60):
            scaled = tm.unwrap_multi(moduli, [t * 2.0**k for t in taus], 8, noise=PHOTON)
            assert torch.equal(scaled * 2.0**k, reference)

    def test_regression_extreme_units_in_the_noise_aware_merge(self) -> None:
        radiance = _scene(8, (1, 1, 8, 8)) / 2**8
        taus = [1.0, 4.0, 16.0, 64.0]
        frames = SimulatedIntensitySensor(8, "q16", seed=2)(radiance, taus).frames
        reference = tm.merge_intensity(frames, taus, 8, noise="q16")
        for unit in (1e155, 1e-300):
            scaled = tm.merge_intensity(frames, [t * unit for t in taus], 8, noise="q16")
            assert torch.allclose(scaled * unit, reference, rtol=1e-12, atol=0.0)

    def test_regression_dark_counts_that_roll_over_the_shortest_frame(self) -> None:
        # 300 dark counts at the shortest exposure: every pixel of it rolled over, and the decoder returned zeros
        # with only the unsafe-ratio warning; plan_exposures refuses the same model. Both now say the same.
        noise = NoiseModel(dark_current=300.0)
        frames = SimulatedModuloSensor(8, noise, seed=0)(torch.full((1, 1, 4, 4), 20.0, dtype=torch.float64), [1, 4])
        message = r"dark counts of the shortest exposure 1 \(300 counts\) leave no count below the rollover at bits=8"
        with pytest.raises(ValueError, match=message):
            tm.unwrap_multi(frames.moduli, [1.0, 4.0], 8, noise=noise)
        with pytest.raises(ValueError, match=message.replace("exposure 1", "exposure base=1")):
            tm.plan_exposures(10, 8, noise=noise)
        with pytest.warns(UserWarning, match=r"dark counts of the shortest exposure 0.84 \(252 counts\)"):
            tm.unwrap_multi(frames.moduli, [0.84, 3.36], 8, noise=noise)  # below the rollover, within 3 sigmas

    @pytest.mark.parametrize(
        ("moduli_dtype", "taus", "what"),
        [
            (torch.float16, [1e-3, 4e-3], "radiance"),
            (torch.float32, [1e-37, 4e-37], "radiance"),
            (torch.float32, [1e-20, 4e-20], "variance"),
        ],
    )
    def test_regression_overflow_warns(self, moduli_dtype: torch.dtype, taus: list[float], what: str) -> None:
        # The noise-free path warned when its result overflowed the moduli's dtype; the noise-aware one did not.
        moduli = torch.tensor([[[[200.0]]], [[[30.0]]]], dtype=moduli_dtype)
        match = rf"{what} reaches .*, beyond the range of {moduli_dtype}.*use float64 moduli"
        with pytest.warns(UserWarning, match=match):
            tm.unwrap_multi(moduli, taus, 8, noise="q16", return_variance=True)
        if what == "variance":
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                radiance = tm.unwrap_multi(moduli, taus, 8, noise="q16")  # the variance is not returned: no warning
            assert bool(torch.isfinite(radiance).all())
