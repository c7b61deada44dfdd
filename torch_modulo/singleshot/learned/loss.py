"""The training loss of the learned method's edge network: targets from true counts, weighted cross-entropy.

The recipe that made the shipped weights (``references/learned_single``) trains the edge network
(:class:`~torch_modulo.singleshot.learned.EdgeJumpNet`) with :func:`edge_loss` against :func:`edge_targets`.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from torch_modulo.singleshot.learned.network import wrap_difference

__all__ = ["edge_loss", "edge_targets"]


def edge_targets(counts: torch.Tensor, bits: int, max_jump: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Jump classes of the true counts and a mask of the pairs whose wrapped step is wrong.

    Args:
        counts: (B, C, H, W) true counts.
        bits: the sensor bit depth ``N``.
        max_jump: ``J``; jumps beyond it are clipped to ``+-J``.

    Returns:
        ``(target, hard)``: (B, C, 2, H, W) int64 classes ``n + J`` (direction 0: to the right neighbour, 1: to the
        one below; the last column / row, which has no neighbour, holds ``J``) and a bool mask of ``n != 0``.

    Example:
        >>> target, hard = edge_targets(torch.tensor([[[[10.0, 300.0, 310.0]]]]), 8, 2)
        >>> target[0, 0, 0].tolist(), hard[0, 0, 0].tolist()
        ([[3, 2, 2]], [[True, False, False]])
    """
    period = float(2**bits)
    c = counts.double()
    m = torch.remainder(c, period)
    out = []
    for dim in (-1, -2):
        d = torch.diff(c, dim=dim)
        wd = wrap_difference(torch.diff(m, dim=dim), period)
        n = torch.round((d - wd) / period).clamp(-max_jump, max_jump).long() + max_jump
        pad = (0, 1) if dim == -1 else (0, 0, 0, 1)
        out.append(F.pad(n, pad, value=max_jump))
    target = torch.stack(out, dim=2)
    return target, target != max_jump


def edge_loss(logits: torch.Tensor, target: torch.Tensor, hard_weight: float = 5.0) -> torch.Tensor:
    """Cross-entropy of (B, 3, 2, 2J + 1, H, W) logits against :func:`edge_targets` classes (B, 3, 2, H, W).

    Pairs whose wrapped step is wrong (class ``!= J``) weigh ``hard_weight``; the others 1. The last column's
    horizontal and the last row's vertical pairs (no neighbour) are left out.
    """
    j = (logits.shape[3] - 1) // 2
    ce = F.cross_entropy(logits.movedim(3, 1), target, reduction="none")
    weight = 1.0 + (hard_weight - 1.0) * (target != j).float()
    weight[:, :, 0, :, -1] = 0.0
    weight[:, :, 1, -1, :] = 0.0
    return (ce * weight).sum() / weight.sum().clamp_min(1.0)
