"""Tests for research.contraction: the paper's moves on contracted region graphs."""

from __future__ import annotations

import numpy as np
import pytest

from research.contraction import contract_regions, solve_contracted, solve_fast_contracted
from torch_modulo.singleshot.energy import EnergyParams
from torch_modulo.singleshot.graphcut import MoveStats, plane_energy
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


def test_fast_contracted_recovers_a_smooth_scene() -> None:
    # What tests/singleshot/test_unwrap_single.py checked as unwrap_single(method="fast", contract=True).
    y, x = np.mgrid[0:64, 0:64].astype(np.float64)
    bump = np.exp(-((y - 40) ** 2 + (x - 36) ** 2) / (2 * 17 * 17))
    truth = np.floor(1 + np.maximum(0, 12 * x + 10 * y + 16 * ((x + y) // 12) + 1500 * bump - 150)).astype(np.int64)
    assert np.array_equal(solve_fast_contracted(truth % 256), truth)
