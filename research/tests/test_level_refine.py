"""Unit tests of research/level_refine.py on small synthetic planes (no scene files needed)."""

from __future__ import annotations

import numpy as np
import torch

from research import level_refine
from torch_modulo.singleshot.learned import BAND, SLOTS


def _halves() -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """(1, 6, 8) moduli whose right half is a period above the left, the true k, and a first pass that put the right
    half a period too low: sure pairs inside the halves, every jump of the band equally likely across the border."""
    truth = np.full((1, 6, 8), 100, dtype=np.int64)
    truth[..., 4:] += 256 + 30
    m = truth % 256
    table = np.full((1, 2, 2 * BAND + 1, 6, 8), 30.0, dtype=np.float32)
    table[:, :, BAND] = 0.0
    table[:, 0, :, :, 3] = 1.6
    jump = np.zeros((1, 2, 6, 8), dtype=np.int16)
    k = np.zeros((1, 6, 8), dtype=np.int64)
    first = {"k": k, "table": table, "first": jump.astype(np.int64) - BAND}
    first["taken"] = level_refine.taken_cost(m, k, table, first["first"])
    return m, truth // 256, first


def test_taken_cost_is_the_dearest_jump_at_each_pixel() -> None:
    m, k_true, first = _halves()
    taken = first["taken"][0]
    assert np.all(taken[:, 3:5] == np.float32(1.6)) and np.all(taken[:, :3] == 0) and np.all(taken[:, 5:] == 0)
    # the truth takes jump 1 across the border: also within the band there, and sure everywhere else
    table = first["table"].copy()
    table[0, 0, :, :, 3] = np.array([30, 30, 30, 0.2, 30])[:, None]
    again = level_refine.taken_cost(m, k_true, table, first["first"])[0]
    assert np.all(again[:, 3:5] == np.float32(0.2)) and again[:, :3].max() == 0
    # a jump outside the band costs 30
    far = level_refine.taken_cost(m, k_true + np.arange(8) // 4 * 5, first["table"], first["first"])
    assert np.all(far[0, :, 3:5] == 30)


def test_second_pass_moves_the_region_the_corrections_point_at() -> None:
    m, k_true, first = _halves()
    costs = np.full((1, level_refine.CLASSES, 6, 8), 5.0, dtype=np.float32)
    costs[0, level_refine.REACH, :, :4] = 0.0  # the left half is right ...
    costs[0, level_refine.REACH + 1, :, 4:] = 0.0  # ... the right one a period low
    k = level_refine.second_pass(m, first, costs)
    assert np.array_equal(k - k.min(), k_true - k_true.min())
    # corrections that prefer no change change nothing
    costs[...] = 5.0
    costs[0, level_refine.REACH] = 0.0
    assert np.array_equal(level_refine.second_pass(m, first, costs), first["k"])


def test_batch_of_masks_the_slots_a_grey_sample_does_not_have() -> None:
    rng = np.random.default_rng(0)
    grey = {
        "moduli": torch.randint(0, 256, (1, 40, 52), dtype=torch.uint8),
        "k": torch.zeros(1, 40, 52, dtype=torch.int16),
        "taken": torch.zeros(1, 40, 52, dtype=torch.float16),
        "delta": torch.full((1, 40, 52), 7, dtype=torch.int8),
    }
    x, y, mask = level_refine.batch_of([grey], 48, 3, rng)
    assert x.shape == (3, 7 * SLOTS, 48, 48) and y.shape == mask.shape == (3, SLOTS, 48, 48)
    assert int(y.max()) == 2 * level_refine.REACH  # clipped to the largest correction
    assert torch.all(mask[:, 1:] == 0) and torch.all(mask[:, 0].sum(dim=(1, 2)) == 40 * 48)


def test_refine_net_gives_correction_logits_per_slot() -> None:
    net = level_refine.RefineNet(width=4, dilations=(1, 2))
    assert net(torch.zeros(2, 7 * SLOTS, 16, 12)).shape == (2, SLOTS, level_refine.CLASSES, 16, 12)
