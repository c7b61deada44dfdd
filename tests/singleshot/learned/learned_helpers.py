"""Shared helpers of the learned method's tests: a scene with a lamp, a spec, the jump log-probabilities of the
truth."""

from __future__ import annotations

import numpy as np
import torch

from torch_modulo.singleshot.learned import edge_targets
from torch_modulo.singleshot.methods import make_spec


def scene(size: int = 48, seed: int = 0) -> np.ndarray:
    """(size, size) counts: a dark floor, a smooth bump and a bright lamp whose border steps by several periods."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    img = 20 + 8 * x + 600 * np.exp(-((y - size / 2) ** 2 + (x - size / 3) ** 2) / (size * size / 8))
    lamp = (np.abs(y - 0.7 * size) < size / 8) & (np.abs(x - 0.7 * size) < size / 8)
    img = img + 1500 * lamp + rng.uniform(0, 3, img.shape)
    return np.floor(img)


def spec(method: str, **options: object):
    """unwrap_single's settings for ``method`` with its defaults and these options."""
    return make_spec(8, method, 8, 0.1, 1e-5, None, 2, 1000, options)


def oracle_logp(counts: np.ndarray, max_jump: int = 15) -> np.ndarray:
    """(2, 2J + 1, H, W) log-probabilities that are sure of the true jump of every pair."""
    target, _ = edge_targets(torch.from_numpy(counts)[None, None], 8, max_jump)
    logp = np.full((2, 2 * max_jump + 1, *counts.shape), -20.0)
    np.put_along_axis(logp, target[0, 0].numpy()[:, None], 0.0, axis=1)
    return logp
