"""Reinhard, Stark, Shirley and Ferwerda (2002) photographic tone reproduction, global operator."""

from __future__ import annotations

import math

import torch
from torch import nn

from torch_modulo._checks import check_flag, check_real
from torch_modulo.tonemap._common import (
    as_batch,
    chunked,
    col,
    encode,
    img,
    luminance,
    luminance_stats_chunked,
    map_chunked,
    restore,
    widened,
)

__all__ = ["ReinhardToneMap", "tonemap_reinhard"]

_POSITIVE = "a positive finite number"


def _check_reinhard_args(key: object, white: object, delta: object) -> tuple[float, float | None, float]:
    key_f = check_real(key, "key", positive=True, what=_POSITIVE)
    white_f = None
    if white is not None:
        white_f = check_real(white, "white", positive=True, allow_inf=True, what="a positive number")
    return key_f, white_f, check_real(delta, "delta", positive=True, what=_POSITIVE)


def tonemap_reinhard(
    hdr: torch.Tensor,
    key: float = 0.18,
    white: float | None = None,
    *,
    delta: float = 1e-6,
    srgb: bool = False,
) -> torch.Tensor:
    r"""Reinhard, Stark, Shirley and Ferwerda (2002) photographic tone reproduction, global operator.

    Per image: the log-average luminance :math:`\bar L_w = \exp(\frac1N \sum \log(\delta + L_w))` (their
    Eq. 1), the scaled luminance :math:`L = \frac{a}{\bar L_w} L_w` (Eq. 2) and the display luminance
    :math:`L_d = \frac{L (1 + L / L_{white}^2)}{1 + L}` (Eq. 4); R, G and B are scaled by :math:`L_d / L_w`.

    Args:
        hdr: linear radiance, (B, C, H, W), (C, H, W) or (H, W), C = 1 or 3, values >= 0.
        key: the key value ``a`` (0.18 is "middle grey"; 0.09 darker, 0.36 or 0.72 brighter).
        white: :math:`L_{white}` in scaled units (after multiplying by ``a / L̄_w``): the smallest luminance
            mapped to white. ``None`` (default) takes each image's maximum scaled luminance, as the paper
            suggests; ``float("inf")`` gives :math:`L / (1 + L)` (Eq. 3).
        delta: the small offset :math:`\delta` that keeps black pixels out of the logarithm's pole, in the
            input's units.
        srgb: apply the sRGB transfer function to the result.

    Returns:
        Display values in ``[0, 1]``, same shape, dtype and device as ``hdr``. float16 and bfloat16 input is
        mapped in float32 and the result cast back. Scaling ``hdr`` and ``delta`` by the same factor leaves the
        result unchanged.

    Example:
        >>> x = torch.tensor([[1.0, 4.0], [16.0, 64.0]])
        >>> tonemap_reinhard(x, key=0.5, white=float("inf"), delta=1e-12)  # log average 8: L = x / 16
        tensor([[0.0588, 0.2000],
                [0.5000, 0.8000]])
    """
    key, white, delta = _check_reinhard_args(key, white, delta)
    srgb = check_flag(srgb, "srgb")
    x, shape = as_batch(hdr)
    if x.numel() == 0:
        return restore(x.clone(), shape, hdr)
    src = widened(x)  # float16's range and precision do not hold the scale and its products
    h, w = src.shape[-2:]
    # Ld / Lw = s (1 + L / Lwhite²) / (1 + L) with L = s Lw, s = a / L̄w, written (s + (Lw c) c) / (1 + s Lw) with
    # c = s / Lwhite: neither s² nor 1 / Lwhite² (either may overflow for a very dim or bright image) is formed.
    if chunked(src):
        y_max, log_sum = luminance_stats_chunked(src, delta)
        assert log_sum is not None
        scale = key / torch.exp(log_sum / (h * w))  # float64, like the sum
        c = scale * _inverse_white(white, y_max.double() * scale)  # 1 / y_max for the default white
        s_col, c_col = col(scale.to(src.dtype)), col(c.to(src.dtype))

        def kernel(y: torch.Tensor, buf: list[torch.Tensor]) -> torch.Tensor:
            num = torch.mul(y, c_col, out=buf[0]).mul_(c_col).add_(s_col)
            return num.div_(y.mul_(s_col).add_(1.0))

        out = map_chunked(src, kernel, 1)
    else:
        y = luminance(src)
        log_avg = torch.exp(torch.log(y + delta).mean(dim=(1, 2, 3)))
        scale = key / log_avg
        c = img(scale * _inverse_white(white, y.amax(dim=(1, 2, 3)) * scale))
        ratio = (img(scale) + y * c * c) / (1.0 + y * img(scale))
        out = (src * ratio).clamp(0.0, 1.0)
    return restore(encode(out, srgb).to(x.dtype), shape, hdr)


def _inverse_white(white: float | None, scaled_max: torch.Tensor) -> torch.Tensor:
    """``1 / L_white`` per image, 0 for an infinite white or an all-black image."""
    if white is not None:
        return torch.full_like(scaled_max, 0.0 if white == math.inf else 1.0 / white)
    safe = torch.where(scaled_max > 0, scaled_max, torch.ones_like(scaled_max))
    return torch.where(scaled_max > 0, 1.0 / safe, torch.zeros_like(scaled_max))


class ReinhardToneMap(nn.Module):
    """Module twin of :func:`tonemap_reinhard` (Reinhard et al. 2002, global operator).

    Shape:
        - Input: (B, C, H, W), (C, H, W) or (H, W) with C = 1 or 3.
        - Output: same as input, values in [0, 1].

    Example:
        >>> ReinhardToneMap(key=0.18)(torch.tensor([[[[1.0, 4.0], [16.0, 64.0]]]]))
        tensor([[[[0.0222, 0.0862],
                  [0.3107, 1.0000]]]])
    """

    def __init__(self, key: float = 0.18, white: float | None = None, delta: float = 1e-6, srgb: bool = False) -> None:
        super().__init__()
        self.key, self.white, self.delta = _check_reinhard_args(key, white, delta)
        self.srgb = check_flag(srgb, "srgb")

    def forward(self, hdr: torch.Tensor) -> torch.Tensor:
        return tonemap_reinhard(hdr, self.key, self.white, delta=self.delta, srgb=self.srgb)

    def extra_repr(self) -> str:
        return f"key={self.key}, white={self.white}, delta={self.delta}, srgb={self.srgb}"
