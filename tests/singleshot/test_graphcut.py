"""Tests for the graph-cut machinery of torch_modulo.singleshot.graphcut and the initial estimate of init.py."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from torch_modulo.singleshot.energy import EnergyParams, pair_offsets
from torch_modulo.singleshot.graphcut import (
    MoveStats,
    _pixel_move,
    _span,
    anchor_k,
    contract_regions,
    move_delta_e,
    plane_energy,
    solve_contracted,
    solve_pixels,
    solve_tiles,
)
from torch_modulo.singleshot.init import quality_guided_k, residue_density, wrapped_difference

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
            delta, delta_e = _pixel_move(restored, P8, OFF8, step, _span(restored))
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
        delta, delta_e = _pixel_move(restored, p, OFF8, 1, _span(restored))
        base = plane_energy(restored, p, OFF8)
        best = min(plane_energy(restored + 256 * d.reshape(3, 4), p, OFF8) - base for d in all_moves(restored.size))
        assert delta_e == pytest.approx(best, abs=1e-9)

    def test_four_neighbourhood(self) -> None:
        restored = np.array([[250, 5, 10], [252, 3, 12]])
        delta, delta_e = _pixel_move(restored, P8, pair_offsets(4), 1, _span(restored))
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
        out = solve_tiles(start, P8, OFF8, tile=8, stats=stats)
        assert plane_energy(out, P8, OFF8) <= plane_energy(start, P8, OFF8)
        assert np.array_equal(out % 256, start % 256)
        assert stats.energies[-1] == pytest.approx(plane_energy(out, P8, OFF8))
        assert all(b < a for a, b in zip(stats.energies, stats.energies[1:], strict=False))

    def test_fixes_local_errors(self) -> None:
        truth = smooth_scene(24, 24, seed=6)
        broken = truth.copy()
        broken[5:8, 5:8] += 256  # a small island one rollover too high: only a down move fixes it in a tile
        out = solve_tiles(broken, P8, OFF8, tile=8)
        assert np.array_equal(out, truth)


class TestContraction:
    def test_regions_and_band(self) -> None:
        restored = np.array([[0, 1, 2, 300, 301], [0, 1, 2, 300, 301]])
        n, labels = contract_regions(restored, 64, OFF8, band=0)
        assert n == 2 and len(set(labels[:, :3].ravel())) == 1 and len(set(labels[:, 3:].ravel())) == 1
        n_band, labels_band = contract_regions(restored, 64, OFF8, band=1)
        # Columns 2 and 3 touch the other region: each of their 4 pixels is a node of its own.
        assert n_band == 2 + 4
        assert len(set(labels_band[:, 2:4].ravel())) == 4

    def test_contracted_moves_lower_energy_exactly(self) -> None:
        truth = smooth_scene(20, 20, seed=7)
        stats = MoveStats()
        out = solve_contracted(truth % 256, P8, OFF8, link=128, band=1, stats=stats)
        assert stats.energies[-1] == pytest.approx(plane_energy(out, P8, OFF8))
        assert stats.energies[-1] < stats.energies[0]
        assert all(b < a for a, b in zip(stats.energies, stats.energies[1:], strict=False))


class TestAnchor:
    def test_darkest_large_region_is_zero(self) -> None:
        k = np.full((40, 40), 3)
        k[:20] = 5
        k[0, 0] = 1  # a lone noisy pixel two levels below: it must not anchor the image
        out = anchor_k(k, min_fraction=0.01)
        assert out[30, 30] == 0 and out[10, 10] == 2 and out[0, 0] == 0
        assert out.min() == 0

    def test_small_images_anchor_on_minimum(self) -> None:
        assert anchor_k(np.array([[2, 3], [4, 2]])).tolist() == [[0, 1], [2, 0]]

    def test_empty(self) -> None:
        assert anchor_k(np.zeros((0, 3), dtype=np.int64)).shape == (0, 3)

    @staticmethod
    def _scene(patch_counts: float) -> tuple[np.ndarray, np.ndarray]:
        """A 50 x 50 ramp at 780-829 counts (k = 3) with a 6 x 6 patch (1.4% of the pixels) at ``patch_counts``."""
        _, x = np.mgrid[0:50, 0:50]
        counts = (780 + x).astype(np.int64)
        counts[5:11, 5:11] = patch_counts + x[5:11, 5:11]
        return counts // 256, counts % 256

    def test_small_region_with_steep_border_does_not_anchor(self) -> None:
        # A 1.4% patch 3 levels below the rest, with steep borders all round: what a solver that put a bright
        # region too low leaves behind. With the modulus the border test rejects it; the 0.1% rule alone takes it.
        k, modulus = self._scene(200)
        assert k[7, 7] == 0 and k[30, 30] == 3
        out = anchor_k(k, modulus=modulus, bits=8)
        assert out[30, 30] == 0 and out[7, 7] == 0  # the bulk at k = 0, the patch clipped to 0
        assert anchor_k(k)[30, 30] == 3

    def test_small_region_with_smooth_border_anchors(self) -> None:
        # The same patch, but its border steps stay under half a period: a true dark region, it anchors.
        k, modulus = self._scene(700)
        assert k[7, 7] == 2 and k[30, 30] == 3
        assert anchor_k(k, modulus=modulus, bits=8)[30, 30] == 1
        assert anchor_k(k, modulus=modulus, bits=8, large_fraction=0.01)[30, 30] == 1

    def test_large_region_anchors_whatever_its_border(self) -> None:
        k, modulus = self._scene(200)
        assert anchor_k(k, modulus=modulus, bits=8, large_fraction=0.01)[30, 30] == 3

    def test_falls_back_to_the_lowest_level_with_a_region(self) -> None:
        # Every region is small and steep-bordered (4 x 4 blocks on 5 levels, a 32-pixel region on the top level):
        # no level passes the tests, and the lowest level with a 0.1% region anchors, as without the modulus,
        # rather than the level of the largest region (which would clip most of the image to k = 0).
        y, x = np.mgrid[0:64, 0:64]
        k = ((y // 4) + (x // 4)) % 5
        k[0:4, 0:8] = 4
        modulus = np.full(k.shape, 100)
        out = anchor_k(k, modulus=modulus, bits=8)
        assert np.array_equal(out, anchor_k(k)) and np.array_equal(out, k - k.min())

    def test_modulus_needs_bits(self) -> None:
        with pytest.raises(ValueError, match="bits"):
            anchor_k(np.zeros((3, 3), dtype=np.int64), modulus=np.zeros((3, 3)))


class TestQualityGuided:
    def test_wrapped_difference(self) -> None:
        d = np.array([-300, -128, -1, 0, 127, 128, 255])
        assert wrapped_difference(d, 256).tolist() == [-44, -128, -1, 0, 127, -128, -1]

    @pytest.mark.parametrize("seed", range(3))
    def test_recovers_smooth_scene_up_to_offset(self, seed: int) -> None:
        truth = smooth_scene(30, 25, seed=seed)
        k = quality_guided_k(truth % 256, 8)
        diff = truth // 256 - k
        assert np.all(diff == diff.flat[0])

    def test_single_pixel(self) -> None:
        assert quality_guided_k(np.array([[7]]), 8).tolist() == [[0]]

    def test_residue_density(self) -> None:
        assert residue_density(smooth_scene(20, 20, seed=0) % 256, 8) == 0.0
        # One 2 x 2 loop whose wrapped differences go 0 -> 100 -> 200 -> 44 (= 300) -> 0 does not close.
        loop = np.array([[0, 100], [44, 200]])
        assert residue_density(loop, 8) == 1.0
        assert residue_density(np.zeros((1, 5)), 8) == 0.0
