"""Larson, Rushmeier and Piatko (1997) histogram adjustment with the linear ceiling: ref. [20] of the paper."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from torch_modulo._checks import check_flag, check_int, check_real
from torch_modulo.tonemap._common import (
    as_batch,
    chunked,
    col,
    encode,
    luminance,
    map_chunked,
    needs_grad,
    restore,
    widened,
)

__all__ = ["HistogramToneMap", "fovea_shape", "tonemap_histogram"]

_POSITIVE = "a positive finite number"


#: The largest display contrast ``ld_max / ld_min`` (real displays reach about 1e6; float32 overflows near 1e38).
MAX_CONTRAST = 1e30


def _check_histogram_args(
    ld_min: object,
    ld_max: object,
    bins: object,
    fov: object,
    fovea: object,
    tolerance: object,
    max_iter: object,
) -> tuple[float, float, int, float, float, float, int]:
    ld_min_f = check_real(ld_min, "ld_min", positive=True, what=_POSITIVE)
    ld_max_f = check_real(ld_max, "ld_max", positive=True, what=_POSITIVE)
    if ld_max_f <= ld_min_f:
        raise ValueError(f"ld_max must be greater than ld_min; got ld_min={ld_min!r}, ld_max={ld_max!r}")
    if ld_max_f / ld_min_f > MAX_CONTRAST:  # beyond, exp(log(ld_max / ld_min) P) overflows the float32 work
        raise ValueError(
            f"ld_max / ld_min must be at most {MAX_CONTRAST:g} (a display's contrast); got ld_min={ld_min!r}, "
            f"ld_max={ld_max!r}"
        )
    bins_i = check_int(bins, "bins", 2)
    fov_f, fovea_f = _check_view(fov, fovea)
    tol = check_real(tolerance, "tolerance", positive=True, high=1.0, what="in (0, 1)")
    if tol == 1.0:
        raise ValueError(f"tolerance must be in (0, 1); got {tol}")
    return ld_min_f, ld_max_f, bins_i, fov_f, fovea_f, tol, check_int(max_iter, "max_iter", 1)


def _check_view(fov: object, fovea: object) -> tuple[float, float]:
    fov_f = check_real(fov, "fov", positive=True, what=_POSITIVE)
    if fov_f >= 180:
        raise ValueError(f"fov must be below 180 degrees; got {fov!r}")
    return fov_f, check_real(fovea, "fovea", positive=True, what=_POSITIVE)


def fovea_shape(height: int, width: int, fov: float = 40.0, fovea: float = 1.0) -> tuple[int, int]:
    """Size of the foveal image: one sample per ``fovea`` degrees when the longer side spans ``fov`` degrees.

    As in Radiance's ``pcond`` (Larson's own implementation): a perspective view whose longer side spans
    ``fov`` degrees has ``2 tan(fov / 2) / fovea_radians`` fovea-sized samples across it (42 for 40 degrees),
    the shorter side proportionally fewer; at least 2 each, and never more than the image has.

    Example:
        >>> fovea_shape(768, 512)
        (42, 28)
    """
    check_int(height, "height", 1)
    check_int(width, "width", 1)
    fov, fovea = _check_view(fov, fovea)
    across = 2.0 * math.tan(math.radians(fov) / 2.0) / math.radians(fovea)
    longer = max(height, width)
    fh = max(2, int(across * height / longer + 0.5))
    fw = max(2, int(across * width / longer + 0.5))
    return min(fh, height), min(fw, width)


def _histogram_tables(
    fovea_lum: torch.Tensor,
    ld_min: float,
    ld_max: float,
    bins: int,
    tolerance: float,
    max_iter: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per-image brightness mapping from the foveal luminance samples (B, M).

    Returns ``lo`` (B,), ``scale`` (B,), ``cumf`` (B, bins + 1) and ``slope`` (B, bins + 1): a pixel of
    brightness ``b = log(Y)`` sits at ``u = clamp((b - lo) * scale, 0, bins)``, and the cumulative distribution
    there is ``P = cumf[floor(u)] + (u - floor(u)) * slope[floor(u)]``.
    """
    dtype, device = fovea_lum.dtype, fovea_lum.device
    batch = fovea_lum.shape[0]
    span = math.log(ld_max) - math.log(ld_min)  # log Ld_max - log Ld_min
    pos = fovea_lum > 0
    n_pos = pos.sum(dim=1)
    bright = torch.log(torch.where(pos, fovea_lum, torch.ones_like(fovea_lum)))  # brightness B = log(Lw)
    inf = torch.tensor(math.inf, dtype=dtype, device=device)
    b_min = torch.where(pos, bright, inf).amin(dim=1)
    b_max = torch.where(pos, bright, -inf).amax(dim=1)
    b_avg = (bright * pos).sum(dim=1) / n_pos.clamp_min(1)
    width = b_max - b_min
    # Compress only where the scene's range exceeds the display's (pcond does the same check).
    compress = (n_pos > 0) & (width > span)
    safe_width = torch.where(compress, width, torch.ones_like(width))
    safe_min = torch.where(compress, b_min, torch.zeros_like(b_min))
    with torch.no_grad():
        idx = ((bright - safe_min[:, None]) * (bins / safe_width)[:, None]).floor_().clamp_(0, bins - 1).long()
    hist = torch.zeros((batch, bins), dtype=dtype, device=device).scatter_add_(1, idx, pos.to(dtype))

    # Linear ceiling, iterated (their histogram_ceiling procedure): trim every bin to
    # T * delta_b / (log Ld_max - log Ld_min), recompute T, and repeat until the trimmings fall to the tolerance
    # (2.5% of the original total); if T itself falls below it, the scene needs no compression.
    tol = tolerance * hist.sum(dim=1)
    delta_b = safe_width / bins
    active = compress.clone()
    failed = torch.zeros_like(compress)
    h = hist
    for _ in range(max_iter):
        if not bool(active.any()):
            break
        total = h.sum(dim=1)
        empty = active & (total < tol)
        failed = failed | empty  # not in place: autograd keeps the masks torch.where used
        active = active & ~empty
        ceiling = total * delta_b / span
        trimmed = torch.minimum(h, ceiling[:, None])
        trimmings = (h - trimmed).sum(dim=1)
        h = torch.where(active[:, None], trimmed, h)
        active = active & (trimmings > tol)
    use_hist = compress & ~failed

    zero = torch.zeros((batch, 1), dtype=dtype, device=device)
    cum = torch.cat([zero, h.cumsum(dim=1)], dim=1)
    cum = cum / cum[:, -1:].clamp_min(torch.finfo(dtype).tiny)
    # Linear mapping (used when the scene fits the display or the ceiling empties the histogram): log Ld = log Lw +
    # const, centred so the log-average fovea luminance maps to sqrt(Ld_min Ld_max), like pcond; written as a
    # uniform distribution over [b_avg - span/2, b_avg + span/2], so one lookup serves both cases.
    uniform = torch.linspace(0.0, 1.0, bins + 1, dtype=dtype, device=device).expand(batch, -1)
    cumf = torch.where(use_hist[:, None], cum, uniform)
    lo = torch.where(use_hist, b_min, b_avg - span / 2)
    scale = bins / torch.where(use_hist, width, torch.full_like(width, span))
    slope = torch.cat([cumf[:, 1:] - cumf[:, :-1], zero], dim=1)
    return lo, scale, cumf, slope


