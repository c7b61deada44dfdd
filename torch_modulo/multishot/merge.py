"""The conventional multi-exposure HDR merge of clipped frames: the baseline the paper compares against (Sec. 5.2)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from torch_modulo._checks import check_bits, check_choice, check_modulus
from torch_modulo.multishot.noisy import exposure_unit
from torch_modulo.multishot.stack import sort_stack, stack_exposures, wide_dtype
from torch_modulo.noise import NoiseModel, as_noise_model

__all__ = ["IntensityMerge", "merge_intensity"]

WEIGHTS = ("binary", "hat")


def merge_intensity(
    frames: torch.Tensor,
    exposures: Sequence[float] | torch.Tensor,
    bits: int = 8,
    *,
    weights: str = "binary",
    noise: NoiseModel | str | None = None,
) -> torch.Tensor:
    """Conventional multi-exposure HDR merge of clipped frames: the baseline the paper compares against.

    Each frame gives the estimate ``I / tau`` (the same convention as Eq. 7). ``weights="binary"`` (the paper's
    Sec. 5.2 description) averages the estimates of frames that are neither under-exposed (``I = 0``) nor saturated
    (``I = 2**bits - 1``); ``weights="hat"`` uses Debevec and Malik's (1997) triangle ``min(I, 2**bits - 1 - I)``.
    A pixel with no usable frame takes the shortest exposure's estimate if it is saturated there (a lower bound)
    and otherwise the longest exposure's (0 for a pixel that is black everywhere).

    With the sensor's ``noise`` model the merge is the noise-optimal one instead (the fair baseline under noise):
    every unsaturated frame's unbiased estimate ``(I + 1/2) / tau`` is weighted by ``tau^2 / Var(I)``, with the
    variance from the noise model at one common radiance (that of the longest unsaturated frame), less the dark
    counts; ``weights`` is then ignored.

    Args:
        frames: intensity images (B, M, C, H, W) or (M, C, H, W), integers in ``[0, 2**bits)``.
        exposures: (M,) or (B, M), any order.
        bits: the sensor's bit depth.
        weights: ``"binary"`` or ``"hat"``.
        noise: the sensor's :class:`~torch_modulo.sensors.NoiseModel` (or a preset name) for the variance-weighted
            merge, or None.

    Returns:
        Radiance (B, C, H, W) or (C, H, W), same dtype and device as ``frames``. float16 and bfloat16 frames are
        merged in float32 (the noise-aware merge runs in float64, float32 on devices without it), so exposures
        beyond a half-precision range are fine; radiance beyond the range of ``frames``' dtype (above 65504 for
        float16) comes back as ``inf``.

    Example:
        >>> frames = torch.tensor([[[[10.0]]], [[[160.0]]], [[[255.0]]]])   # (M, C, H, W), 8 bits
        >>> merge_intensity(frames, [1.0, 16.0, 256.0], bits=8)
        tensor([[[10.]]])
    """
    check_choice(weights, "weights", WEIGHTS)
    stack, tau, unbatched = stack_exposures(frames, exposures, "frames")
    bits = check_bits(bits, frames.dtype)
    check_modulus(stack, bits, "frames")
    stack, tau = sort_stack(stack, tau)
    top = float(2**bits - 1)
    noise = as_noise_model(noise)
    if noise is not None:  # in float64 (float32 on devices without it), as unwrap_multi decodes
        out = _merge_noisy(stack.to(wide_dtype(frames.device)), tau, top, noise).to(frames.dtype)
        return out[0] if unbatched else out
    # Half precision is merged in float32: in float16 an exposure of 65536 is inf, which made every estimate of
    # that frame 0 (and 0 * inf a NaN). float32 and float64 stay as they are.
    work = torch.float32 if frames.dtype in (torch.float16, torch.bfloat16) else frames.dtype
    stack = stack.to(work)
    tau_b = tau.to(work).view(*tau.shape, 1, 1, 1)
    estimates = stack / tau_b
    if weights == "binary":
        w = ((stack > 0) & (stack < top)).to(work)
    else:
        w = torch.minimum(stack, top - stack)
    total = w.sum(dim=1)
    merged = (w * estimates).sum(dim=1) / total.clamp_min(torch.finfo(work).tiny)
    fallback = torch.where(stack[:, 0] >= top, estimates[:, 0], estimates[:, -1])
    out = torch.where(total > 0, merged, fallback).to(frames.dtype)
    return out[0] if unbatched else out


def _merge_noisy(stack: torch.Tensor, tau: torch.Tensor, top: float, noise: NoiseModel) -> torch.Tensor:
    """Inverse-variance merge of the unsaturated frames of a sorted stack (B, M, C, H, W), in the stack's dtype."""
    x = stack
    _, down = exposure_unit(tau, x.dtype)  # work in a unit where tau^2 stays in range (no rounding changes)
    t = (tau.to(x.dtype) * down.unsqueeze(1)).view(*tau.shape, 1, 1, 1)
    usable = x < top
    estimates = (x + 0.5) / t
    # The common radiance for the variances: the longest unsaturated frame's (the shortest's if all saturate).
    last = (usable * torch.arange(1, x.shape[1] + 1, device=x.device).view(1, -1, 1, 1, 1)).amax(dim=1, keepdim=True)
    reference = torch.gather(estimates, 1, (last - 1).clamp_min(0))
    merged, total = _weighted_estimate(x, usable, t, reference, noise)
    merged = torch.where(total > 0, merged, estimates[:, 0])  # saturated everywhere: a lower bound
    return (merged * down.view(-1, 1, 1, 1) - noise.dark_counts).clamp_min(0.0)


