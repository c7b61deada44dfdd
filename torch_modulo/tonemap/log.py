"""Logarithmic mapping of luminance (Banterle et al. 2011, Sec. 3.2.1)."""

from __future__ import annotations

import math

import torch
from torch import nn

from torch_modulo._checks import check_flag, check_real
from torch_modulo.tonemap._common import (
    as_batch,
    check_exposure_stops,
    chunked,
    col,
    encode,
    img,
    luminance,
    luminance_stats_chunked,
    map_chunked,
    restore,
)

__all__ = ["LogToneMap", "tonemap_log"]

_POSITIVE = "a positive finite number"


def _check_log_args(q: object, k: object, exposure: object) -> tuple[float, float, float]:
    q_f = check_real(q, "q", positive=True, what=_POSITIVE)
    k_f = check_real(k, "k", positive=True, what=_POSITIVE)
    exposure_f = check_exposure_stops(exposure)
    for name, value in (("q", q_f), ("k", k_f)):
        scaled = value * 2.0**exposure_f
        # A comparison rather than math.isfinite: torch.compile traces it on symbolic floats too (NaN fails it).
        if not (abs(scaled) < math.inf and scaled >= torch.finfo(torch.float64).tiny):
            raise ValueError(
                f"{name} * 2**exposure = {value} * 2**{exposure_f} is beyond float64's range; "
                f"use a smaller |exposure| or a {name} nearer 1"
            )
    return q_f, k_f, exposure_f


def _fits(dtype: torch.dtype, scale: float, top: float) -> bool:
    """Whether ``dtype`` holds ``scale`` as a normal number and ``scale * top`` with room to spare."""
    info = torch.finfo(dtype)
    return info.tiny <= scale and scale * max(top, 1.0) <= info.max / 4


def _log1p_scaled(y: torch.Tensor, scale: float | torch.Tensor) -> torch.Tensor:
    """``log(1 + scale * y)`` for ``y > 0``; where ``scale * y`` overflows, ``log(y) + log(scale)``."""
    z = y * scale
    out = torch.log1p(z)
    overflow = torch.isinf(z)
    if isinstance(scale, torch.Tensor):  # traced: no host sync
        return torch.where(overflow, torch.log(y) + torch.log(scale).to(y.dtype), out)
    if bool(overflow.any()):
        out = torch.where(overflow, torch.log(y) + math.log(scale), out)
    return out


def _log_map(src: torch.Tensor, qs: float | torch.Tensor, ks: float | torch.Tensor) -> torch.Tensor:
    """Whole-tensor mapping of (B, C, H, W) ``src``: ``clip(src * log1p(qs Y) / (Y log1p(ks Ymax)), 0, 1)``."""
    y = luminance(src)
    denom = _log1p_scaled(y.amax(dim=(1, 2, 3)), ks)
    denom = torch.where(denom > 0, denom, torch.ones_like(denom))
    y = y.clamp_min(torch.finfo(src.dtype).tiny)
    ratio = _log1p_scaled(y, qs) / y / img(denom)  # in this order: y * denom may underflow
    return (src * ratio).clamp(0.0, 1.0)


def _log_map_wide(src: torch.Tensor, qs: torch.Tensor, ks: torch.Tensor) -> torch.Tensor:
    """:func:`_log_map` in float64, returned in ``src``'s dtype."""
    return _log_map(src.double(), qs, ks).to(src.dtype)


def _log_map_traced(x: torch.Tensor, qs: float, ks: float) -> torch.Tensor:
    """:func:`_log_map` for ``torch.compile``: the float64 fallback chosen with ``torch.cond``, not a host sync.

    The scales enter as float64 scalar tensors (a scalar tensor scales a float32 tensor in float32, as a Python
    float does), so that ``torch.cond`` takes them as operands.
    """
    qs_t = torch.scalar_tensor(qs, dtype=torch.float64, device=x.device)
    ks_t = torch.scalar_tensor(ks, dtype=torch.float64, device=x.device)
    if not (_fits(x.dtype, qs, 1.0) and _fits(x.dtype, ks, 1.0)):
        return _log_map_wide(x, qs_t, ks_t)
    # _fits(dtype, s, top) for both scales, as a tensor: top * max(qs, ks) <= max / 4 in float64 (NaN fails).
    fits = x.detach().amax().double() * torch.maximum(qs_t, ks_t) <= torch.finfo(x.dtype).max / 4
    return torch.cond(fits, _log_map, _log_map_wide, (x, qs_t, ks_t))


