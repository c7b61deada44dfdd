"""Multi-shot UHDR (paper Sec. 5): rollover counting over an exposure stack (Eqs. 6-7), exposure planning, and
the conventional multi-exposure merge of clipped frames that the paper compares against.

Eqs. 6-7 as printed: sort by exposure ``tau``; ``E^(0) = 0``;

    k^(i) = floor(tau^(i) E^(i-1) / 2^N),    E^(i) = (k^(i) 2^N + I_m^(i)) / tau^(i).

Because ``E^(i-1)`` is the *lower* edge of a quantisation cell, the printed floor picks the wrong ``k`` on a large
share of pixels whenever the neighbouring exposure ratio ``r`` is not exactly ``2^N`` (about a third of the pixels
for 1:100:10000 at 8 bits, noise-free). ``method="robust"`` (the default) predicts the next count from the centre
of the previous cell and rounds against the observed modulus:

    k^(i) = round((r (I^(i-1) + 1/2) - 1/2 - I_m^(i)) / 2^N),    I^(i) = I_m^(i) + k^(i) 2^N,

which is exact, noise-free, for every ratio ``1 <= r <= 2^N - 1`` and for every integer ratio up to ``2^N``. (For a
non-integer ratio strictly between ``2^N - 1`` and ``2^N`` the counts behind one count of the shorter exposure span
up to ``2^N + 1`` values, so no rule can be exact there; such ratios are accepted and are right on all but a small
share of pixels.) Both return ``E = I^(M) / tau^(M)`` (Eq. 7's
convention: the lower edge of the final cell) or, with ``return_counts=True``, the integer counts ``I^(M)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn

from torch_modulo._checks import (
    check_bits,
    check_finite,
    check_floating,
    check_modulus,
    exposure_tensor,
)
from torch_modulo.capture import column_tiles

__all__ = [
    "IntensityMerge",
    "MultiExposureUnwrap",
    "merge_intensity",
    "plan_exposures",
    "unwrap_multi",
]

_METHODS = ("robust", "paper")
_WEIGHTS = ("binary", "hat")


def _stack_exposures(
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


def _sorted(stack: torch.Tensor, tau: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Sort each batch item's exposures ascending, reordering frames only when needed."""
    tau_sorted, order = torch.sort(tau, dim=1, stable=True)
    identity = torch.arange(tau.shape[1], device=tau.device).expand_as(order)
    if torch.equal(order, identity):
        return stack, tau_sorted
    if bool((order == order[:1]).all()):
        return stack[:, order[0]], tau_sorted
    index = order.view(*order.shape, 1, 1, 1).expand(-1, -1, *stack.shape[2:])
    return torch.take_along_dim(stack, index, dim=1), tau_sorted


def _check_ratios(tau: torch.Tensor, bits: int) -> torch.Tensor:
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


