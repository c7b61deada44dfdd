"""Inputs and operator table shared by the tone-mapping tests (tests/tonemap/)."""

from __future__ import annotations

import numpy as np
import torch

from torch_modulo.tonemap import tonemap_clahe, tonemap_gamma, tonemap_histogram, tonemap_log, tonemap_reinhard

LUMA = np.array([0.2126, 0.7152, 0.0722])


def hdr(shape: tuple[int, ...], seed: int = 0, stops: float = 16.0, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Log-uniform radiance spanning ``stops`` stops, with some colour."""
    gen = torch.Generator().manual_seed(seed)
    return torch.exp2(torch.rand(shape, generator=gen, dtype=torch.float64) * stops - stops / 2).to(dtype)


OPERATORS = {
    "histogram": lambda x: tonemap_histogram(x),
    "reinhard": lambda x: tonemap_reinhard(x),
    "gamma": lambda x: tonemap_gamma(x, percentile=99.0),
    "log": lambda x: tonemap_log(x),
    "clahe": lambda x: tonemap_clahe(x, grid_size=(2, 2)),
}
GLOBAL = ["histogram", "reinhard", "gamma", "log"]


LUMINANCE_BASED = ["histogram", "reinhard", "log", "clahe"]
