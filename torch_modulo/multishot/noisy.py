r"""Noise-aware rollover counting: decode each frame only as far as the noise model says its count is determined.

Under noise the robust rule's prediction of the next count, ``r (I^(i-1) + 1/2)``, is off by the ratio ``r`` times
the previous frame's noise plus the new frame's own noise; once that spread nears half a period the rounding picks a
wrong rollover count, and every later frame inherits the error. This decoder walks each pixel's frames from the
shortest and keeps, from the :class:`~torch_modulo.noise.NoiseModel`, the variance of its running radiance
estimate. Frame ``i`` is decoded only while the predicted count's standard deviation,

.. math:: s_i = \sqrt{\tau_i^2 \operatorname{Var}(\hat E) + \operatorname{Var}(I^{(i)})},

stays within ``2^N / (2 z)`` (``z`` = ``sigmas``: the rounding is then wrong with probability about that of a
``z``-sigma Gaussian tail); from the first frame where it does not, the pixel's remaining frames are ignored (their
noise only grows with the exposure). The radiance is the inverse-variance weighted mean of the decoded frames'
estimates ``(I^{(i)} + 1/2) / \tau_i``, with every frame's variance evaluated at one common radiance (so a frame's
own noise does not set its weight), less the dark counts.
"""

from __future__ import annotations

import torch

from torch_modulo.multishot.stack import wide_dtype
from torch_modulo.noise import NoiseModel

__all__ = ["decode_noisy", "exposure_unit", "weighted_estimate"]


def decode_noisy(
    frames: torch.Tensor,
    tau: torch.Tensor,
    bits: int,
    noise: NoiseModel,
    sigmas: float = 3.0,
    return_counts: bool = False,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Decode a sorted exposure stack under ``noise``.

    It runs on each item's exposures divided by a power of two near their geometric middle (which changes no
    rounding; the dark counts follow the unit), so that exposures in any unit within float64's range decode, where
    ``tau^2`` alone would overflow or underflow.

    Args:
        frames: (B, M, n) moduli, exposures sorted ascending, integers in ``[0, 2**bits)``.
        tau: (B, M) exposures, ascending.
        bits: the bit depth ``N``.
        noise: the sensor's noise model.
        sigmas: ``z``, the gate on the predicted count's standard deviation in units of ``2**bits / 2``.
        return_counts: return the expected count at the longest exposure, ``tau_max E``, and its variance, instead
            of the radiance ``E``.

    Returns:
        ``(radiance, variance, used)``, each (B, n): the radiance estimate (counts per unit exposure, >= 0; or the
        counts), its variance from the noise model, and the number of frames decoded per pixel (the shortest is
        always used). Radiance and variance are float64 (float32 on devices without float64); they are ``inf`` where
        they are beyond its range.
    """
    work = wide_dtype(frames.device)
    x = frames.to(work)
    up, down = exposure_unit(tau, work)
    t = (tau.to(device=x.device, dtype=work) * down.unsqueeze(1)).unsqueeze(-1)  # (B, M, 1): tau / s
    m = x.shape[1]
    period = float(2**bits)
    gate = (period / (2.0 * sigmas)) ** 2

    counts = torch.full_like(x, float("nan"))  # decoded counts; NaN where a frame is not used
    counts[:, 0] = x[:, 0]  # the shortest exposure does not roll over
    estimate = (x[:, 0] + 0.5) / t[:, 0]
    weight = t[:, 0] ** 2 / noise.count_variance(x[:, 0] + 0.5)
    total = weight.clone()
    weighted = weight * estimate
    active = torch.ones_like(estimate, dtype=torch.bool)
    for i in range(1, m):
        predicted = t[:, i] * estimate - 0.5
        own = noise.count_variance(predicted + 0.5)
        spread = t[:, i] ** 2 / total + own
        active &= spread <= gate
        k = torch.round((predicted - x[:, i]) / period).clamp_min_(0.0)
        decoded = x[:, i] + k * period
        counts[:, i] = torch.where(active, decoded, counts[:, i])
        weight = torch.where(active, t[:, i] ** 2 / own, 0.0)  # the prediction's variance: independent of frame i
        total += weight
        weighted += weight * torch.where(active, (decoded + 0.5) / t[:, i], 0.0)
        estimate = weighted / total

    # Re-weight with every decoded frame's variance at the final estimate.
    used = torch.isfinite(counts)
    radiance, total = weighted_estimate(counts, used, t, estimate.unsqueeze(1), noise)
    variance = 1.0 / total
    up, down = up.unsqueeze(1), down.unsqueeze(1)
    if return_counts:  # tau_max (E - D) = (tau_max / s) (s E - s D): no unit enters
        longest = t[:, -1]
        radiance = (radiance - noise.dark_counts * up).clamp_min_(0.0) * longest
        return radiance, variance * (longest * longest), used.sum(dim=1)
    radiance = (radiance * down - noise.dark_counts).clamp_min_(0.0)
    return radiance, variance * down * down, used.sum(dim=1)


def exposure_unit(tau: torch.Tensor, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """Per batch item, the unit ``s`` the noise-aware decoder and merge work in, and ``1 / s``, each (B,) in ``dtype``.

    ``s`` is the power of two nearest the geometric middle of the item's shortest and longest exposure (sorted
    (B, M) ``tau``), so that scaling by it rounds nothing and ``(tau / s)^2`` stays within ``dtype``'s range.
    """
    exponent = torch.frexp(tau.to(dtype=dtype))[1].to(torch.int64)
    return _powers_of_two((exponent[:, 0] + exponent[:, -1]) // 2, dtype)


def _powers_of_two(exponent: torch.Tensor, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """``2**exponent`` and ``2**-exponent``, exactly, in ``dtype`` (float64 or float32), with the exponent clamped to
    the normal range (``torch.exp2`` is not exact)."""
    if dtype == torch.float64:
        e = exponent.clamp(-1022, 1022)
        return ((e + 1023) << 52).view(torch.float64), ((1023 - e) << 52).view(torch.float64)
    e = exponent.to(torch.int32).clamp(-126, 126)
    return ((e + 127) << 23).view(torch.float32), ((127 - e) << 23).view(torch.float32)


def weighted_estimate(
    counts: torch.Tensor, used: torch.Tensor, tau: torch.Tensor, reference: torch.Tensor, noise: NoiseModel
) -> tuple[torch.Tensor, torch.Tensor]:
    """The inverse-variance mean over the frames (dim 1) of their unbiased estimates ``(I + 1/2) / tau``.

    Each used frame weighs ``tau^2 / Var(I)``, its variance from ``noise`` at the common radiance ``reference``
    (so a frame's own noise does not set its weight). Shared by the noise-aware decoder and the noise-aware
    intensity merge.

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