def unwrap_multi(
    moduli: torch.Tensor,
    exposures: Sequence[float] | torch.Tensor,
    bits: int = 8,
    method: str = "robust",
    *,
    return_counts: bool = False,
) -> torch.Tensor:
    r"""Recover radiance from modulus images taken at several exposures (paper Sec. 5.2, Eqs. 6-7).

    Exposures may come in any order; they are sorted per batch item. The shortest exposure must not roll over
    (its modulus is taken as its count), and neighbouring exposure ratios must not exceed ``2**bits``.

    The work is vectorised over batch, exposures' pixels and channels. On the CPU it runs over cache-sized tiles
    of pixels (all batch items at once) with float64 arithmetic in place, so the decisions are exact for counts up
    to ``2**53`` and the cost stays close to a copy of the data; on other devices it runs on whole tensors.
    The result carries no gradient (rollover counts are discrete).

    Args:
        moduli: modulus images, (B, M, C, H, W) or (M, C, H, W), floating, integers in ``[0, 2**bits)``.
        exposures: ``tau`` > 0 per exposure: (M,) shared by the batch, or (B, M).
        bits: the sensor's bit depth ``N``.
        method: ``"robust"`` (default; exact for every neighbouring ratio up to ``2**bits - 1`` and for integer
            ratios up to ``2**bits``) or ``"paper"``
            (Eq. 6 as printed; wrong on many pixels unless the ratios are exactly ``2**bits``).
        return_counts: return the restored counts ``I = I_m + k 2^N`` at the longest exposure instead of radiance.

    Returns:
        Radiance ``I / tau_max`` (or the counts ``I``), (B, C, H, W) or (C, H, W), same dtype and device as
        ``moduli``. Counts above ``2**24`` are rounded in float32: use float64 for them.

    Raises:
        TypeError: ``moduli`` is not a floating tensor, or ``exposures`` not numbers.
        ValueError: bad shapes, values outside ``[0, 2**bits)``, non-integers, NaN/Inf, non-positive exposures, a
            neighbouring ratio above ``2**bits``, or an unknown method.

    Example:
        >>> from torch_modulo import capture_modulo
        >>> radiance = torch.tensor([[[[0.25, 2.75, 70.5]]]])            # (B, C, H, W) = (1, 1, 1, 3)
        >>> taus = [1.0, 100.0, 10000.0]
        >>> stack = torch.stack([capture_modulo(radiance, t, bits=8) for t in taus], dim=1)
        >>> unwrap_multi(stack, taus, bits=8, return_counts=True)
        tensor([[[[  2500.,  27500., 705000.]]]])
        >>> unwrap_multi(stack, taus, bits=8, method="paper", return_counts=True)
        tensor([[[[  2500.,   1900., 705000.]]]])
    """
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}; got {method!r}")
    stack, tau, unbatched = _stack_exposures(moduli, exposures, "moduli")
    bits = check_bits(bits, moduli.dtype)
    stack, tau = _sorted(stack, tau)
    ratios = _check_ratios(tau, bits)
    b, m = stack.shape[:2]
    pixel_shape = stack.shape[2:]
    n = math.prod(pixel_shape)
    out = torch.empty((b, n), dtype=moduli.dtype, device=moduli.device)
    if out.numel():
        frames = stack.detach().reshape(b, m, n)
        _unwrap_tiles(frames, tau, ratios, bits, method, return_counts, out)
    out = out.view(b, *pixel_shape)
    return out[0] if unbatched else out


def _unwrap_tiles(
    frames: torch.Tensor,
    tau: torch.Tensor,
    ratios: torch.Tensor,
    bits: int,
    method: str,
    return_counts: bool,
    out: torch.Tensor,
) -> None:
    """Run Eqs. 6-7 (or the robust rule) tile by tile, validating each tile's moduli on the way."""
    b, m, n = frames.shape
    period = float(2**bits)
    inv_p = 1.0 / period
    on_cpu = frames.device.type == "cpu"
    tiles = column_tiles(n, b) if on_cpu else [slice(0, n)]  # float64 work stays in cache on the CPU
    tile = tiles[0].stop
    work = torch.float64 if (on_cpu or frames.device.type == "cuda") else frames.dtype
    scale = (ratios * inv_p).to(work).unsqueeze(-1)  # (B, M-1, 1): r / P
    tau_max = tau[:, -1:].to(work)
    counts = torch.empty((b, min(tile, n)), dtype=work, device=frames.device)
    scratch = torch.empty((b, min(tile, n)), dtype=frames.dtype, device=frames.device)
    bad = False
    for cols in tiles:
        width = cols.stop - cols.start
        acc, tmp = counts[:, :width], scratch[:, :width]
        for i in range(m):
            m_i = frames[:, i, cols]
            lo, hi = torch.aminmax(m_i)
            bad |= not (float(lo) >= 0.0 and float(hi) < period)  # NaN fails both comparisons
            bad |= not torch.equal(torch.floor(m_i, out=tmp), m_i)
            if i == 0:
                acc.copy_(m_i)
                continue
            s = scale[:, i - 1]
            if method == "robust":
                # k >= 0: under noise the rounding can ask for k = -1 on dark pixels; no counter runs backwards.
                acc.add_(0.5).mul_(s).sub_(m_i, alpha=inv_p).sub_(0.5 * inv_p).round_().clamp_min_(0.0)
            else:
                acc.mul_(s).floor_()
            torch.add(m_i, acc, alpha=period, out=acc)
        if return_counts:
            out[:, cols].copy_(acc)
        else:
            torch.div(acc, tau_max, out=acc)
            out[:, cols].copy_(acc)
    if bad:  # diagnose with the slow, precise checks
        check_finite(frames, "moduli")
        check_modulus(frames, bits, "moduli")


