"""Unit tests of research/level_errors.py on small synthetic planes (no scene files needed)."""

from __future__ import annotations

import numpy as np
import pytest

from research import level_errors
from torch_modulo.singleshot.learned import LEVELS


def _halves() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A plane whose right half is a period above its left, sure pairs inside the halves and unsure ones across:
    (moduli, true counts, table (2, 5, H, W), first jumps, level costs leaning to the truth)."""
    truth = np.full((6, 8), 100, dtype=np.int64)
    truth[:, 4:] += 256 + 30
    m = truth % 256
    table = np.full((2, 5, 6, 8), 30.0)
    table[:, 2] = 0.0  # sure of the wrapped step (jump 0) ...
    table[0, :, :, 3] = 1.6  # ... but across the border, where every jump of the band costs the same
    first = np.full((2, 6, 8), -2)
    u = np.full((LEVELS, 6, 8), 4.0, dtype=np.float16)
    np.put_along_axis(u, (truth // 256)[None], 0.5, axis=0)
    return m, truth, table, first, u


def test_oracle_puts_every_region_at_its_most_common_level() -> None:
    m, truth, table, first, u = _halves()
    count, labels = level_errors.regions(table, 0.01)
    assert count == 2
    k = level_errors.oracle(np.zeros_like(m), truth // 256, labels, count)
    assert np.array_equal(k, truth // 256)


def test_energy_counts_levels_and_pairs() -> None:
    m, truth, table, first, u = _halves()
    level, pair = level_errors.energy(m, truth // 256, table, first, u)
    assert level == pytest.approx(0.5 * m.size) and pair == pytest.approx(1.6 * 6)  # the border's six pairs
    level0, pair0 = level_errors.energy(m, np.zeros_like(m), table, first, u)
    assert level0 == pytest.approx(0.5 * 24 + 4.0 * 24) and pair0 == pytest.approx(1.6 * 6)


def test_plane_report_of_a_plane_the_moves_get_right() -> None:
    m, truth, table, first, u = _halves()
    out = level_errors.plane_report(m, np.zeros_like(m), table, first, u, truth)
    assert out["values"] == m.size and out["wrong"] == 0  # the level costs move the right half up
    assert out["oracle 0.01"] == m.size and out["head right"] == m.size and out["truth costs more"] == 0


def test_plane_report_counts_values_by_true_level_and_at_the_clip() -> None:
    m, truth, table, first, u = _halves()
    out = level_errors.plane_report(m, np.zeros_like(m), table, first, u, truth, peak=float(truth.max()))
    assert out["at k 0"] == out["at k 1"] == 24 and out["at k 2"] == 0
    assert out["right at k 0"] == out["right at k 1"] == 24  # the level costs move the right half up
    assert out["clipped"] == out["clipped right"] == 24  # the right half is at the peak
    # level costs that keep the right half down: one half is wrong (the halves tie in the alignment)
    flat = np.full_like(u, 4.0)
    flat[0] = 0.5
    out = level_errors.plane_report(m, np.zeros_like(m), table, first, flat, truth, peak=float(truth.max()))
    assert out["right at k 0"] + out["right at k 1"] == 24 and out["clipped right"] == out["right at k 1"]


def test_border_report_of_a_bright_region_put_a_period_low() -> None:
    # rows of 100 ... 100, 200, 300, 400: the last two values roll over once, through steps of 100 (below half a
    # period); a result of k = 0 everywhere puts them a period low, crossing the border with a jump of -1.
    truth = np.tile(np.array([100, 100, 100, 100, 100, 200, 300, 400]), (6, 1))
    m = truth % 256
    table = np.full((2, 5, 6, 8), 30.0)
    table[:, 2] = 0.0  # the network is sure of every wrapped step (jump 0: first + 2)
    first = np.full((2, 6, 8), -2)
    out = level_errors.border_report(m, np.zeros_like(m), table, first, truth)
    assert out["share"] == 0.25 and out["offset"] == -1
    assert out["pairs"] == 6 and out["net picks truth"] == 6 and out["net picks result"] == 0
    assert out["truth cost"] == 0.0 and out["result cost"] == 6 * 30.0
    assert out["small steps"] == out["small steps read"] == 6
    assert level_errors.border_report(m, truth // 256, table, first, truth) is None  # nothing wrong


def test_pair_jumps_are_the_whole_periods_beyond_the_wrapped_step() -> None:
    m = np.array([[200, 10]])
    right, down = level_errors.pair_jumps(m, np.array([[0, 1]]))
    assert right.tolist() == [[0]] and down.shape == (0, 2)  # 266 - 200 = 66: the wrapped step
    assert level_errors.pair_jumps(m, np.array([[0, 2]]))[0].tolist() == [[1]]
