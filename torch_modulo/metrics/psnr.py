"""PSNR on linear values with a given peak, and PSNR on log radiance relative to the reference's peak."""

from __future__ import annotations

import math

import torch
from torch import nn

from torch_modulo._checks import check_finite, check_real
from torch_modulo.metrics._common import (
    POSITIVE,
    check_eps,
    float_pair,
    image_pair,
    log_relative,
    nonnegative_pair,
    psnr_bchw,
    reference_peak,
)

__all__ = ["PSNR", "PSNRLog", "psnr", "psnr_log"]


def psnr(x: torch.Tensor, y: torch.Tensor, peak: float) -> torch.Tensor:
    """Peak signal-to-noise ratio per batch item, over all channels: ``10 log10(peak^2 / MSE)`` in dB.

    The benchmark scores restored counts against the true counts with ``peak = 2^12 - 1 = 4095`` (protocol A).
    The metric is symmetric in ``x`` and ``y``; identical images give ``+inf``.

    Args:
        x: an image, ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        y: the reference, same shape.
        peak: the largest possible value (the data range), a positive number.

    Returns:
        ``(B,)`` PSNR in dB, in the floating dtype of the inputs; ``(1,)`` for unbatched inputs. Computed in
        float64, so values near the dtype's limits, and tiny or huge values that differ, give finite scores.

    Raises:
        TypeError: an input is not a real tensor, or ``peak`` is not a number.
        ValueError: shapes differ, a value is NaN or infinite, an image is empty, or ``peak`` is not positive.

    Example:
        >>> x = torch.tensor([[0.0, 2.0], [0.0, 0.0]])
        >>> psnr(x, torch.zeros(2, 2), peak=1.0)  # MSE = 4 / 4 = 1: 10 log10(1 / 1)
        tensor([0.])
        >>> psnr(x, x, peak=1.0)
        tensor([inf])
    """
    xb, yb = image_pair(x, y, ("x", "y"))
    peak = check_real(peak, "peak", positive=True, what=POSITIVE)
    check_finite(xb, "x")
    check_finite(yb, "y")
    if xb.shape[0] and xb[0].numel() == 0:
        raise ValueError(f"x and y must have at least one value per image; got shape {tuple(x.shape)}")
    xb, yb = float_pair(xb, yb)
    return psnr_bchw(xb, yb, peak)


class PSNR(nn.Module):
    """Module twin of :func:`psnr`.

    Shape:
        - x, y: ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        - Output: ``(B,)``.

    Example:
        >>> PSNR(peak=10.0)(torch.ones(1, 1, 2, 2), torch.zeros(1, 1, 2, 2))
        tensor([20.])
    """

    def __init__(self, peak: float) -> None:
        super().__init__()
        self.peak = check_real(peak, "peak", positive=True, what=POSITIVE)

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return psnr(x, y, self.peak)

    def extra_repr(self) -> str:
        return f"peak={self.peak}"


def psnr_log(x: torch.Tensor, y: torch.Tensor, eps: float = 2.0**-16) -> torch.Tensor:
    """PSNR on log radiance, in stops relative to the reference's peak.

    With ``m`` the largest value of the reference ``y`` in each batch item (1 if the reference is all zero), both
    images are mapped to ``v(z) = log2(z / m + eps)``. The reference then spans at most
    ``[log2(eps), log2(1 + eps)]``, and that span is the peak: ``peak = log2((1 + eps) / eps)`` (about 16 stops for
    the default ``eps = 2^-16``, which floors values more than 16 stops below the reference's peak). The score is
    ``10 log10(peak^2 / MSE(v(x), v(y)))`` over all channels. It is invariant to a common scale of ``x`` and ``y``,
    so radiance in any linear unit (counts per unit exposure, relative radiance) gives the same number. Not
    symmetric: ``y`` is the reference.

    Args:
        x: the estimate, linear radiance ``>= 0``, ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        y: the reference, same shape.
        eps: floor relative to the reference's peak, in ``(0, 1)``.

    Returns:
        ``(B,)`` PSNR in dB; ``+inf`` where the images are equal.

    Raises:
        TypeError: an input is not a real tensor, or ``eps`` is not a number.
        ValueError: shapes differ, a value is NaN, infinite or negative, an image is empty, or ``eps`` is not in
            ``(0, 1)``.

    Example:
        >>> y = torch.tensor([[1.0, 4.0], [16.0, 64.0]])
        >>> round(float(psnr_log(2 * y, y, eps=2.0**-16)[0]), 2)  # every value about one stop off, of 16
        24.08
    """
    eps = check_eps(eps)
    xb, yb = nonnegative_pair(x, y)
    m = reference_peak(yb)
    peak = math.log2((1 + eps) / eps)
    return psnr_bchw(log_relative(xb, m, eps), log_relative(yb, m, eps), peak)


class PSNRLog(nn.Module):
    """Module twin of :func:`psnr_log`.

    Shape:
        - x, y: ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        - Output: ``(B,)``.

    Example:
        >>> PSNRLog()(torch.ones(1, 1, 2, 2), torch.ones(1, 1, 2, 2))
        tensor([inf])
    """

    def __init__(self, eps: float = 2.0**-16) -> None:
        super().__init__()
        self.eps = check_eps(eps)

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return psnr_log(x, y, self.eps)

    def extra_repr(self) -> str:
        return f"eps={self.eps}"