def merge_intensity(
    frames: torch.Tensor,
    exposures: Sequence[float] | torch.Tensor,
    bits: int = 8,
    *,
    weights: str = "binary",
) -> torch.Tensor:
    """Conventional multi-exposure HDR merge of clipped frames: the baseline the paper compares against.

    Each frame gives the estimate ``I / tau`` (the same convention as Eq. 7). ``weights="binary"`` (the paper's
    Sec. 5.2 description) averages the estimates of frames that are neither under-exposed (``I = 0``) nor saturated
    (``I = 2**bits - 1``); ``weights="hat"`` uses Debevec and Malik's (1997) triangle ``min(I, 2**bits - 1 - I)``.
    A pixel with no usable frame takes the shortest exposure's estimate if it is saturated there (a lower bound)
    and otherwise the longest exposure's (0 for a pixel that is black everywhere).

    Args:
        frames: intensity images (B, M, C, H, W) or (M, C, H, W), integers in ``[0, 2**bits)``.
        exposures: (M,) or (B, M), any order.
        bits: the sensor's bit depth.
        weights: ``"binary"`` or ``"hat"``.

    Returns:
        Radiance (B, C, H, W) or (C, H, W), same dtype and device as ``frames``.

    Example:
        >>> frames = torch.tensor([[[[10.0]]], [[[160.0]]], [[[255.0]]]])   # (M, C, H, W), 8 bits
        >>> merge_intensity(frames, [1.0, 16.0, 256.0], bits=8)
        tensor([[[10.]]])
    """
    if weights not in _WEIGHTS:
        raise ValueError(f"weights must be one of {_WEIGHTS}; got {weights!r}")
    stack, tau, unbatched = _stack_exposures(frames, exposures, "frames")
    bits = check_bits(bits, frames.dtype)
    check_modulus(stack, bits, "frames")
    stack, tau = _sorted(stack, tau)
    top = float(2**bits - 1)
    tau_b = tau.to(frames.dtype).view(*tau.shape, 1, 1, 1)
    estimates = stack / tau_b
    if weights == "binary":
        w = ((stack > 0) & (stack < top)).to(frames.dtype)
    else:
        w = torch.minimum(stack, top - stack)
    total = w.sum(dim=1)
    merged = (w * estimates).sum(dim=1) / total.clamp_min(torch.finfo(frames.dtype).tiny)
    fallback = torch.where(stack[:, 0] >= top, estimates[:, 0], estimates[:, -1])
    out = torch.where(total > 0, merged, fallback)
    return out[0] if unbatched else out


