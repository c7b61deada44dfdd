"""Tone mapping: HDR radiance to display values in ``[0, 1]``.

The paper shows its recovered radiance maps "tone-mapped with the method in [20]" (Sec. 1, Fig. 1) and calls it
"a tone mapping scheme by adaptive histogram equalization [20]" (Sec. 6.1.1): [20] is Larson, Rushmeier and
Piatko, "A Visibility Matching Tone Reproduction Operator for High Dynamic Range Scenes", IEEE TVCG 3(4), 1997.
This module implements that operator (:func:`tonemap_histogram`) and the operators PyTorch users usually compare
it with:

==========================  ===========================================================  ==========
function / module           operator                                                     kind
==========================  ===========================================================  ==========
``tonemap_histogram``       Larson et al. 1997 histogram adjustment, linear ceiling      global
``tonemap_reinhard``        Reinhard et al. 2002 photographic operator (global form)      global
``tonemap_gamma``           exposure and gamma, per channel                              global
``tonemap_log``             logarithmic mapping ``log(1 + qL) / log(1 + k L_max)``       global
``tonemap_clahe``           CLAHE on log luminance (``kornia.enhance.equalize_clahe``)   local
==========================  ===========================================================  ==========

Conventions shared by every operator:

- Input: linear, non-negative radiance, ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``, with ``C = 1`` (grey) or
  ``C = 3`` (linear Rec.709 / sRGB primaries). Luminance is ``Y = 0.2126 R + 0.7152 G + 0.0722 B``. Negative,
  NaN or infinite values, other channel counts and other ranks raise ``ValueError``; non-floating input raises
  ``TypeError``. The absolute scale of the radiance does not matter except where an operator says so (the
  ``exposure`` of the gamma and logarithmic mappings).
- Output: display-referred values in ``[0, 1]``, same shape, dtype and device as the input; linear display
  values unless ``srgb=True``, which applies the sRGB transfer function (``kornia.color.linear_rgb_to_rgb``).
- Statistics (log average, maximum, histogram, percentiles) are computed per batch item: a batch gives the
  same result as its images one at a time.
- Colour: the luminance-based operators (histogram, Reinhard, logarithmic, CLAHE) map luminance and scale R, G
  and B by the same factor ``Y_display / Y``, so colour ratios are kept wherever no channel exceeds 1 (channels
  are clipped to ``[0, 1]`` last, as a display would). The gamma mapping works per channel, as display
  encodings do, and does not keep ratios.
- Monotonic: for a fixed colour, a brighter input never gives a darker output. The global operators are
  monotonic over the whole image; CLAHE is monotonic at each pixel position (a blend of monotonic tile
  curves) but, being local, not between positions.

Gradients:
    The global operators are differentiable almost everywhere, including through their statistics (log
    average, maximum, the histogram's range and ceiling). Histogram bin counts are piecewise constant, so
    their derivative is 0 almost everywhere, and the ceiling loop's stopping decision is discrete. CLAHE is
    differentiable only with ``differentiable=True`` (Kornia's slow path); its default path quantises to 256
    levels and passes no gradient through the equalisation curve.

Speed:
    On the CPU without autograd the global operators read the batch once for their statistics (the histogram
    operator reads it through adaptive average pooling), then map it tile by tile through cache-sized scratch
    buffers with in-place arithmetic and one write of the output; each operation on a tile runs on PyTorch's
    intra-op threads. Measured on (8, 3, 1024, 1024) float32 with ``scripts/bench_tonemap.py``: see the
    README for the ratios to ``tensor.clone()``. With autograd, or on other devices,
    the same formulas run as ordinary whole-tensor operations. CLAHE always runs through Kornia.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TypeVar

import kornia
import torch
import torch.nn.functional as F
from torch import nn

from torch_modulo._checks import check_floating, check_image_shape, check_nonnegative

__all__ = [
    "REC709_LUMA",
    "ClaheToneMap",
    "GammaToneMap",
    "HistogramToneMap",
    "LogToneMap",
    "ReinhardToneMap",
    "fovea_shape",
    "luminance",
    "tonemap_clahe",
    "tonemap_gamma",
    "tonemap_histogram",
    "tonemap_log",
    "tonemap_reinhard",
]

#: Luminance weights of linear Rec.709 (sRGB) primaries: ``Y = 0.2126 R + 0.7152 G + 0.0722 B``.
REC709_LUMA: tuple[float, float, float] = (0.2126, 0.7152, 0.0722)

#: Elements per tile on the CPU path: 8x PyTorch's intra-op grain size, so each operation on a tile is split over
#: PyTorch's threads, while a few such float32 buffers (1 MiB each) stay in the L2/L3 caches.
_TILE_ELEMS = 1 << 18


# ----------------------------------------------------------------------------------------------------------------
# validation and shared plumbing
# ----------------------------------------------------------------------------------------------------------------


def _number(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(f"{name} must be a real number; got {value!r}")
    return float(value)


def _positive(value: object, name: str, *, allow_inf: bool = False) -> float:
    v = _number(value, name)
    if math.isnan(v) or v <= 0 or (math.isinf(v) and not allow_inf):
        kind = "a positive number" if allow_inf else "a positive finite number"
        raise ValueError(f"{name} must be {kind}; got {value!r}")
    return v


def _finite(value: object, name: str) -> float:
    v = _number(value, name)
    if not math.isfinite(v):
        raise ValueError(f"{name} must be finite; got {value!r}")
    return v


def _integer(value: object, name: str, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name} must be an integer; got {value!r}")
    if value < minimum:
        raise ValueError(f"{name} must be >= {minimum}; got {value}")
    return int(value)


def _flag(value: object, name: str) -> bool:
    if not isinstance(value, bool):
        raise TypeError(f"{name} must be True or False; got {value!r}")
    return value


def _as_batch(hdr: object, name: str = "hdr") -> tuple[torch.Tensor, torch.Size]:
    """Validate an HDR image and return it as (B, C, H, W) with its original shape."""
    check_floating(hdr, name)
    assert isinstance(hdr, torch.Tensor)
    check_image_shape(hdr, name, 2, 4)
    shape = hdr.shape
    x = hdr
    if x.dim() == 2:
        x = x[None, None]
    elif x.dim() == 3:
        x = x[None]
    if x.shape[1] not in (1, 3):
        raise ValueError(
            f"{name} must have 1 (grey) or 3 (linear Rec.709 RGB) channels; got {x.shape[1]} in shape {tuple(shape)}"
        )
    if x.numel():
        # One fused pass: NaN propagates through min/max, infinities show as extremes.
        lo, hi = torch.aminmax(x.detach())
        lo_f, hi_f = float(lo), float(hi)
        if not (math.isfinite(lo_f) and math.isfinite(hi_f)) or lo_f < 0:
            check_nonnegative(x.detach(), name)
    return x, shape


def _restore(out: torch.Tensor, shape: torch.Size) -> torch.Tensor:
    return out.reshape(shape)


def _needs_grad(x: torch.Tensor) -> bool:
    return torch.is_grad_enabled() and x.requires_grad


def _tiled(x: torch.Tensor) -> bool:
    """Whether to take the in-place CPU path (no autograd, CPU tensor)."""
    return x.device.type == "cpu" and not _needs_grad(x)


def _tile_step(rows: int) -> int:
    """Columns per tile so that a (rows, step) buffer holds at most ``_TILE_ELEMS`` elements."""
    return max(64, _TILE_ELEMS // max(1, rows))


def _tiles(n: int, step: int) -> list[tuple[int, int]]:
    return [(s, min(n, s + step)) for s in range(0, n, step)]


_R = TypeVar("_R")


def _parallel_tiles(tiles: list[tuple[int, int]], worker: Callable[[Callable[[], int | None]], _R]) -> list[_R]:
    """Run ``worker`` over the tiles in order, in the calling thread.

    ``worker(next_tile)`` allocates its scratch buffers once and calls ``next_tile()`` for tile indices until it
    returns None. Each tile holds ``_TILE_ELEMS`` elements, above PyTorch's intra-op grain size, so every operation
    on it runs on PyTorch's own threads while the tile stays in cache. (Measured on 2 cores: this beat a Python
    thread pool over grain-sized tiles by 1.1-2.5x, and a 2-thread pool was no faster than one thread.)
    """
    counter = iter(range(len(tiles)))
    return [worker(lambda: next(counter, None))]


def _encode(out: torch.Tensor, srgb: bool) -> torch.Tensor:
    """Optionally apply the sRGB transfer function (values stay in [0, 1])."""
    if not srgb:
        return out
    if out.shape[1] == 1:
        return kornia.color.linear_rgb_to_rgb(out.expand(-1, 3, -1, -1))[:, :1].clamp(0.0, 1.0)
    return kornia.color.linear_rgb_to_rgb(out).clamp(0.0, 1.0)


def luminance(image: torch.Tensor) -> torch.Tensor:
    """Luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` of (B, 3, H, W) linear RGB, or the grey channel itself.

    Args:
        image: (B, C, H, W) with C = 1 or 3 (no value checks).

    Returns:
        (B, 1, H, W) luminance on the input's device and dtype.

    Example:
        >>> luminance(torch.ones(1, 3, 1, 2))
        tensor([[[[1., 1.]]]])
    """
    if image.dim() != 4 or image.shape[1] not in (1, 3):
        raise ValueError(f"image must have shape (B, 1, H, W) or (B, 3, H, W); got {tuple(image.shape)}")
    if image.shape[1] == 1:
        return image
    r, g, b = image[:, 0:1], image[:, 1:2], image[:, 2:3]
    return r * REC709_LUMA[0] + g * REC709_LUMA[1] + b * REC709_LUMA[2]


def _luminance_tile(tile: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """Luminance of a (B, C, n) tile written into the (B, n) buffer ``out``."""
    if tile.shape[1] == 1:
        return out.copy_(tile[:, 0])
    torch.mul(tile[:, 0], REC709_LUMA[0], out=out)
    out.add_(tile[:, 1], alpha=REC709_LUMA[1])
    return out.add_(tile[:, 2], alpha=REC709_LUMA[2])


#: A tile kernel turns luminance (B, n) into the factor that scales R, G, B, using scratch buffers (B, n).
_TileKernel = Callable[[torch.Tensor, list[torch.Tensor]], torch.Tensor]


def _map_tiled(x: torch.Tensor, kernel: _TileKernel, n_scratch: int, index_scratch: bool = False) -> torch.Tensor:
    """CPU path: ``out = clip(x * kernel(Y), 0, 1)`` tile by tile through cache-sized scratch buffers."""
    b, c, h, w = x.shape
    n = h * w
    x3 = x.reshape(b, c, n)
    out = torch.empty((b, c, h, w), dtype=x.dtype, device=x.device)
    o3 = out.view(b, c, n)
    step = min(n, _tile_step(b))
    tiles = _tiles(n, step)

    def worker(next_tile: Callable[[], int | None]) -> None:
        y = torch.empty((b, step), dtype=x.dtype, device=x.device)
        scratch = [torch.empty((b, step), dtype=x.dtype, device=x.device) for _ in range(n_scratch)]
        if index_scratch:
            scratch.append(torch.empty((b, step), dtype=torch.long, device=x.device))
        while (i := next_tile()) is not None:
            s, e = tiles[i]
            m = e - s
            tile = x3[:, :, s:e]
            ratio = kernel(_luminance_tile(tile, y[:, :m]), [buf[:, :m] for buf in scratch])
            for ch in range(c):
                torch.mul(tile[:, ch], ratio, out=o3[:, ch, s:e]).clamp_(0.0, 1.0)

    _parallel_tiles(tiles, worker)
    return out


def _luminance_stats_tiled(x: torch.Tensor, log_offset: float | None) -> tuple[torch.Tensor, torch.Tensor | None]:
    """One read of the batch: per-image max luminance and, if ``log_offset`` is given, sum of log(Y + offset).

    Partial results are kept per tile and added in tile order, so the result does not depend on threading.
    """
    b, c, h, w = x.shape
    n = h * w
    x3 = x.reshape(b, c, n)
    step = min(n, _tile_step(b))
    tiles = _tiles(n, step)
    maxima = torch.zeros((len(tiles), b), dtype=x.dtype, device=x.device)
    sums = None if log_offset is None else torch.zeros((len(tiles), b), dtype=torch.float64, device=x.device)

    def worker(next_tile: Callable[[], int | None]) -> None:
        y = torch.empty((b, step), dtype=x.dtype, device=x.device)
        while (i := next_tile()) is not None:
            s, e = tiles[i]
            yt = _luminance_tile(x3[:, :, s:e], y[:, : e - s])
            torch.amax(yt, dim=1, out=maxima[i])
            if sums is not None:
                torch.sum(yt.add_(log_offset).log_(), dim=1, dtype=torch.float64, out=sums[i])

    _parallel_tiles(tiles, worker)
    return maxima.amax(dim=0), None if sums is None else sums.sum(dim=0)


def _col(v: torch.Tensor) -> torch.Tensor:
    """(B,) -> (B, 1) for broadcasting against (B, n) tiles."""
    return v.reshape(-1, 1)


def _img(v: torch.Tensor) -> torch.Tensor:
    """(B,) -> (B, 1, 1, 1) for broadcasting against (B, C, H, W)."""
    return v.reshape(-1, 1, 1, 1)


# ----------------------------------------------------------------------------------------------------------------
# Reinhard et al. 2002
# ----------------------------------------------------------------------------------------------------------------


def _check_reinhard_args(key: object, white: object, delta: object) -> tuple[float, float | None, float]:
    key_f = _positive(key, "key")
    white_f = None if white is None else _positive(white, "white", allow_inf=True)
    return key_f, white_f, _positive(delta, "delta")


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
        Display values in ``[0, 1]``, same shape, dtype and device as ``hdr``.

    Example:
        >>> x = torch.tensor([[1.0, 4.0], [16.0, 64.0]])
        >>> tonemap_reinhard(x, key=0.5, white=float("inf"), delta=1e-12)  # log average 8: L = x / 16
        tensor([[0.0588, 0.2000],
                [0.5000, 0.8000]])
    """
    key, white, delta = _check_reinhard_args(key, white, delta)
    x, shape = _as_batch(hdr)
    if x.numel() == 0:
        return _restore(x.clone(), shape)
    h, w = x.shape[-2:]
    if _tiled(x):
        y_max, log_sum = _luminance_stats_tiled(x, delta)
        assert log_sum is not None
        scale = (key / torch.exp(log_sum / (h * w))).to(x.dtype)
        inv_w2 = _inverse_white_squared(white, y_max * scale)
        # Ld / Lw = s (1 + L / Lwhite²) / (1 + L) with L = s Lw, s = a / L̄w: (s + s² / Lwhite² Lw) / (1 + s Lw)
        s_col, a_col = _col(scale), _col(scale * scale * inv_w2)

        def kernel(y: torch.Tensor, buf: list[torch.Tensor]) -> torch.Tensor:
            num = torch.mul(y, a_col, out=buf[0]).add_(s_col)
            return num.div_(y.mul_(s_col).add_(1.0))

        out = _map_tiled(x, kernel, 1)
    else:
        y = luminance(x)
        log_avg = torch.exp(torch.log(y + delta).mean(dim=(1, 2, 3)))
        scale = key / log_avg
        inv_w2 = _inverse_white_squared(white, y.amax(dim=(1, 2, 3)) * scale)
        big_l = y * _img(scale)
        ratio = _img(scale) * (1.0 + big_l * _img(inv_w2)) / (1.0 + big_l)
        out = (x * ratio).clamp(0.0, 1.0)
    return _restore(_encode(out, srgb), shape)


def _inverse_white_squared(white: float | None, scaled_max: torch.Tensor) -> torch.Tensor:
    """``1 / L_white²`` per image, 0 for an infinite white or an all-black image."""
    if white is not None:
        return torch.full_like(scaled_max, 0.0 if math.isinf(white) else 1.0 / (white * white))
    safe = torch.where(scaled_max > 0, scaled_max, torch.ones_like(scaled_max))
    return torch.where(scaled_max > 0, 1.0 / (safe * safe), torch.zeros_like(scaled_max))


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
        self.srgb = _flag(srgb, "srgb")

    def forward(self, hdr: torch.Tensor) -> torch.Tensor:
        return tonemap_reinhard(hdr, self.key, self.white, delta=self.delta, srgb=self.srgb)

    def extra_repr(self) -> str:
        return f"key={self.key}, white={self.white}, delta={self.delta}, srgb={self.srgb}"


# ----------------------------------------------------------------------------------------------------------------
# exposure and gamma
# ----------------------------------------------------------------------------------------------------------------


def _check_gamma_args(gamma: object, exposure: object, percentile: object) -> tuple[float, float, float | None]:
    gamma_f = _positive(gamma, "gamma")
    exposure_f = _finite(exposure, "exposure")
    pct = None
    if percentile is not None:
        pct = _number(percentile, "percentile")
        if not 0 < pct <= 100:
            raise ValueError(f"percentile must be in (0, 100]; got {percentile!r}")
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
        exposure: exposure adjustment :math:`EV` in stops (the radiance is multiplied by ``2**exposure``).
        percentile: if given, ``s`` makes this percentile of each image's luminance reach 1 before the
            exposure adjustment (auto exposure per image: ``percentile=99`` clips the brightest 1%); by default
            ``s = 1`` and the radiance's own scale is used.
        srgb: apply the sRGB transfer function after the gamma (usually with ``gamma=1``).

    Returns:
        Display values in ``[0, 1]``, same shape, dtype and device as ``hdr``. Values whose exposed radiance
        exceeds 1 clip to 1; colour ratios are not kept (the curve works on each channel).

    Example:
        >>> tonemap_gamma(torch.tensor([[0.0, 0.25], [1.0, 8.0]]), gamma=2.0)
        tensor([[0.0000, 0.5000],
                [1.0000, 1.0000]])
    """
    gamma, exposure, pct = _check_gamma_args(gamma, exposure, percentile)
    x, shape = _as_batch(hdr)
    if x.numel() == 0:
        return _restore(x.clone(), shape)
    scale = torch.full((x.shape[0],), 2.0**exposure, dtype=x.dtype, device=x.device)
    if pct is not None:
        ref = _percentile_luminance(x.detach() if not _needs_grad(x) else x, pct)
        top = x.detach().amax(dim=(1, 2, 3)) if not _needs_grad(x) else x.amax(dim=(1, 2, 3))
        ref = torch.where(ref > 0, ref, torch.where(top > 0, top, torch.ones_like(top)))
        scale = scale / ref
    inv_gamma = 1.0 / gamma
    if _tiled(x):
        b, c, h, w = x.shape
        n = h * w
        x3 = x.reshape(b, c, n)
        out = torch.empty_like(x, memory_format=torch.contiguous_format)
        o3 = out.view(b, c, n)
        s3 = scale.reshape(-1, 1, 1)
        tiles = _tiles(n, min(n, _tile_step(b * c)))

        def worker(next_tile: Callable[[], int | None]) -> None:
            while (i := next_tile()) is not None:
                s, e = tiles[i]
                o = o3[:, :, s:e]
                torch.mul(x3[:, :, s:e], s3, out=o).clamp_(0.0, 1.0)
                if inv_gamma != 1.0:
                    o.log_().mul_(inv_gamma).exp_()  # x ** (1 / gamma), faster than pow_; log(0) = -inf gives 0

        _parallel_tiles(tiles, worker)
    else:
        out = (x * _img(scale)).clamp(0.0, 1.0)
        if inv_gamma != 1.0:
            # d/dx x^(1/g) is infinite at 0 for g > 1: keep the gradient finite there.
            out = torch.where(out > 0, out.clamp_min(torch.finfo(x.dtype).tiny) ** inv_gamma, out)
    return _restore(_encode(out, srgb), shape)


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
        self.srgb = _flag(srgb, "srgb")

    def forward(self, hdr: torch.Tensor) -> torch.Tensor:
        return tonemap_gamma(hdr, self.gamma, self.exposure, percentile=self.percentile, srgb=self.srgb)

    def extra_repr(self) -> str:
        return f"gamma={self.gamma}, exposure={self.exposure}, percentile={self.percentile}, srgb={self.srgb}"


# ----------------------------------------------------------------------------------------------------------------
# logarithmic mapping
# ----------------------------------------------------------------------------------------------------------------


def _check_log_args(q: object, k: object, exposure: object) -> tuple[float, float, float]:
    return _positive(q, "q"), _positive(k, "k"), _finite(exposure, "exposure")


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
            scale).
        srgb: apply the sRGB transfer function to the result.

    Returns:
        Display values in ``[0, 1]``, same shape, dtype and device as ``hdr``.

    Example:
        >>> tonemap_log(torch.tensor([[0.0, 1.0], [3.0, 15.0]]))
        tensor([[0.0000, 0.2500],
                [0.5000, 1.0000]])
    """
    q, k, exposure = _check_log_args(q, k, exposure)
    x, shape = _as_batch(hdr)
    if x.numel() == 0:
        return _restore(x.clone(), shape)
    s = 2.0**exposure
    tiny = torch.finfo(x.dtype).tiny
    if _tiled(x):
        y_max, _ = _luminance_stats_tiled(x, None)
        denom = torch.log1p(k * s * y_max)
        # Ld / Y = log1p(q s Y) / (Y log1p(k s Ymax))
        inv_col = _col(1.0 / torch.where(denom > 0, denom, torch.ones_like(denom)))

        def kernel(y: torch.Tensor, buf: list[torch.Tensor]) -> torch.Tensor:
            y.clamp_min_(tiny)
            ld = torch.mul(y, q * s, out=buf[0]).log1p_()
            return ld.div_(y).mul_(inv_col)

        out = _map_tiled(x, kernel, 1)
    else:
        big_l = luminance(x) * s
        denom = torch.log1p(k * big_l.amax(dim=(1, 2, 3)))
        denom = torch.where(denom > 0, denom, torch.ones_like(denom))
        big_l = big_l.clamp_min(tiny)
        ratio = s * torch.log1p(q * big_l) / (big_l * _img(denom))
        out = (x * ratio).clamp(0.0, 1.0)
    return _restore(_encode(out, srgb), shape)


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
        self.srgb = _flag(srgb, "srgb")

    def forward(self, hdr: torch.Tensor) -> torch.Tensor:
        return tonemap_log(hdr, self.q, self.k, self.exposure, srgb=self.srgb)

    def extra_repr(self) -> str:
        return f"q={self.q}, k={self.k}, exposure={self.exposure}, srgb={self.srgb}"


# ----------------------------------------------------------------------------------------------------------------
# Larson, Rushmeier and Piatko 1997: histogram adjustment
# ----------------------------------------------------------------------------------------------------------------


def _check_histogram_args(
    ld_min: object,
    ld_max: object,
    bins: object,
    fov: object,
    fovea: object,
    tolerance: object,
    max_iter: object,
) -> tuple[float, float, int, float, float, float, int]:
    ld_min_f = _positive(ld_min, "ld_min")
    ld_max_f = _positive(ld_max, "ld_max")
    if ld_max_f <= ld_min_f:
        raise ValueError(f"ld_max must be greater than ld_min; got ld_min={ld_min!r}, ld_max={ld_max!r}")
    bins_i = _integer(bins, "bins", 2)
    fov_f = _positive(fov, "fov")
    if fov_f >= 180:
        raise ValueError(f"fov must be below 180 degrees; got {fov!r}")
    fovea_f = _positive(fovea, "fovea")
    tol = _number(tolerance, "tolerance")
    if not 0 < tol < 1:
        raise ValueError(f"tolerance must be in (0, 1); got {tolerance!r}")
    return ld_min_f, ld_max_f, bins_i, fov_f, fovea_f, tol, _integer(max_iter, "max_iter", 1)


def fovea_shape(height: int, width: int, fov: float = 40.0, fovea: float = 1.0) -> tuple[int, int]:
    """Size of the foveal image: one sample per ``fovea`` degrees when the longer side spans ``fov`` degrees.

    As in Radiance's ``pcond`` (Larson's own implementation): a perspective view whose longer side spans
    ``fov`` degrees has ``2 tan(fov / 2) / fovea_radians`` fovea-sized samples across it (42 for 40 degrees),
    the shorter side proportionally fewer; at least 2 each, and never more than the image has.

    Example:
        >>> fovea_shape(768, 512)
        (42, 28)
    """
    _integer(height, "height", 1)
    _integer(width, "width", 1)
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
        ld_max: display white luminance :math:`L_{d,max}` (default 100:1 display).
        bins: histogram bins (the paper and ``pcond`` use 100).
        fov: angle in degrees spanned by the image's longer side (``pcond``'s default view is 40 degrees).
        fovea: foveal sample size in degrees (1 in the paper).
        tolerance: share of the original histogram total at which the ceiling loop stops (0.025 in the paper).
        max_iter: safety bound on ceiling iterations; the loop ends far sooner in practice (bins only shrink).
        srgb: apply the sRGB transfer function to the result.

    Returns:
        Display values in ``[0, 1]``, same shape, dtype and device as ``hdr``.

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
    x, shape = _as_batch(hdr)
    if x.numel() == 0:
        return _restore(x.clone(), shape)
    b, _, h, w = x.shape
    grad = _needs_grad(x)
    src = x if grad else x.detach()
    fov_img = F.adaptive_avg_pool2d(src, fovea_shape(h, w, fov, fovea))
    lo, scale, cumf, slope = _histogram_tables(
        luminance(fov_img).reshape(b, -1), ld_min, ld_max, bins, tolerance, max_iter
    )
    span = math.log(ld_max) - math.log(ld_min)
    c = ld_min / (ld_max - ld_min)  # (Ld - Ld_min) / (Ld_max - Ld_min) = c * expm1(span * P)
    tiny = torch.finfo(x.dtype).tiny
    if _tiled(x):
        # span * P = span * (cumf[i] + (u - i) slope[i]) = offset[i] + u * steep[i]: one gather fewer per pixel.
        steep = span * slope
        offset = span * cumf - torch.arange(bins + 1, dtype=x.dtype, device=x.device) * steep
        shift_col, scale_col = _col(-lo * scale), _col(scale)

        def kernel(y: torch.Tensor, buf: list[torch.Tensor]) -> torch.Tensor:
            u, tmp, idx = buf
            y.clamp_min_(tiny)
            torch.addcmul(shift_col, torch.log(y, out=u), scale_col, out=u).clamp_(0.0, float(bins))
            idx.copy_(u)  # truncation == floor for u >= 0
            u.mul_(torch.gather(steep, 1, idx, out=tmp)).add_(torch.gather(offset, 1, idx, out=tmp))
            return u.expm1_().div_(y).mul_(c)

        out = _map_tiled(x, kernel, 2, index_scratch=True)
    else:
        y = luminance(x).reshape(b, -1).clamp_min(tiny)
        u = ((torch.log(y) - lo[:, None]) * scale[:, None]).clamp(0.0, float(bins))
        i = u.detach().floor().long()
        p = torch.gather(cumf, 1, i) + (u - i.to(u.dtype)) * torch.gather(slope, 1, i)
        ratio = c * torch.expm1(span * p) / y
        out = (x * ratio.reshape(b, 1, h, w)).clamp(0.0, 1.0)
    return _restore(_encode(out, srgb), shape)


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
        self.srgb = _flag(srgb, "srgb")

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


# ----------------------------------------------------------------------------------------------------------------
# CLAHE on log luminance
# ----------------------------------------------------------------------------------------------------------------


def _check_clahe_args(clip_limit: object, grid_size: object, differentiable: object) -> tuple[float, tuple[int, int]]:
    clip = _number(clip_limit, "clip_limit")
    if not math.isfinite(clip) or clip < 0:
        raise ValueError(f"clip_limit must be >= 0 (0 disables clipping); got {clip_limit!r}")
    if not isinstance(grid_size, tuple | list) or len(grid_size) != 2:
        raise TypeError(f"grid_size must be a pair of integers (rows, columns); got {grid_size!r}")
    grid = (_integer(grid_size[0], "grid_size[0]", 1), _integer(grid_size[1], "grid_size[1]", 1))
    _flag(differentiable, "differentiable")
    return clip, grid


def tonemap_clahe(
    hdr: torch.Tensor,
    clip_limit: float = 2.0,
    grid_size: tuple[int, int] = (8, 8),
    *,
    differentiable: bool = False,
    srgb: bool = False,
) -> torch.Tensor:
    r"""Contrast-limited adaptive histogram equalisation of log luminance (``kornia.enhance.equalize_clahe``).

    Per image, brightness :math:`\log Y` is scaled into ``[0, 1]`` between its minimum over non-zero pixels and
    its maximum (Kornia's CLAHE needs values in ``[0, 1]``), equalised by CLAHE, and used as the display
    luminance; R, G and B are scaled by the same factor (black pixels take the equalised value as grey). This
    is the "adaptive histogram equalization" the paper's figures are often taken to mean; the operator the
    paper cites is :func:`tonemap_histogram`.

    Args:
        hdr: linear radiance, (B, C, H, W), (C, H, W) or (H, W), C = 1 or 3, values >= 0.
        clip_limit: CLAHE contrast limit (OpenCV's meaning; 0 disables limiting; Kornia's default is 40).
        grid_size: tiles along (H, W); the image must be larger than the grid along each axis.
        differentiable: use Kornia's slow, differentiable path; the default fast path quantises brightness to
            256 levels and passes no gradient through the equalisation.
        srgb: apply the sRGB transfer function to the result.

    Returns:
        Display values in ``[0, 1]``, same shape, dtype and device as ``hdr``. Monotonic in luminance at each
        pixel position; a local operator, so not between positions (with ``grid_size=(1, 1)`` it is global).

    Example:
        >>> x = torch.logspace(0, 6, 16).reshape(4, 4)
        >>> y = tonemap_clahe(x, clip_limit=0.0, grid_size=(1, 1))
        >>> bool((y.flatten().diff() >= 0).all()), round(float(y.min()), 3), float(y.max())
        (True, 0.063, 1.0)
    """
    clip, grid = _check_clahe_args(clip_limit, grid_size, differentiable)
    x, shape = _as_batch(hdr)
    if x.numel() == 0:
        return _restore(x.clone(), shape)
    h, w = x.shape[-2:]
    if h <= grid[0] or w <= grid[1]:
        raise ValueError(
            f"tonemap_clahe needs an image larger than grid_size={grid} along each axis; got {h}x{w} "
            f"(use a smaller grid_size)"
        )
    src = x if _needs_grad(x) else x.detach()
    y = luminance(src)
    pos = y > 0
    bright = torch.log(torch.where(pos, y, torch.ones_like(y)))
    inf = torch.tensor(math.inf, dtype=x.dtype, device=x.device)
    lo = torch.where(pos, bright, inf).amin(dim=(1, 2, 3), keepdim=True)
    hi = torch.where(pos, bright, -inf).amax(dim=(1, 2, 3), keepdim=True)
    ok = torch.isfinite(lo) & (hi > lo)
    lo = torch.where(torch.isfinite(lo), lo, torch.zeros_like(lo))
    width = torch.where(ok, hi - lo, torch.ones_like(lo))
    level = torch.where(pos, (bright - lo) / width, torch.zeros_like(bright)).clamp(0.0, 1.0)
    eq = kornia.enhance.equalize_clahe(level, clip, grid, slow_and_differentiable=differentiable)
    if x.shape[1] == 1:
        out = eq.clamp(0.0, 1.0)
    else:
        ratio = eq / y.clamp_min(torch.finfo(x.dtype).tiny)
        out = torch.where(pos, src * ratio, eq.expand_as(src)).clamp(0.0, 1.0)
    return _restore(_encode(out, srgb), shape)


class ClaheToneMap(nn.Module):
    """Module twin of :func:`tonemap_clahe` (CLAHE on log luminance).

    Shape:
        - Input: (B, C, H, W), (C, H, W) or (H, W) with C = 1 or 3; H and W larger than the grid.
        - Output: same as input, values in [0, 1].

    Example:
        >>> ClaheToneMap(grid_size=(2, 2))(torch.rand(1, 3, 16, 16) * 1000).shape
        torch.Size([1, 3, 16, 16])
    """

    def __init__(
        self,
        clip_limit: float = 2.0,
        grid_size: tuple[int, int] = (8, 8),
        differentiable: bool = False,
        srgb: bool = False,
    ) -> None:
        super().__init__()
        self.clip_limit, self.grid_size = _check_clahe_args(clip_limit, grid_size, differentiable)
        self.differentiable = differentiable
        self.srgb = _flag(srgb, "srgb")

    def forward(self, hdr: torch.Tensor) -> torch.Tensor:
        return tonemap_clahe(hdr, self.clip_limit, self.grid_size, differentiable=self.differentiable, srgb=self.srgb)

    def extra_repr(self) -> str:
        return (
            f"clip_limit={self.clip_limit}, grid_size={self.grid_size}, differentiable={self.differentiable}, "
            f"srgb={self.srgb}"
        )
