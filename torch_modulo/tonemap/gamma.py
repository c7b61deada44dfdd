"""Exposure and gamma per channel: the display encoding most viewers apply to linear images."""

from __future__ import annotations

import torch
from torch import nn

from torch_modulo._checks import check_flag, check_real
from torch_modulo.tonemap._common import (
    as_batch,
    check_exposure_stops,
    chunked,
    encode,
    img,
    luminance,
    needs_grad,
    pixel_chunks,
    restore,
    widened,
)

__all__ = ["GammaToneMap", "tonemap_gamma"]


def _check_gamma_args(gamma: object, exposure: object, percentile: object) -> tuple[float, float, float | None]:
    gamma_f = check_real(gamma, "gamma", positive=True, what="a positive finite number")
    exposure_f = check_exposure_stops(exposure)
    pct = None
    if percentile is not None:
        pct = check_real(percentile, "percentile", positive=True, high=100.0, what="in (0, 100]")
    return gamma_f, exposure_f, pct


def _percentile_luminance(x: torch.Tensor, pct: float) -> torch.Tensor:
    """Per-image luminance percentile (nearest rank, lower), (B,)."""
    y = luminance(x).reshape(x.shape[0], -1)
    k = int(round(pct / 100.0 * (y.shape[1] - 1))) + 1
    return torch.kthvalue(y, k, dim=1).values


def tonemap_gamma(
    hdr: torch.Tensor,
    gamma: float = 2.2,
    exposure: float = 0.0,
    *,
    percentile: float | None = None,
    srgb: bool = False,
) -> torch.Tensor:
    r"""Exposure and gamma: :math:`\min(1, 2^{EV} s\, x)^{1/\gamma}` per channel.

    Args:
        hdr: linear radiance, (B, C, H, W), (C, H, W) or (H, W), C = 1 or 3, values >= 0.
        gamma: display gamma :math:`\gamma` (2.2 for a typical display; 1 for a linear clip).
        exposure: exposure adjustment :math:`EV` in stops (the radiance is multiplied by ``2**exposure``), from
            -1022 to 1023 (the range where ``2**exposure`` is a normal float64).
        percentile: if given, ``s`` makes this percentile of each image's luminance reach 1 before the
            exposure adjustment (auto exposure per image: ``percentile=99`` clips the brightest 1%); by default
            ``s = 1`` and the radiance's own scale is used.
        srgb: apply the sRGB transfer function after the gamma (usually with ``gamma=1``).

    Returns:
        Display values in ``[0, 1]``, same shape, dtype and device as ``hdr``. Values whose exposed radiance
        exceeds 1 clip to 1; colour ratios are not kept (the curve works on each channel).

    Raises:
        TypeError: ``hdr`` is not a floating tensor, an option is not a number or ``srgb`` not a bool.
        ValueError: bad radiance (see the module's conventions), ``gamma`` not positive, ``exposure`` outside
            [-1022, 1023] stops, ``percentile`` outside (0, 100].

    Example:
        >>> tonemap_gamma(torch.tensor([[0.0, 0.25], [1.0, 8.0]]), gamma=2.0)
        tensor([[0.0000, 0.5000],
                [1.0000, 1.0000]])
    """
    gamma, exposure, pct = _check_gamma_args(gamma, exposure, percentile)
    srgb = check_flag(srgb, "srgb")
    given, shape = as_batch(hdr)
    if given.numel() == 0:
        return restore(given.clone(), shape, hdr)
    x = widened(given)  # float16's range does not hold the scale of dim radiance (2**17 for 2**-17)
    # 2**exposure is a normal float64; in the work dtype it may overflow, so cap it (and its quotient by the
    # percentile) at the dtype's largest value: any radiance it multiplies then still clips to 1 (float32 holds
    # the reciprocal of every float16 radiance), and black stays 0.
    top = torch.finfo(x.dtype).max
    scale = torch.full((x.shape[0],), min(2.0**exposure, top), dtype=x.dtype, device=x.device)
    if pct is not None:
        src = x if needs_grad(x) else x.detach()
        ref = _percentile_luminance(src, pct)
        brightest = src.amax(dim=(1, 2, 3))
        ref = torch.where(ref > 0, ref, torch.where(brightest > 0, brightest, torch.ones_like(brightest)))
        scale = (scale / ref).clamp(max=top)
    inv_gamma = 1.0 / gamma
    if chunked(x):
        out = _gamma_chunked(x, scale, inv_gamma)
    else:
        out = (x * img(scale)).clamp(0.0, 1.0)
        if inv_gamma != 1.0:
            # d/dx x^(1/g) is infinite at 0 for g > 1: keep the gradient finite there.
            out = torch.where(out > 0, out.clamp_min(torch.finfo(x.dtype).tiny) ** inv_gamma, out)
    return restore(encode(out, srgb).to(given.dtype), shape, hdr)


def _gamma_chunked(x: torch.Tensor, scale: torch.Tensor, inv_gamma: float) -> torch.Tensor:
    """CPU path of :func:`tonemap_gamma`: ``clip(x * scale, 0, 1) ** inv_gamma`` chunk by chunk, in place."""
    b, c, h, w = x.shape
    n = h * w
    x3 = x.reshape(b, c, n)
    out = torch.empty_like(x, memory_format=torch.contiguous_format)
    o3 = out.view(b, c, n)
    s3 = scale.reshape(-1, 1, 1)
    for cols in pixel_chunks(n, b * c):
        o = o3[:, :, cols]
        torch.mul(x3[:, :, cols], s3, out=o).clamp_(0.0, 1.0)
        if inv_gamma != 1.0:
            o.log_().mul_(inv_gamma).exp_()  # x ** (1 / gamma), faster than pow_; log(0) = -inf gives 0
    return out


class GammaToneMap(nn.Module):
    """Module twin of :func:`tonemap_gamma` (exposure and gamma per channel).

    Shape:
        - Input: (B, C, H, W), (C, H, W) or (H, W) with C = 1 or 3.
        - Output: same as input, values in [0, 1].

    Example:
        >>> GammaToneMap(gamma=1.0, exposure=-1.0)(torch.tensor([[1.0, 4.0]]))
        tensor([[0.5000, 1.0000]])
    """

    def __init__(
        self, gamma: float = 2.2, exposure: float = 0.0, percentile: float | None = None, srgb: bool = False
    ) -> None:
        super().__init__()
        self.gamma, self.exposure, self.percentile = _check_gamma_args(gamma, exposure, percentile)
        self.srgb = check_flag(srgb, "srgb")

    def forward(self, hdr: torch.Tensor) -> torch.Tensor:
        return tonemap_gamma(hdr, self.gamma, self.exposure, percentile=self.percentile, srgb=self.srgb)

    def extra_repr(self) -> str:
        return f"gamma={self.gamma}, exposure={self.exposure}, percentile={self.percentile}, srgb={self.srgb}"