def plan_exposures(
    stops: float,
    bits: int = 8,
    *,
    base: float = 1.0,
    max_ratio: float | None = None,
) -> list[float]:
    """The fewest exposures whose modulo captures cover a scene of ``stops`` stops.

    A scene spans ``E_max / E_min = 2**stops``. The shortest exposure ``base`` must not roll over at ``E_max``
    (``base * E_max < 2**bits``), and the longest must give ``E_min`` at least one count, so the exposures must span
    ``2**stops / 2**bits``, with neighbouring ratios of at most ``max_ratio``. The ratios are spread evenly.

    Args:
        stops: the scene's dynamic range, ``log2(E_max / E_min)``, >= 0.
        bits: the sensor's bit depth.
        base: the shortest exposure.
        max_ratio: the largest neighbouring ratio; default ``2**bits - 1``, which leaves a margin for noise
            (:func:`unwrap_multi` accepts up to ``2**bits`` noise-free).

    Returns:
        Exposures in ascending order, starting at ``base``.

    Example:
        >>> plan_exposures(24, bits=8, max_ratio=256)     # the paper: three 8-bit captures cover 24 stops
        [1.0, 256.0, 65536.0]
        >>> len(plan_exposures(24, bits=8))               # with ratios <= 255 it takes four
        4
    """
    if isinstance(stops, bool) or not isinstance(stops, int | float) or not math.isfinite(stops) or stops < 0:
        raise ValueError(f"stops must be a finite number >= 0; got {stops!r}")
    bits = check_bits(bits, torch.float64)
    if isinstance(base, bool) or not isinstance(base, int | float) or not math.isfinite(base) or base <= 0:
        raise ValueError(f"base must be a positive finite number; got {base!r}")
    limit = float(2**bits - 1 if max_ratio is None else max_ratio)
    if not math.isfinite(limit) or limit <= 1 or limit > 2**bits:
        raise ValueError(f"max_ratio must be in (1, 2^bits = {2**bits}]; got {max_ratio!r}")
    span_log2 = stops - bits
    if span_log2 <= 0:
        return [float(base)]
    count = 1 + math.ceil(span_log2 / math.log2(limit) - 1e-12)
    step = 2.0 ** (span_log2 / (count - 1))
    return [float(base * step**i) for i in range(count)]


class MultiExposureUnwrap(nn.Module):
    """Module twin of :func:`unwrap_multi` (Eqs. 6-7).

    Args:
        bits: the sensor's bit depth.
        method: ``"robust"`` (default) or ``"paper"``.
        return_counts: return counts at the longest exposure instead of radiance.

    Shape:
        - Input: moduli (B, M, C, H, W) or (M, C, H, W); exposures (M,) or (B, M).
        - Output: (B, C, H, W) or (C, H, W).

    Example:
        >>> layer = MultiExposureUnwrap(bits=4)
        >>> layer(torch.tensor([[[[3.0]]], [[[4.0]]]]), torch.tensor([1.0, 16.0]))   # (M, C, H, W)
        tensor([[[3.2500]]])
    """

    def __init__(self, bits: int = 8, method: str = "robust", return_counts: bool = False) -> None:
        super().__init__()
        if method not in _METHODS:
            raise ValueError(f"method must be one of {_METHODS}; got {method!r}")
        self.bits = check_bits(bits, torch.float64)
        self.method = method
        self.return_counts = bool(return_counts)

    def forward(self, moduli: torch.Tensor, exposures: Sequence[float] | torch.Tensor) -> torch.Tensor:
        return unwrap_multi(moduli, exposures, self.bits, self.method, return_counts=self.return_counts)

    def extra_repr(self) -> str:
        return f"bits={self.bits}, method={self.method!r}, return_counts={self.return_counts}"


class IntensityMerge(nn.Module):
    """Module twin of :func:`merge_intensity` (the conventional-sensor baseline).

    Example:
        >>> IntensityMerge(bits=4)(torch.tensor([[[[15.0]]], [[[15.0]]]]), [1.0, 4.0])
        tensor([[[15.]]])
    """

    def __init__(self, bits: int = 8, weights: str = "binary") -> None:
        super().__init__()
        if weights not in _WEIGHTS:
            raise ValueError(f"weights must be one of {_WEIGHTS}; got {weights!r}")
        self.bits = check_bits(bits, torch.float64)
        self.weights = weights

    def forward(self, frames: torch.Tensor, exposures: Sequence[float] | torch.Tensor) -> torch.Tensor:
        return merge_intensity(frames, exposures, self.bits, weights=self.weights)

    def extra_repr(self) -> str:
        return f"bits={self.bits}, weights={self.weights!r}"
