"""Unit tests of research/common.py, research/single_limits.py and research/bench_cuts.py (no scene files needed)."""

from __future__ import annotations

import numpy as np
import pytest

from research import bench_cuts, common, single_limits


def _ramp(h: int = 12, w: int = 16) -> np.ndarray:
    """(1, H, W) smooth true counts, 40 per column: 2.4 rollovers of an 8-bit counter at w = 16."""
    return np.broadcast_to(np.arange(w) * 40.0 + 5, (1, h, w)).copy()


class TestCommon:
    @pytest.mark.parametrize("spec", ["guided", "fast:window=0", "skimage"])
    def test_run_method_recovers_a_ramp(self, spec: str) -> None:
        truth = _ramp()
        restored, seconds = common.run_method(spec, np.mod(truth, common.PERIOD))
        assert seconds >= 0 and restored.shape == truth.shape
        assert common.scores(restored, truth) == (1.0, float("inf"))

    def test_aligned_shifts_whole_periods(self) -> None:
        truth = _ramp()
        assert np.array_equal(common.aligned(truth + 3 * common.PERIOD, truth), truth)


class TestSingleLimits:
    def test_cliff_splits_the_smooth_region_and_the_oracle_crosses_it_once(self) -> None:
        truth = np.zeros((8, 8))
        truth[:, 4:] = 1000.0  # a cliff of nearly 4 periods: nothing smooth joins the halves
        assert single_limits.largest_smooth_region(truth) == 0.5
        k = single_limits.oracle_k(_ramp()[0])
        assert np.array_equal(np.mod(_ramp()[0], 256) + 256 * k, _ramp()[0])

    def test_truncated_energy_and_auc(self) -> None:
        image = np.array([[[0.0, 10.0, 110.0]]])
        assert single_limits.truncated_energy(image, 32) == 10 + 32
        assert single_limits.auc(np.array([0.1, 0.9, 0.8]), np.array([False, True, True])) == 1.0

    def test_channels_at_true_level(self) -> None:
        truth = _ramp()
        assert single_limits.channels_at_true_level(truth, truth) == (1, 1)
        assert single_limits.channels_at_true_level(truth + 256, truth) == (0, 1)

    def test_scene_scores_count_the_rolled_over_values(self) -> None:
        truth = _ramp()  # 5, 45, ..., 605: 9 of the 16 columns rolled over
        assert single_limits.scene_scores(truth + 256, truth, "A") == (1.0, 1.0, float("inf"))
        wrong = truth.copy()
        wrong[..., -1] -= 256  # the brightest column a period low
        k, rolled, _ = single_limits.scene_scores(wrong, truth, "A10")
        assert k == 15 / 16 and rolled == 8 / 9

    def test_summarize_the_oracle_alone(self) -> None:
        rows = [
            {"largest": 1.0, "oracle_k": 1.0, "oracle_rolled": r, "oracle_psnr": p}
            for r, p in ((0.5, 30.0), (1.0, 1e9))
        ]
        out = single_limits.summarize(rows, "A", "none", "validation")
        assert out["scenes"] == 2 and out["oracle_rolled_over_right"] == 0.75 and out["oracle_psnr"] == 65.0
        assert "exact_k" not in out

    def test_confidence_scores_of_a_perfect_result(self) -> None:
        _, caught, wrong = single_limits.confidence_scores(_ramp(), _ramp())
        assert wrong == 0.0 and np.isnan(caught)


def test_bench_cuts_measure_runs_on_a_small_plane() -> None:
    row = bench_cuts.measure(np.mod(_ramp(16, 16)[0], 256).astype(np.int64), tiles=(8,))
    assert row["paper_cuts"] >= 1 and row["tiles_energy_ratio"] > 0 and row["cut_at_zero_s_per_mp"] >= 0
