"""Smoke and unit tests for the research scripts' building blocks (no scene files needed)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from research import bench_cuts, common, edges, harness, single_limits


def _ramp(h: int = 12, w: int = 16) -> np.ndarray:
    """(1, H, W) smooth true counts, 40 per column: 2.4 rollovers of an 8-bit counter at w = 16."""
    return np.broadcast_to(np.arange(w) * 40.0 + 5, (1, h, w)).copy()


class TestCommon:
    @pytest.mark.parametrize("spec", ["guided", "fast:tile=0", "skimage"])
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


class TestEdges:
    def test_features_and_labels_have_one_row_per_horizontal_pair(self) -> None:
        truth = _ramp(6, 9)[0].astype(np.int64)
        assert edges.features(np.mod(truth, 256)).shape == (6, 8, edges.N_FEATURES)
        truth[:, 5:] += 300
        labels = edges.steep_labels(truth)
        assert labels.shape == (6, 8) and labels[:, 4].all() and labels.sum() == 6

    def test_tree_k_with_even_costs_integrates_a_ramp(self) -> None:
        truth = _ramp(6, 9)[0].astype(np.int64)
        costs = [np.ones((6, 8)), np.ones((5, 9))]
        k = edges.tree_k(np.mod(truth, 256), costs)
        assert np.array_equal(k - k.min(), truth // 256)


def test_bench_cuts_measure_runs_on_a_small_plane() -> None:
    row = bench_cuts.measure(np.mod(_ramp(16, 16)[0], 256).astype(np.int64), tiles=(8,))
    assert row["paper_cuts"] >= 1 and row["tiles_energy_ratio"] > 0 and row["cut_at_zero_s_per_mp"] >= 0


def test_harness_parses_options() -> None:
    assert harness.parse_opts(["links=64,0", "jacobian=0", "potential=linear", "colour=False"]) == {
        "links": (64.0, 0.0),
        "jacobian": 0,
        "potential": "linear",
        "colour": False,
    }


class TestRegionMerge:
    def test_a_region_shifted_by_a_period_is_merged_back(self) -> None:
        import torch

        from research import region_merge
        from torch_modulo.singleshot.learned import edge_targets

        truth = np.floor(np.add.outer(np.arange(24) * 9.0, np.arange(24) * 7.0))
        truth[6:14, 8:16] += 700  # a bright block behind steep borders
        m = np.mod(truth, 256).astype(np.int64)
        target, _ = edge_targets(torch.from_numpy(truth)[None, None], 8, 5)
        logp = np.full((2, 11, 24, 24), -8.0)
        np.put_along_axis(logp, target[0, 0].numpy()[:, None], -0.01, axis=1)
        k_true = (truth.astype(np.int64) - m) // 256
        k = k_true.copy()
        k[6:14, 8:16] -= 1  # as if one wrong tree pair had carried the block a period down
        k_merged = region_merge.merge_regions(m, k, logp, 8, tau=0.1)
        assert np.array_equal(k_merged - k_merged[0, 0], k_true - k_true[0, 0])


class TestLearnedRegions:
    def test_regions_follow_the_sure_pairs(self) -> None:
        from research import learned_regions

        cost = np.zeros((2, 4, 6))
        cost[0][:, 2] = 5.0  # every right pair between columns 2 and 3 is unsure: two regions
        count, labels = learned_regions.confident_regions(cost, 0.1)
        assert count == 2 and (labels[:, :3] == labels[0, 0]).all() and (labels[:, 3:] == labels[0, 3]).all()
        assert learned_regions.confident_regions(cost, 10.0)[0] == 1

    def test_oracle_moves_large_regions_only(self) -> None:
        from research import learned_regions

        labels = np.zeros((4, 8), dtype=np.int64)
        labels[:, 4:] = 1  # two halves
        labels[0, 7] = 2  # and one pixel
        true_k = np.zeros((4, 8), dtype=np.int64)
        true_k[:, 4:] = 2
        k = np.zeros((4, 8), dtype=np.int64)  # the right half two periods low, the lone pixel too
        moved, count, share = learned_regions.oracle_levels(k, true_k, labels, 3, min_share=0.1)
        expected = true_k.copy()
        expected[0, 7] = 0  # too small to move
        assert np.array_equal(moved, expected) and count == 2 and share == 31 / 32


class TestLearnedScales:
    def test_long_pairs_with_true_jumps_restore_the_truth(self) -> None:
        from research import learned_scales

        truth = (np.arange(12)[:, None] * 90 + np.arange(10)[None, :] * 70).astype(np.int64)  # long steps > P/2
        m = truth % 256
        pairs = []
        for step in (1, 2):
            t, mm = truth[::step, ::step], m[::step, ::step]
            jump = np.zeros((2, *t.shape), dtype=np.int64)  # the true jumps: n = (dI - wrap(dI_m)) / 256
            for d, (a, b) in enumerate(((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :]))):
                diff = mm[b] - mm[a]
                jump[d][a] = (t[b] - t[a] - (np.mod(diff + 128, 256) - 128)) // 256
            cost = np.full((2, *t.shape), 2.0 if step == 1 else 1.0)
            pairs += learned_scales.long_pairs(mm, jump, cost, step, 10)
        k = learned_scales.decode_pairs(120, pairs).reshape(12, 10)
        assert np.array_equal(m + 256 * k, truth - 256 * (truth[0, 0] // 256))
        # the same pair twice: the cheaper one is kept, whichever end comes first
        wrong = (np.array([1]), np.array([0]), np.array([5]), np.array([0.5]))  # k_0 - k_1 = 5
        right = (np.array([0]), np.array([1]), np.array([2]), np.array([0.1]))  # k_1 - k_0 = 2
        assert learned_scales.decode_pairs(2, [wrong]).tolist() == [0, -5]
        for order in ([wrong, right], [right, wrong]):
            assert learned_scales.decode_pairs(2, order).tolist() == [0, 2]

    def test_shift_regions_follows_the_coarse_levels(self) -> None:
        from research import learned_scales

        labels = np.zeros((4, 8), dtype=np.int64)
        labels[:, 5:] = 1
        k = np.zeros((4, 8), dtype=np.int64)
        coarse = np.full((4, 8), 3, dtype=np.int64)  # one constant off everywhere ...
        coarse[:, 5:] = 5  # ... and the right region two more
        moved = learned_scales.shift_regions(k, coarse, labels, 2, 0.01, None)
        assert (moved[:, :5] == 0).all() and (moved[:, 5:] == 2).all()
        kept = learned_scales.shift_regions(k, coarse, labels, 2, 0.01, np.array([True, False]))
        assert (kept == 0).all()


class TestLearnedEnsemble:
    def test_mean_of_log_probabilities(self) -> None:
        from research import learned_ensemble

        a = torch.log_softmax(torch.randn(1, 2, 5, 3, 4, generator=torch.Generator().manual_seed(0)), dim=2)
        assert torch.allclose(learned_ensemble.mean_logp([a, a]), a, atol=1e-6)  # agreeing runs: unchanged
        b = a.flip(2)  # a second run that puts the same beliefs on the mirrored jumps
        mean = learned_ensemble.mean_logp([a, b])
        assert torch.allclose(mean.exp().sum(dim=2), torch.ones(1, 2, 3, 4), atol=1e-6)
        assert torch.allclose(mean, mean.flip(2), atol=1e-6)  # the product of experts is symmetric
        c = torch.log_softmax(torch.randn(1, 2, 5, 3, 4, generator=torch.Generator().manual_seed(1)), dim=2)
        product = torch.log_softmax((a + c) / 2, dim=2)  # a product of experts, not a mixture of probabilities
        assert torch.allclose(learned_ensemble.mean_logp([a, c]), product, atol=1e-6)
