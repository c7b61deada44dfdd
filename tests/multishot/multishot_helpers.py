"""Shared helpers of the multi-shot tests: random scenes and noise-free exposure stacks."""

from __future__ import annotations

import torch

import torch_modulo as tm


def scene(shape: tuple[int, ...], stops: float, seed: int = 0, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Random radiance spanning ``stops`` stops below 1 (so exposure 2**stops gives up to 2**stops counts)."""
    gen = torch.Generator().manual_seed(seed)
    return torch.exp2(-torch.rand(shape, generator=gen, dtype=torch.float64) * stops).to(dtype)


def stack(radiance: torch.Tensor, taus: list[float], bits: int) -> torch.Tensor:
    return torch.stack([tm.capture_modulo(radiance, t, bits) for t in taus], dim=-4)


def ratios_to_taus(ratios: list[float]) -> list[float]:
    taus = [1.0]
    for r in ratios:
        taus.append(taus[-1] * r)
    return taus