def _weighted_estimate(
    counts: torch.Tensor, used: torch.Tensor, tau: torch.Tensor, reference: torch.Tensor, noise: NoiseModel
) -> tuple[torch.Tensor, torch.Tensor]:
    """The inverse-variance mean over the frames (dim 1) of their unbiased estimates ``(I + 1/2) / tau``.

    Each used frame weighs ``tau^2 / Var(I)``, its variance from ``noise`` at the common radiance ``reference``
    (so a frame's own noise does not set its weight).

    Args:
        counts: (B, M, ...) counts (values where ``used`` is False are ignored, NaN included).
        used: which counts enter the mean, the shape of ``counts``.
        tau: the exposures, broadcastable to ``counts``.
        reference: the radiance the variances are evaluated at, broadcastable to ``counts``.
        noise: the sensor's noise model.

    Returns:
        ``(mean, total)``: the mean radiance (dark counts included) and the total weight, (B, ...); the mean is 0
        where no frame is used.
    """
    weight = torch.where(used, tau**2 / noise.count_variance(tau * reference), 0.0)
    total = weight.sum(dim=1)
    mean = (weight * torch.where(used, (counts + 0.5) / tau, 0.0)).sum(dim=1)
    return mean / total.clamp_min(torch.finfo(total.dtype).tiny), total


class IntensityMerge(nn.Module):
    """Module twin of :func:`merge_intensity` (the conventional-sensor baseline).

    Example:
        >>> IntensityMerge(bits=4)(torch.tensor([[[[15.0]]], [[[15.0]]]]), [1.0, 4.0])
        tensor([[[15.]]])
    """

    def __init__(self, bits: int = 8, weights: str = "binary", *, noise: NoiseModel | str | None = None) -> None:
        super().__init__()
        check_choice(weights, "weights", WEIGHTS)
        self.bits = check_bits(bits, torch.float64)
        self.weights = weights
        self.noise = as_noise_model(noise)

    def forward(self, frames: torch.Tensor, exposures: Sequence[float] | torch.Tensor) -> torch.Tensor:
        return merge_intensity(frames, exposures, self.bits, weights=self.weights, noise=self.noise)

    def extra_repr(self) -> str:
        return f"bits={self.bits}, weights={self.weights!r}, noise={self.noise}"