def tonemap_histogram(
    hdr: torch.Tensor,
    ld_min: float = 1.0,
    ld_max: float = 100.0,
    *,
    bins: int = 100,
    fov: float = 40.0,
    fovea: float = 1.0,
    tolerance: float = 0.025,
    max_iter: int = 100,
    srgb: bool = False,
) -> torch.Tensor:
    r"""Larson, Rushmeier and Piatko (1997) histogram adjustment with the linear ceiling: ref. [20] of the paper.

    The operator the paper uses to show its results (Fig. 1; "adaptive histogram equalization", Sec. 6.1.1).
    Per image:

    1. Foveal image: the luminance averaged over blocks of about ``fovea`` degrees (1 degree), for a view whose
       longer side spans ``fov`` degrees (:func:`fovea_shape`; box filter via adaptive average pooling).
    2. Histogram of brightness :math:`B = \log L_w` of the foveal samples, ``bins`` equal bins between the
       samples' minimum and maximum (zero samples are left out); :math:`P(B)` is the cumulative distribution,
       linearly interpolated within each bin.
    3. Linear ceiling: histogram equalisation alone can exaggerate contrast. Requiring the display contrast
       never to exceed the world contrast, :math:`dL_d / dL_w \le L_d / L_w`, bounds every bin:
       :math:`f(b_i) \le T \Delta b / (\log L_{d,max} - \log L_{d,min})`, with :math:`T` the histogram total.
       Bins above the ceiling are trimmed to it and the ceiling recomputed from the new total until the
       trimmings fall to ``tolerance`` (2.5%) of the original total. If the scene's brightness range fits the
       display's, or the total itself falls below the tolerance, the mapping is linear instead: :math:`L_d`
       proportional to :math:`L_w`, the log-average foveal luminance shown at :math:`\sqrt{L_{d,min} L_{d,max}}`.
    4. Display mapping: :math:`\log L_d = \log L_{d,min} + (\log L_{d,max} - \log L_{d,min}) P(\log L_w)`,
       for every full-resolution pixel (below the foveal range :math:`P = 0`, above it :math:`P = 1`).
    5. Output: :math:`(L_d - L_{d,min}) / (L_{d,max} - L_{d,min})` in ``[0, 1]`` (as ``pcond`` writes it), with
       R, G and B scaled by the same factor, then clipped to ``[0, 1]``.

    Not implemented (each needs absolute luminance in cd/m² and models of human vision): the
    human-contrast-sensitivity ceiling (threshold-versus-intensity), veiling glare, loss of colour sensitivity
    in scotopic and mesopic vision, loss of visual acuity, and fixation-weighted histograms. ``pcond``'s extra
    full-resolution point samples and its duplicated bottom bin are not in the paper and are left out too.
    The linear-ceiling operator needs only relative radiance: scaling the input does not change the output.

    Args:
        hdr: linear radiance, (B, C, H, W), (C, H, W) or (H, W), C = 1 or 3, values >= 0.
        ld_min: display black luminance :math:`L_{d,min}` (cd/m², only the ratio to ``ld_max`` matters).
        ld_max: display white luminance :math:`L_{d,max}` (default 100:1 display; at most :data:`MAX_CONTRAST`
            times ``ld_min``).
        bins: histogram bins (the paper and ``pcond`` use 100).
        fov: angle in degrees spanned by the image's longer side (``pcond``'s default view is 40 degrees).
        fovea: foveal sample size in degrees (1 in the paper).
        tolerance: share of the original histogram total at which the ceiling loop stops (0.025 in the paper).
        max_iter: safety bound on ceiling iterations; the loop ends far sooner in practice (bins only shrink).
        srgb: apply the sRGB transfer function to the result.

    Returns:
        Display values in ``[0, 1]``, same shape, dtype and device as ``hdr``. float16 and bfloat16 input is
        mapped in float32 and the result cast back.

    Example:
        Four bins of one decade each; five samples fall in the first, one in each of the others, and the
        ceiling trims the first bin 5 -> 4 -> 3.5 -> 3.25 -> 3.125:

        >>> x = torch.tensor([[1.0, 2.0, 3.0, 4.0], [5.0, 50.0, 500.0, 10000.0]])
        >>> tonemap_histogram(x, ld_min=1.0, ld_max=100.0, bins=4)
        tensor([[0.0000, 0.0104, 0.0209, 0.0315],
                [0.0421, 0.1690, 0.3697, 1.0000]])
    """
    ld_min, ld_max, bins, fov, fovea, tolerance, max_iter = _check_histogram_args(
        ld_min, ld_max, bins, fov, fovea, tolerance, max_iter
    )
    srgb = check_flag(srgb, "srgb")
    x, shape = as_batch(hdr)
    if x.numel() == 0:
        return restore(x.clone(), shape, hdr)
    b, _, h, w = x.shape
    grad = needs_grad(x)
    # In float16 the ratio expm1(span P) / Y overflows 65504 for dim pixels (and 0 * inf is NaN in a black
    # channel), the clamp at float16's smallest normal number (6e-5) merges dimmer ones, and log brightness keeps
    # 11 bits: map in float32.
    src = widened(x if grad else x.detach())
    fov_img = F.adaptive_avg_pool2d(src, fovea_shape(h, w, fov, fovea))
    lo, scale, cumf, slope = _histogram_tables(
        luminance(fov_img).reshape(b, -1), ld_min, ld_max, bins, tolerance, max_iter
    )
    span = math.log(ld_max) - math.log(ld_min)
    c = ld_min / (ld_max - ld_min)  # (Ld - Ld_min) / (Ld_max - Ld_min) = c * expm1(span * P)
    tiny = torch.finfo(src.dtype).tiny
    if chunked(src):
        # span * P = span * (cumf[i] + (u - i) slope[i]) = offset[i] + u * steep[i]: one gather fewer per pixel.
        steep = span * slope
        offset = span * cumf - torch.arange(bins + 1, dtype=src.dtype, device=src.device) * steep
        shift_col, scale_col = col(-lo * scale), col(scale)

        def kernel(y: torch.Tensor, buf: list[torch.Tensor]) -> torch.Tensor:
            u, tmp, idx = buf
            y.clamp_min_(tiny)
            torch.addcmul(shift_col, torch.log(y, out=u), scale_col, out=u).clamp_(0.0, float(bins))
            idx.copy_(u)  # truncation == floor for u >= 0
            u.mul_(torch.gather(steep, 1, idx, out=tmp)).add_(torch.gather(offset, 1, idx, out=tmp))
            return u.expm1_().mul_(c).div_(y)  # in this order: expm1(span P) / y may overflow

        out = map_chunked(src, kernel, 2, index_scratch=True)
    else:
        y = luminance(src).reshape(b, -1).clamp_min(tiny)
        u = ((torch.log(y) - lo[:, None]) * scale[:, None]).clamp(0.0, float(bins))
        i = u.detach().floor().long()
        p = torch.gather(cumf, 1, i) + (u - i.to(u.dtype)) * torch.gather(slope, 1, i)
        ratio = c * torch.expm1(span * p) / y
        out = (src * ratio.reshape(b, 1, h, w)).clamp(0.0, 1.0)
    return restore(encode(out, srgb).to(x.dtype), shape, hdr)


