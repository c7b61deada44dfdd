"""Exposure stacks shared by the multi-shot decoders and the intensity merge: shapes, exposures, sorting, ratios."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from torch_modulo._checks import check_floating, exposure_tensor

__all__ = ["neighbour_ratios", "sort_stack", "stack_exposures", "wide_dtype"]


def wide_dtype(device: torch.device) -> torch.dtype:
    """The dtype the noise-aware decoding and merge compute in: float64 where the device has it (CPU, CUDA), else
    float32 (MPS, for one)."""
    return torch.float64 if device.type in ("cpu", "cuda") else torch.float32


def stack_exposures(
    frames: torch.Tensor, exposures: Sequence[float] | torch.Tensor, name: str
) -> tuple[torch.Tensor, torch.Tensor, bool]:
    """Validate a (B, M, C, H, W) or (M, C, H, W) stack and its exposures.

    Returns the stack as (B, M, C, H, W), exposures as a float64 (B, M) tensor on the stack's device, and whether the
    input was unbatched.
    """
    check_floating(frames, name)
    if frames.dim() not in (4, 5):
        raise ValueError(f"{name} must have shape (B, M, C, H, W) or (M, C, H, W); got {tuple(frames.shape)}")
    unbatched = frames.dim() == 4
    stack = frames.unsqueeze(0) if unbatched else frames
    b, m = stack.shape[:2]
    if m < 1:
        raise ValueError(f"{name} must hold at least one exposure (M >= 1); got shape {tuple(frames.shape)}")
    tau = exposure_tensor(exposures, torch.empty(0, dtype=torch.float64, device=frames.device), "exposures")
    if tau.dim() == 1 and tau.shape[0] == m:
        tau = tau.expand(b, m)
    elif not (tau.dim() == 2 and tau.shape == (b, m)):
        raise ValueError(
            f"exposures must have shape (M,) = ({m},) or (B, M) = ({b}, {m}) for {name} of shape "
            f"{tuple(frames.shape)}; got {tuple(tau.shape)}"
        )
    return stack, tau, unbatched


def sort_stack(stack: torch.Tensor, tau: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Sort each batch item's exposures ascending, reordering frames only when needed."""
    tau_sorted, order = torch.sort(tau, dim=1, stable=True)
    if torch.compiler.is_compiling():  # no data-dependent shortcut in a traced graph
        index = order.view(*order.shape, 1, 1, 1).expand(-1, -1, *stack.shape[2:])
        return torch.take_along_dim(stack, index, dim=1), tau_sorted
    identity = torch.arange(tau.shape[1], device=tau.device).expand_as(order)
    if torch.equal(order, identity):
        return stack, tau_sorted
    if bool((order == order[:1]).all()):
        return stack[:, order[0]], tau_sorted
    index = order.view(*order.shape, 1, 1, 1).expand(-1, -1, *stack.shape[2:])
    return torch.take_along_dim(stack, index, dim=1), tau_sorted


def neighbour_ratios(tau: torch.Tensor, bits: int) -> torch.Tensor:
    """Neighbouring ratios tau[i] / tau[i - 1] of sorted exposures; refuse any above 2**bits."""
    ratios = tau[:, 1:] / tau[:, :-1]
    period = 2**bits
    if ratios.numel() and float(ratios.max()) > period:
        flat = int(ratios.argmax())
        b, i = divmod(flat, ratios.shape[1])
        raise ValueError(
            f"neighbouring exposure ratio {float(tau[b, i + 1])} / {float(tau[b, i])} = {float(ratios[b, i]):g} "
            f"exceeds 2^bits = {period} (batch item {b}): rollovers between these exposures cannot be counted; "
            "add an exposure in between"
        )
    return ratios
