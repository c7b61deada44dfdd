"""Tests for torch_modulo/noise.py: the noise model, its presets and its count statistics."""

from __future__ import annotations

import pytest
import torch

from torch_modulo.noise import PRESETS, NoiseModel, as_noise_model
from torch_modulo.sensors import SimulatedModuloSensor


class TestNoiseModel:
    @pytest.mark.parametrize("name", list(PRESETS))
    def test_presets(self, name: str) -> None:
        noise = NoiseModel.preset(name)
        assert isinstance(noise, NoiseModel) and not noise.is_noiseless
        assert as_noise_model(name) == noise
        assert SimulatedModuloSensor(8, name).noise == noise

    def test_default_is_the_photon_counting_preset(self) -> None:
        assert NoiseModel() == NoiseModel.preset("photon-counting")
        assert SimulatedModuloSensor().noise == NoiseModel()

    @pytest.mark.parametrize(("q", "read"), [(1.0, 1.0), (16.0, 16.0), (4.0, 0.0)])
    def test_count_variance_matches_simulation(self, q: float, read: float) -> None:
        # A flat field at 400 counts: the simulated counts' variance is the model's within 5 standard errors.
        noise = NoiseModel(electrons_per_count=q, read_noise=read)
        flat = torch.full((1, 1, 200, 200), 400.0, dtype=torch.float64)
        counts = SimulatedModuloSensor(53, noise, seed=1)(flat, [1.0]).moduli.flatten()
        expected = noise.count_variance(400.0)
        n = counts.numel()
        assert abs(float(counts.var()) - expected) < 5 * expected * (2 / n) ** 0.5
        assert abs(float(counts.mean()) - 399.5) < 5 * (expected / n) ** 0.5

    def test_count_variance_tensor_and_no_shot_noise(self) -> None:
        noise = NoiseModel(electrons_per_count=2.0, read_noise=2.0)
        out = noise.count_variance(torch.tensor([-1.0, 0.0, 8.0]))
        assert torch.allclose(out, torch.tensor([1 + 1 / 12, 1 + 1 / 12, 5 + 1 / 12]))
        quiet = NoiseModel(read_noise=0.0, shot_noise=False)
        assert quiet.count_variance(100.0) == pytest.approx(1 / 12)
        assert NoiseModel(dark_current=3.0, electrons_per_count=2.0).dark_counts == 1.5

    @pytest.mark.parametrize(
        ("value", "error", "match"),
        [
            ({"q": 1}, TypeError, "noise must be a NoiseModel or None; got dict"),
            ("loud", ValueError, "noise preset must be one of .*'photon-counting'.*; got 'loud'"),
            (["q16"], TypeError, "got list"),
        ],
    )
    def test_bad_input(self, value: object, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            as_noise_model(value)
        with pytest.raises(error, match=match):
            SimulatedModuloSensor(8, value)  # type: ignore[arg-type]

    @pytest.mark.parametrize(
        ("kwargs", "match"),
        [
            ({"electrons_per_count": 1e-300}, r"electrons_per_count=1e-300 .* overflow"),
            ({"electrons_per_count": 1e-300, "read_noise": 0.0}, r"electrons_per_count=1e-300 .* overflow"),
            ({"electrons_per_count": 1e-200, "read_noise": 1e120}, r"read_noise=1e\+120 .* overflow"),
            ({"electrons_per_count": 1e-10, "dark_current": 1e300}, r"dark_current=1e\+300 .* overflow"),
        ],
    )
    def test_regression_models_whose_variance_overflows(self, kwargs: dict, match: str) -> None:
        # NoiseModel(electrons_per_count=1e-300) was accepted; unwrap_multi and plan_exposures then raised
        # OverflowError from count_variance.
        with pytest.raises(ValueError, match=match):
            NoiseModel(**kwargs)
        NoiseModel(electrons_per_count=0.5, read_noise=1.5)  # sub-electron charge quanta stay accepted
