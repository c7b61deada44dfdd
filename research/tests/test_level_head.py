"""Unit tests of research/level_head.py's decoder and head (no scene files, no trained weights needed)."""

from __future__ import annotations

import numpy as np
import torch

from research import level_head
from torch_modulo.singleshot.learned import EdgeJumpNet


def _two_halves() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A plane whose right half is one period above its left (a steep border), the tree's wrong k (0 everywhere),
    jump log-probabilities sure inside the halves and unsure across, and the head's costs."""
    truth = np.full((6, 8), 100, dtype=np.int64)
    truth[:, 4:] += 256 + 30  # k = 1 on the right: the wrapped step (+30) hides a period
    modulus = truth % 256
    logp = np.full((2, 5, 6, 8), -30.0)  # J = 2: jumps -2 .. 2
    logp[:, 2] = 0.0  # sure of the wrapped step everywhere...
    logp[0, :, :, 3] = np.log(1 / 5)  # ...but for the border pairs (column 3 -> 4): unsure
    u = np.full((level_head.LEVELS, 6, 8), 5.0)
    u[0][truth < 256] = 0.0
    u[1][truth >= 256] = 0.0
    return modulus, np.zeros((6, 8), dtype=np.int64), logp, u


def test_region_moves_put_a_region_at_the_level_the_head_says() -> None:
    modulus, tree, logp, u = _two_halves()
    k = level_head.region_moves(modulus, tree, logp, u, lam=1.0)
    assert np.array_equal(modulus + 256 * k, modulus + 256 * (np.arange(8) >= 4)[None, :].repeat(6, 0))
    assert np.array_equal(level_head.region_moves(modulus, tree, logp, u, lam=0.0), tree)  # no head, no move


def test_the_head_sees_the_networks_features() -> None:
    net, head = EdgeJumpNet(width=16, max_jump=3), level_head.LevelHead(cin=level_head.HEAD_INPUT)
    features, head_input = level_head.trunk_and_head_input(net, torch.zeros(2, 3, 8, 12))
    assert features.shape == (2, 16, 8, 12) and head(head_input).shape == (2, 3, level_head.LEVELS, 8, 12)


def test_level_loss_weighs_the_rolled_over_values() -> None:
    logits = torch.randn(2, 1, level_head.LEVELS, 3, 4, generator=torch.Generator().manual_seed(0))
    counts = torch.zeros(2, 1, 3, 4)
    counts[:, :, 0] = 700.0  # level 2 in the first row
    plain = level_head.level_loss(logits, counts)
    assert torch.allclose(level_head.level_loss(logits, counts, 1.0), plain)
    each = torch.nn.functional.cross_entropy(
        logits.permute(0, 1, 3, 4, 2).reshape(-1, level_head.LEVELS),
        (counts // 256).long().reshape(-1),
        reduction="none",
    )
    rolled = (counts >= 256).reshape(-1)
    expect = (3 * each[rolled].sum() + each[~rolled].sum()) / (3 * rolled.sum() + (~rolled).sum())
    assert torch.allclose(level_head.level_loss(logits, counts, 3.0), expect)
