"""Tests for the graph-cut machinery of torch_modulo.singleshot.graphcut."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from torch_modulo.singleshot.anchor import anchor_k
from torch_modulo.singleshot.energy import EnergyParams, potential_np
from torch_modulo.singleshot.graphcut import (
    MoveStats,
    PairTerms,
    move_delta_e,
    pixel_move,
    plane_energy,
    solve_fast,
    solve_pixels,
    solve_windows,
)
from torch_modulo.singleshot.grid import pair_offsets

P8 = EnergyParams.make(8)
OFF8 = pair_offsets(8)


def smooth_scene(h: int, w: int, seed: int, peak: float = 3000.0) -> np.ndarray:
    """Integer counts of a smooth scene (two Gaussian bumps on a ramp) with a dark corner at k = 0.

    The bumps are kept gentle enough (steepest step below about 100 counts per pixel) that the true image is
    what the energy prefers.
    """
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    sigma = 0.25 * max(h, w)
    peak = min(peak, 100.0 * sigma)
    img = 20 + 3 * x
    for _ in range(2):
        cy, cx = rng.uniform(0.4, 0.6) * h, rng.uniform(0.4, 0.6) * w
        img += peak * np.exp(-((y - cy) ** 2 + (x - cx) ** 2) / (2 * sigma**2))
    return np.floor(img).astype(np.int64)


def all_moves(n: int) -> np.ndarray:
    return np.array(list(itertools.product((0, 1), repeat=n)), dtype=bool)


class TestPixelMove:
    @pytest.mark.parametrize("seed", range(6))
    def test_energy_change_is_exact_and_never_positive(self, seed: int) -> None:
        rng = np.random.default_rng(seed)
        restored = rng.integers(0, 1024, (5, 6))
        for step in (1, 2):
            delta, delta_e = pixel_move(restored, P8, OFF8, step, int(restored.max() - restored.min()))
            moved = restored + step * 256 * delta
            assert delta_e == pytest.approx(plane_energy(moved, P8, OFF8) - plane_energy(restored, P8, OFF8))
            assert delta_e <= 1e-9

    @pytest.mark.parametrize("seed", range(4))
    def test_exact_minimum_when_every_term_is_representable(self, seed: int) -> None:
        # With x0 beyond every difference V is convex, every pair term is representable, and the cut must find
        # the true minimum of the move over all 2^n labellings.
        p = EnergyParams.make(8, x0=1e6)
        rng = np.random.default_rng(seed)
        restored = rng.integers(0, 900, (3, 4))
        delta, delta_e = pixel_move(restored, p, OFF8, 1, int(restored.max() - restored.min()))
        base = plane_energy(restored, p, OFF8)
        best = min(plane_energy(restored + 256 * d.reshape(3, 4), p, OFF8) - base for d in all_moves(restored.size))
        assert delta_e == pytest.approx(best, abs=1e-9)

    def test_four_neighbourhood(self) -> None:
        restored = np.array([[250, 5, 10], [252, 3, 12]])
        delta, delta_e = pixel_move(restored, P8, pair_offsets(4), 1, int(restored.max() - restored.min()))
        # Lifting the right two columns removes the fringe: 0.1 * |245 - 256| per crossing pair.
        assert delta_e < 0
        assert plane_energy(restored + 256 * delta, P8, pair_offsets(4)) < plane_energy(restored, P8, pair_offsets(4))


class TestSolvePixels:
    def test_recovers_smooth_scene(self) -> None:
        truth = smooth_scene(24, 20, seed=0)
        stats = MoveStats()
        restored = solve_pixels(truth % 256, P8, OFF8, stats=stats)
        k = anchor_k((restored - truth % 256) // 256)
        assert np.array_equal(truth % 256 + 256 * k, truth)
        assert stats.stop == "converged"
        assert stats.iterations == len(stats.energies) - 1 > 0

    def test_energy_never_increases(self) -> None:
        rng = np.random.default_rng(3)
        modulus = rng.integers(0, 256, (16, 16))
        stats = MoveStats()
        solve_pixels(modulus, P8, OFF8, stats=stats)
        assert all(b < a for a, b in zip(stats.energies, stats.energies[1:], strict=False))

    def test_max_iter_and_rel_tol(self) -> None:
        truth = smooth_scene(16, 16, seed=1)
        stats = MoveStats()
        solve_pixels(truth % 256, P8, OFF8, max_iter=2, stats=stats)
        assert stats.cuts == 2 and stats.stop == "max_iter"
        stats = MoveStats()
        solve_pixels(truth % 256, P8, OFF8, rel_tol=0.5, stats=stats)
        assert stats.stop == "rel_tol" and stats.iterations >= 1

    def test_does_not_modify_input(self) -> None:
        modulus = smooth_scene(8, 8, seed=2) % 256
        before = modulus.copy()
        solve_pixels(modulus, P8, OFF8)
        assert np.array_equal(modulus, before)


class TestMoveDeltaE:
    def test_matches_energy_difference(self) -> None:
        rng = np.random.default_rng(4)
        restored = rng.integers(0, 2000, (7, 9))
        moved = rng.random((7, 9)) < 0.3
        for shift in (256, -512):
            expected = plane_energy(restored + shift * moved, P8, OFF8) - plane_energy(restored, P8, OFF8)
            assert move_delta_e(restored, moved, shift, P8, OFF8) == pytest.approx(expected)


class TestSolveTiles:
    def test_never_raises_energy_and_stays_integral(self) -> None:
        rng = np.random.default_rng(5)
        start = rng.integers(0, 256, (20, 24)) + 256 * rng.integers(0, 3, (20, 24))
        stats = MoveStats()
        out = solve_windows(start, P8, OFF8, window=8, stats=stats)
        assert plane_energy(out, P8, OFF8) <= plane_energy(start, P8, OFF8)
        assert np.array_equal(out % 256, start % 256)
        assert stats.energies[-1] == pytest.approx(plane_energy(out, P8, OFF8))
        assert all(b < a for a, b in zip(stats.energies, stats.energies[1:], strict=False))

    def test_fixes_local_errors(self) -> None:
        truth = smooth_scene(24, 24, seed=6)
        broken = truth.copy()
        broken[5:8, 5:8] += 256  # a small island one rollover too high: only a down move fixes it in a window
        out = solve_windows(broken, P8, OFF8, window=8)
        assert np.array_equal(out, truth)


class TestSolveFast:
    def test_windows_only_after_an_early_stop(self) -> None:
        truth = smooth_scene(16, 16, seed=1)
        converged = MoveStats()
        out = solve_fast(truth % 256, P8, OFF8, rel_tol=0.0, stats=converged)
        assert converged.stop == "converged" and "windows" not in converged.seconds
        assert np.array_equal(out, solve_pixels(truth % 256, P8, OFF8))
        early = MoveStats()
        solve_fast(truth % 256, P8, OFF8, rel_tol=0.5, window=8, stats=early)
        assert early.stop == "rel_tol" and "windows" in early.seconds

    def test_energy_never_increases(self) -> None:
        rng = np.random.default_rng(8)
        stats = MoveStats()
        out = solve_fast(rng.integers(0, 256, (16, 16)), P8, OFF8, window=8, stats=stats)
        assert stats.energies[-1] == pytest.approx(plane_energy(out, P8, OFF8))
        assert all(b < a for a, b in zip(stats.energies, stats.energies[1:], strict=False))


class TestPairTerms:
    @pytest.mark.parametrize("span", [300, 1 << 22])
    def test_table_and_direct_terms_agree(self, span: int) -> None:
        d = np.array([-300, -128, 0, 5, 200, 300])
        terms = PairTerms(P8, 1, span, 1)
        assert terms.table == (span == 300)
        a, b = terms.ab(terms.index(d.copy()))
        assert np.allclose(a, potential_np(d + 256, P8) - potential_np(d, P8))
        assert np.allclose(b, potential_np(d - 256, P8) - potential_np(d, P8))
        cij, cji, m = terms.graph_terms(terms.index(d.copy()))
        assert np.allclose((cij, cji, m), PairTerms.decompose(a, b))