class HistogramToneMap(nn.Module):
    """Module twin of :func:`tonemap_histogram` (Larson, Rushmeier and Piatko 1997, linear ceiling).

    Shape:
        - Input: (B, C, H, W), (C, H, W) or (H, W) with C = 1 or 3.
        - Output: same as input, values in [0, 1].

    Example:
        >>> HistogramToneMap(bins=4)(torch.tensor([[1.0, 2.0, 3.0, 4.0], [5.0, 50.0, 500.0, 10000.0]]))
        tensor([[0.0000, 0.0104, 0.0209, 0.0315],
                [0.0421, 0.1690, 0.3697, 1.0000]])
    """

    def __init__(
        self,
        ld_min: float = 1.0,
        ld_max: float = 100.0,
        bins: int = 100,
        fov: float = 40.0,
        fovea: float = 1.0,
        tolerance: float = 0.025,
        max_iter: int = 100,
        srgb: bool = False,
    ) -> None:
        super().__init__()
        (self.ld_min, self.ld_max, self.bins, self.fov, self.fovea, self.tolerance, self.max_iter) = (
            _check_histogram_args(ld_min, ld_max, bins, fov, fovea, tolerance, max_iter)
        )
        self.srgb = check_flag(srgb, "srgb")

    def forward(self, hdr: torch.Tensor) -> torch.Tensor:
        return tonemap_histogram(
            hdr,
            self.ld_min,
            self.ld_max,
            bins=self.bins,
            fov=self.fov,
            fovea=self.fovea,
            tolerance=self.tolerance,
            max_iter=self.max_iter,
            srgb=self.srgb,
        )

    def extra_repr(self) -> str:
        return (
            f"ld_min={self.ld_min}, ld_max={self.ld_max}, bins={self.bins}, fov={self.fov}, fovea={self.fovea}, "
            f"tolerance={self.tolerance}, max_iter={self.max_iter}, srgb={self.srgb}"
        )
