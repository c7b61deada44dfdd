"""SSIM (Kornia) on tone-mapped HDR images, and the log tone map it uses by default."""

from __future__ import annotations

import math
from collections.abc import Callable

import kornia
import torch
from torch import nn

from torch_modulo._checks import check_finite, check_int, check_tensor
from torch_modulo.metrics._common import check_eps, log_relative, nonnegative_pair, reference_peak

__all__ = ["SSIMToneMapped", "log_relative_tonemap", "ssim_tonemapped"]


def log_relative_tonemap(hdr: torch.Tensor, reference: torch.Tensor, eps: float = 2.0**-16) -> torch.Tensor:
    """The default tone map of :func:`ssim_tonemapped`: log radiance normalised by the reference's range.

    ``t(z) = clamp((log2(z / m + eps) - log2(eps)) / log2((1 + eps) / eps), 0, 1)`` with ``m`` the largest value of
    the reference in each batch item (1 if it is all zero): the same log coordinates as :func:`psnr_log`, scaled so
    that the reference spans ``[0, 1]`` (its peak maps to 1, values ``eps`` or more below it to about 0). Global,
    deterministic and monotonic; both images use the reference's ``m`` so their tone maps are the same curve.

    Args:
        hdr: linear radiance ``>= 0``, ``(B, C, H, W)``.
        reference: the reference image whose peak sets the curve, ``(B, C, H, W)``.
        eps: floor relative to the reference's peak, in ``(0, 1)``.

    Returns:
        ``hdr`` tone-mapped into ``[0, 1]``, same shape.

    Example:
        >>> ref = torch.tensor([[[[1.0, 2.0**-8, 2.0**-16]]]])
        >>> log_relative_tonemap(ref, ref, eps=2.0**-16).round(decimals=2)
        tensor([[[[1.0000, 0.5000, 0.0600]]]])
    """
    eps = check_eps(eps)
    m = reference_peak(reference)
    lo = math.log2(eps)
    span = math.log2((1 + eps) / eps)
    return ((log_relative(hdr, m, eps) - lo) / span).clamp(0.0, 1.0)


def _check_window(window_size: object) -> int:
    what = "an odd positive integer"
    window_size = check_int(window_size, "window_size", 1, what=what)
    if window_size % 2 == 0:
        raise ValueError(f"window_size must be {what}; got {window_size}")
    return window_size


def _check_tonemap(tonemap: object) -> Callable[[torch.Tensor], torch.Tensor] | None:
    if tonemap is not None and not callable(tonemap):
        raise TypeError(f"tonemap must be callable or None; got {tonemap!r}")
    return tonemap


def ssim_tonemapped(
    x: torch.Tensor,
    y: torch.Tensor,
    tonemap: Callable[[torch.Tensor], torch.Tensor] | None = None,
    window_size: int = 11,
) -> torch.Tensor:
    """Mean SSIM per batch item of two tone-mapped HDR images (Kornia's Gaussian-window SSIM).

    Both images are tone-mapped, then ``kornia.metrics.ssim`` (Gaussian window, sigma 1.5, ``'same'`` reflect
    padding, data range 1, no denominator ``eps`` so identical images score exactly 1) gives a per-pixel map that is
    averaged over channels and pixels.

    Args:
        x: the estimate, linear radiance ``>= 0``, ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        y: the reference, same shape.
        tonemap: a function mapping a ``(B, C, H, W)`` HDR tensor to the same shape in ``[0, 1]``, applied to each
            image separately (e.g. a tone map of :mod:`torch_modulo.tonemap`). ``None`` uses
            :func:`log_relative_tonemap` with the reference's peak for both images.
        window_size: odd Gaussian window size; ``H`` and ``W`` must exceed ``window_size // 2``.

    Returns:
        ``(B,)`` mean SSIM, at most 1.

    Raises:
        TypeError: an input is not a real tensor, ``tonemap`` is not callable or ``window_size`` not an integer.
        ValueError: shapes differ, a value is NaN, infinite or negative, the image is smaller than the window
            needs, ``window_size`` is not odd and positive, or the tone map returns a wrong shape or NaN.

    Example:
        >>> y = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(0)) * 1000
        >>> ssim_tonemapped(y, y).round(decimals=4)
        tensor([1.])
    """
    tonemap = _check_tonemap(tonemap)
    window_size = _check_window(window_size)
    xb, yb = nonnegative_pair(x, y)
    h, w = xb.shape[-2:]
    if min(h, w) <= window_size // 2:
        raise ValueError(
            f"images must be larger than window_size // 2 = {window_size // 2} in H and W; got {tuple(xb.shape)}"
        )
    if tonemap is None:
        tx, ty = log_relative_tonemap(xb, yb), log_relative_tonemap(yb, yb)
    else:
        tx, ty = tonemap(xb), tonemap(yb)
        for name, t in (("tonemap(x)", tx), ("tonemap(y)", ty)):
            check_tensor(t, name)
            if t.shape != xb.shape:
                raise ValueError(f"{name} must keep the shape {tuple(xb.shape)}; got {tuple(t.shape)}")
            check_finite(t, name)
    if xb.shape[0] == 0:
        return xb.new_zeros(0)
    ssim_map = kornia.metrics.ssim(tx, ty, window_size, max_val=1.0, eps=0.0)
    # E[x^2] - mu^2 cancels in float32: nearly identical images can score 1 + 2e-6; SSIM is at most 1.
    return ssim_map.flatten(1).mean(dim=1).clamp(max=1.0).to(xb.dtype)


class SSIMToneMapped(nn.Module):
    """Module twin of :func:`ssim_tonemapped`.

    Shape:
        - x, y: ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        - Output: ``(B,)``.

    Example:
        >>> SSIMToneMapped(window_size=3)(torch.ones(1, 1, 4, 4), torch.ones(1, 1, 4, 4))
        tensor([1.])
    """

    def __init__(self, tonemap: Callable[[torch.Tensor], torch.Tensor] | None = None, window_size: int = 11) -> None:
        super().__init__()
        self.tonemap = _check_tonemap(tonemap)
        self.window_size = _check_window(window_size)

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return ssim_tonemapped(x, y, self.tonemap, self.window_size)

    def extra_repr(self) -> str:
        return f"tonemap={self.tonemap!r}, window_size={self.window_size}"
