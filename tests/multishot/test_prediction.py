"""Tests for torch_modulo/multishot/prediction.py: predicted errors of modulo and conventional plans."""

from __future__ import annotations

import math

import pytest
import torch

import torch_modulo as tm
from torch_modulo.multishot.prediction import (
    Prediction,
    conventional_exposures,
    plan_conventional,
    predict_conventional,
    predict_modulo,
)


class TestPredictModulo:
    def test_smoke_and_fields(self) -> None:
        taus = tm.plan_exposures(12, 8, noise="q16", longest=1.0)
        p = predict_modulo(taus, 8, "q16", stops=12)
        assert isinstance(p, Prediction) and p.sensor == "modulo" and p.frames == len(taus)
        assert p.stops == pytest.approx(12.0)
        assert p.radiance[0] == pytest.approx(1.0 / taus[-1]) and p.radiance.dtype == torch.float64
        assert p.relative_error.shape == p.radiance.shape and bool((p.relative_error > 0).all())
        assert 0.0 < p.median_error < 0.05 and 0.0 <= p.gross_share < 0.1
        d = p.to_dict(grid=False)
        assert d["frames"] == len(taus) and "radiance" not in d and "radiance" in p.to_dict()

    def test_order_of_exposures_does_not_matter(self) -> None:
        taus = [1 / 64, 1 / 8, 1.0]
        a, b = predict_modulo(taus, 8, "q16", stops=12), predict_modulo(taus[::-1], 8, "q16", stops=12)
        assert a.median_error == b.median_error and a.exposures == b.exposures

    def test_shot_noise_relative_error_falls_as_one_over_root_counts(self) -> None:
        # One frame, no read noise, q = 1: Var(E) = E / tau, so the rms relative error is 1 / sqrt(E tau).
        noise = tm.sensors.NoiseModel(electrons_per_count=1.0, read_noise=0.0)
        p = predict_modulo([1.0], 8, noise, stops=6)
        expected = torch.sqrt(p.radiance + 1 / 12) / p.radiance
        assert torch.allclose(p.relative_error, expected, rtol=1e-9)

    def test_quieter_sensor_predicts_a_smaller_error(self) -> None:
        taus = [1 / 64, 1 / 8, 1.0]
        assert (
            predict_modulo(taus, 8, "dfpa", stops=12).median_error
            < predict_modulo(taus, 8, "q16", stops=12).median_error
        )

    def test_a_plan_with_too_large_a_ratio_predicts_gross_errors(self) -> None:
        # The paper's noise-free ratios (256) cannot be decoded at q = 1: the prediction says so.
        safe = predict_modulo(
            tm.plan_exposures(16, 8, noise="photon-counting", longest=1.0), 8, "photon-counting", stops=16
        )
        blind = predict_modulo([1 / 256, 1.0], 8, "photon-counting", stops=16)
        assert blind.gross_share > safe.gross_share + 0.3  # (the safe plan's gross share is its one-count end)

    @pytest.mark.parametrize(
        ("args", "error", "match"),
        [
            (([], 8, "q16"), ValueError, "at least one exposure"),
            (([1.0, -1.0], 8, "q16"), ValueError, "exposures"),
            (("1,2", 8, "q16"), TypeError, "sequence"),
            (([1.0], 8, None), ValueError, "noise must be a NoiseModel"),
            (([1.0], 0, "q16"), ValueError, "bits"),
            (([1.0], 8, "nope"), ValueError, "nope"),
        ],
    )
    def test_bad_input_named(self, args: tuple, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            predict_modulo(*args)


class TestPredictConventional:
    def test_one_unsaturated_frame_is_its_shot_noise(self) -> None:
        noise = tm.sensors.NoiseModel(electrons_per_count=1.0, read_noise=0.0)
        p = predict_conventional([1.0], 8, noise, stops=6)  # up to 64 counts: never saturated
        assert torch.allclose(p.relative_error, torch.sqrt(p.radiance + 1 / 12) / p.radiance, rtol=1e-9)
        # Neither saturated nor rolled over: the same estimate as a modulo sensor's single frame.
        modulo = predict_modulo([1.0], 8, noise, stops=6)
        assert p.median_error == pytest.approx(modulo.median_error, rel=1e-6)
        assert p.gross_share == pytest.approx(modulo.gross_share, rel=1e-6)

    def test_values_saturated_everywhere_are_gross(self) -> None:
        # 12 stops from one count with a single frame: everything above 255 counts is clipped.
        p = predict_conventional([1.0], 8, "q16", stops=12)
        clipped = 1.0 - 8.0 / 12.0  # the share of the log ramp above 2^8 counts
        assert p.gross_share > 0.8 * clipped

    def test_more_frames_predict_no_worse(self) -> None:
        medians = [
            predict_conventional(conventional_exposures(1 / 256, k), 8, "q16", stops=16).median_error for k in (2, 4, 8)
        ]
        assert medians[0] >= medians[1] >= medians[2]


class TestPlanConventional:
    def test_fewest_frames_that_meet_the_target(self) -> None:
        taus = plan_conventional(12, 8, "q16", target_median=0.02)
        assert taus[-1] == 1.0
        assert predict_conventional(taus, 8, "q16", stops=12).median_error <= 0.02
        fewer = conventional_exposures(taus[0], len(taus) - 1)
        assert len(taus) == 1 or predict_conventional(fewer, 8, "q16", stops=12).median_error > 0.02

    def test_default_target_is_the_modulo_plan(self) -> None:
        modulo = tm.plan_exposures(12, 8, noise="q16", longest=1.0)
        target = predict_modulo(modulo, 8, "q16", stops=12).median_error
        taus = plan_conventional(12, 8, "q16")
        assert (
            taus[0] == pytest.approx(modulo[0])
            and predict_conventional(taus, 8, "q16", stops=12).median_error <= target
        )

    def test_unreachable_target_is_refused_with_the_best_median(self) -> None:
        with pytest.raises(
            ValueError, match=r"target_median=1e-06 is not met by a conventional plan of at most 4 frames"
        ):
            plan_conventional(12, 8, "q16", target_median=1e-6, frames=4)

    def test_geometric_exposures(self) -> None:
        taus = conventional_exposures(1 / 16, 3)
        assert taus == [0.0625, 0.25, 1.0] and conventional_exposures(0.5, 1) == [1.0]
        assert all(math.isclose(b / a, 4.0) for a, b in zip(taus, taus[1:], strict=False))