def tonemap_log(
    hdr: torch.Tensor,
    q: float = 1.0,
    k: float = 1.0,
    exposure: float = 0.0,
    *,
    srgb: bool = False,
) -> torch.Tensor:
    r"""Logarithmic mapping :math:`L_d = \log(1 + q L) / \log(1 + k L_{max})` of luminance.

    The form in Banterle, Artusi, Debattista and Chalmers, *Advanced High Dynamic Range Imaging* (2011), Sec.
    3.2.1, also used by colour-hdri's ``tonemapping_operator_logarithmic``. :math:`L = 2^{EV} Y` and
    :math:`L_{max}` is each image's maximum; R, G and B are scaled by :math:`L_d / Y`.

    Args:
        hdr: linear radiance, (B, C, H, W), (C, H, W) or (H, W), C = 1 or 3, values >= 0.
        q: steepness for the pixel (``q <= k`` keeps the brightest pixel at or below 1).
        k: steepness for the maximum.
        exposure: stops applied to the luminance before the mapping (the curve is not scale invariant: for
            luminance much greater than 1 it approaches ``log(L) / log(L_max)``, for much less than 1 a linear
            scale), from -1022 to 1023; ``q * 2**exposure`` and ``k * 2**exposure`` must be normal float64
            numbers. Where the scaled luminance leaves the input dtype's range, the mapping runs in float64.
        srgb: apply the sRGB transfer function to the result.

    Returns:
        Display values in ``[0, 1]``, same shape, dtype and device as ``hdr``.

    Raises:
        TypeError: ``hdr`` is not a floating tensor, an option is not a number or ``srgb`` not a bool.
        ValueError: bad radiance (see the module's conventions), ``q`` or ``k`` not positive, ``exposure``
            outside [-1022, 1023] stops or scaling ``q`` or ``k`` beyond float64's range.

    Example:
        >>> tonemap_log(torch.tensor([[0.0, 1.0], [3.0, 15.0]]))
        tensor([[0.0000, 0.2500],
                [0.5000, 1.0000]])
    """
    q, k, exposure = _check_log_args(q, k, exposure)
    srgb = check_flag(srgb, "srgb")
    x, shape = as_batch(hdr)
    if x.numel() == 0:
        return restore(x.clone(), shape, hdr)
    s = 2.0**exposure
    qs, ks = q * s, k * s

    def fitting(tops: torch.Tensor) -> list[bool]:
        """Per image, whether its largest luminance (or a bound of it) scaled stays in ``x``'s dtype."""
        return [_fits(x.dtype, qs, t) and _fits(x.dtype, ks, t) for t in tops.tolist()]

    def one_by_one() -> torch.Tensor:
        # Some images need float64 and others not: map them one at a time, so that a batch gives the same result
        # as its images alone (one image would otherwise move the whole batch to float64).
        parts = [tonemap_log(x[i : i + 1], q, k, exposure, srgb=srgb) for i in range(x.shape[0])]
        return restore(torch.cat(parts), shape, hdr)

    if chunked(x):
        y_max, _ = luminance_stats_chunked(x, None)
        fit = fitting(y_max)
        if any(fit) and not all(fit):
            return one_by_one()
        if all(fit):
            tiny = torch.finfo(x.dtype).tiny
            denom = torch.log1p(ks * y_max)
            # Ld / Y = log1p(q s Y) / (Y log1p(k s Ymax))
            inv_col = col(1.0 / torch.where(denom > 0, denom, torch.ones_like(denom)))

            def kernel(y: torch.Tensor, buf: list[torch.Tensor]) -> torch.Tensor:
                y.clamp_min_(tiny)
                ld = torch.mul(y, qs, out=buf[0]).log1p_()
                return ld.div_(y).mul_(inv_col)

            return restore(encode(map_chunked(x, kernel, 1), srgb), shape, hdr)
    if x.dtype == torch.float64 or x.device.type == "mps":
        out = _log_map(x, qs, ks)
    elif torch.compiler.is_compiling():
        out = _log_map_traced(x, qs, ks)
    else:
        fit = fitting(x.detach().amax(dim=(1, 2, 3)))  # bounds each image's luminance: its weights sum to 1
        if any(fit) and not all(fit):
            return one_by_one()
        # Where the scaled luminance leaves the input dtype's range, map in float64.
        out = _log_map(x, qs, ks) if all(fit) else _log_map(x.double(), qs, ks).to(x.dtype)
    return restore(encode(out, srgb), shape, hdr)


class LogToneMap(nn.Module):
    """Module twin of :func:`tonemap_log` (logarithmic mapping of luminance).

    Shape:
        - Input: (B, C, H, W), (C, H, W) or (H, W) with C = 1 or 3.
        - Output: same as input, values in [0, 1].

    Example:
        >>> LogToneMap(q=1.0, k=1.0)(torch.tensor([[0.0, 3.0, 15.0]]))
        tensor([[0.0000, 0.5000, 1.0000]])
    """

    def __init__(self, q: float = 1.0, k: float = 1.0, exposure: float = 0.0, srgb: bool = False) -> None:
        super().__init__()
        self.q, self.k, self.exposure = _check_log_args(q, k, exposure)
        self.srgb = check_flag(srgb, "srgb")

    def forward(self, hdr: torch.Tensor) -> torch.Tensor:
        return tonemap_log(hdr, self.q, self.k, self.exposure, srgb=self.srgb)

    def extra_repr(self) -> str:
        return f"q={self.q}, k={self.k}, exposure={self.exposure}, srgb={self.srgb}"
