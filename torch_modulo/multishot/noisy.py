r"""Noise-aware rollover counting: decode each frame only as far as the noise model says its count is determined.

Under noise the robust rule's prediction of the next count, ``r (I^(i-1) + 1/2)``, is off by the ratio ``r`` times
the previous frame's noise plus the new frame's own noise; once that spread nears half a period the rounding picks a
wrong rollover count, and every later frame inherits the error. This decoder walks each pixel's frames from the
shortest and keeps, from the :class:`~torch_modulo.noise.NoiseModel`, the variance of its running radiance
estimate. Frame ``i`` is decoded only while the predicted count's standard deviation,

.. math:: s_i = \sqrt{\tau_i^2 \operatorname{Var}(\hat E) + \operatorname{Var}(I^{(i)})},

stays within ``2^N / (2 z)`` (``z`` = ``sigmas``: the rounding is then wrong with probability about that of a
``z``-sigma Gaussian tail); from the first frame where it does not, the pixel's remaining frames are ignored (their
noise only grows with the exposure).

The radiance is then the weighted least-squares fit of the decoded counts to their expected values under the noise
model. A frame whose expected count (signal plus dark) is ``x`` reads on average

.. math:: \mathrm{E}[I] = x - \tfrac12 + b(x),

where ``b`` is what the counter's clip at zero (a negative charge reads 0) and, where the noise does not smooth it,
its floor add to the smooth ``x - 1/2``. :func:`_clip_curve` tabulates ``b`` once per noise model: exactly, over
Poisson electrons and Gaussian read noise, where a count is at most 64 electrons; with many electrons per count
the charge is Gaussian on the count scale (spread ``s^2 = x / q + (\sigma_r / q)^2``) and
``b = \sum_{j \ge 0} P(y < -j) \approx s\,G(z) - \varphi(z) / (24 s)``, ``z = (x - 1/2) / s``, ``G`` the Gaussian
loss function (the midpoint rule for the sum). ``b`` is about 0.68 counts at ``x = 0`` for a 1-count read noise,
and vanishes a few ``s`` above zero. The estimate ``E`` solves

.. math:: \sum_i \frac{\tau_i}{\operatorname{Var}(I^{(i)})} \left(I^{(i)} + \tfrac12 - d_i - b(\tau_i E + d_i)
   - \tau_i E\right) = 0

over the decoded frames (``d_i`` the dark counts; every variance at one common radiance, the clip-corrected running
estimate, so that a frame's own noise does not set its weight); it is clamped at 0. Without the ``b`` term the
short frames of a dark pixel, which read 0 or 1 where their expected count is far below one, lift its estimate by
about a count. The solution depends on the raw weighted mean of ``(I + 1/2) / tau`` and on the number of frames
used only, so it is solved by Newton's method once per batch item on a grid of raw means (:func:`_item_table`) and
read off by linear interpolation per pixel.

With spatial evidence (``shape`` given: the default of :func:`~torch_modulo.unwrap_multi`) each prediction is the
mean of the estimates of the pixel and its agreeing neighbours (:mod:`~torch_modulo.multishot.spatial`), and the
prediction's spread and the whole spread are gated separately (:func:`~torch_modulo.multishot.spatial.gates`); the
fit that follows is each pixel's own.

The work runs in float32 unless the moduli are float64 (:func:`work_dtype`). On the CPU it runs item by item over
chunks of pixels (of whole image planes with spatial evidence); under ``torch.compile`` (and on other devices) the
same arithmetic runs on the whole stack.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import torch

from torch_modulo._chunks import chunk_on_cpu, column_chunks
from torch_modulo.multishot.spatial import (
    REACH,
    SETTLE_FLOOR,
    SETTLE_GATE,
    gates,
    neighbour_prediction,
    settle_counts,
    stored,
)
from torch_modulo.multishot.stack import wide_dtype
from torch_modulo.noise import NoiseModel

__all__ = ["decode_noisy", "exposure_unit", "work_dtype"]

#: The clip-bias tables hold the correction in counts at the longest used frame for raw counts ``expm1(u)``, ``u``
#: on ``_GRID`` points up to ``log1p(_TOP)``; above ``_TOP`` counts it is taken as constant (it tends to one: only
#: the shortest frames, which read a few counts, still carry a clip bias there).
_GRID = 256
_TOP = 2.0**16
#: Newton steps per grid point of a table (from above; the last ones change nothing measurable).
_NEWTON_STEPS = 8
#: Columns per CPU chunk: each operation on a chunk also pays a fixed cost (dispatch, its scalars made tensors),
#: which 2^16 columns did not hide (2^18 decoded 1.2 times faster, the same values).
_CHUNK = 1 << 18
#: Pixels per band of rows with spatial evidence.
_BAND = 1 << 18

_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
_INV_SQRT_2 = 1.0 / math.sqrt(2.0)


def work_dtype(frames: torch.Tensor) -> torch.dtype:
    """The dtype the noise-aware decoding runs in: float64 for float64 moduli (where the device has it), float32
    otherwise. float32 holds every decision the decoder makes: a frame is decoded only while its predicted count's
    spread is a fair share of a period, far above float32's rounding of the count."""
    if frames.dtype == torch.float64 and frames.device.type != "mps":
        return torch.float64
    return torch.float32


@dataclass(frozen=True)
class _Counts:
    """The noise model's count statistics as plain numbers, for whole-tensor arithmetic."""

    per_count: float  # 1 / q with shot noise, else 0: the variance's slope in the expected count
    read: float  # (read_noise / q)^2: the collected charge's variance at zero signal, in counts^2
    floor: float  # read + 1/12: the count variance at zero signal

    @classmethod
    def of(cls, noise: NoiseModel) -> _Counts:
        q = noise.electrons_per_count
        read = (noise.read_noise / q) ** 2
        return cls(1.0 / q if noise.shot_noise else 0.0, read, read + 1.0 / 12.0)

    def variance(self, expected: torch.Tensor) -> torch.Tensor:
        """Var(I) of frames whose expected count (signal plus dark) is ``expected`` (>= 0)."""
        return (expected * self.per_count).add_(self.floor)

    def clip_bias(self, expected: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``b(x) = E[I] - (x - 1/2)`` at ``x = expected`` (module docstring), and its slope, from
        :func:`_clip_curve` by linear interpolation (the last value beyond it)."""
        step, curve = _clip_curve(self)
        curve = curve.to(device=expected.device, dtype=expected.dtype)
        u = (expected / step).clamp(0.0, curve.numel() - 1.0)
        cell = u.floor().clamp_(max=curve.numel() - 2.0)
        low = curve[cell.long()]
        rise = curve[cell.long() + 1] - low
        return low + (u - cell) * rise, torch.where(u < curve.numel() - 1.0, rise / step, 0.0)


@functools.lru_cache(maxsize=16)
def _clip_curve(model: _Counts, step: float = 1.0 / 64.0) -> tuple[float, torch.Tensor]:
    """``b(x) = E[I] - (x - 1/2)`` on ``x = 0, step, 2 step, ...`` until it has settled (float64, on the CPU).

    Where the charge quantum is a few electrons or more per count (``q <= 64``), ``E[I]`` is the exact mean of
    ``max(floor(k / q + e), 0)`` over Poisson ``k`` electrons and Gaussian read noise ``e`` (``read`` counts^2): the
    clip at zero, and the floor where the read noise does not smooth it. With many electrons per count the charge is
    Gaussian on the count scale and ``b`` is its clip bias, ``s G((x - 1/2) / s) - phi((x - 1/2) / s) / (24 s)``
    (the midpoint rule's sum of ``P(y < -j)``; the floor's steps are left out, as they are below the noise)."""
    sd = math.sqrt(model.read)
    top = 1.0
    for _ in range(50):  # where b has settled: 9 deviations above half a count
        top = 0.5 + 9.0 * math.sqrt(top * model.per_count + model.read) + 8.0
    x = torch.arange(0.0, top + step, step, dtype=torch.float64)
    q = 1.0 / model.per_count if model.per_count else math.inf
    if q > 64.0:
        s = (x * model.per_count + model.read).clamp_min(1e-12).sqrt()
        centre = x - 0.5
        z = centre / s
        density = torch.exp(-0.5 * z * z) * _INV_SQRT_2PI
        bias = density * (s - 1.0 / (24.0 * s)) - centre * 0.5 * torch.erfc(z * _INV_SQRT_2)
        return step, bias.clamp_min(0.0)
    lam = x * q  # mean electrons
    most = math.ceil(top * q + 12.0 * math.sqrt(top * q) + 12.0)  # electrons: the Poisson tail at the top
    k = torch.arange(0.0, most, dtype=torch.float64)
    level = k / q  # counts of charge
    if sd > 0:
        n = torch.arange(1.0, math.ceil(most / q + 9.0 * sd + 2.0), dtype=torch.float64)
        reading = torch.special.ndtr((level.unsqueeze(1) - n) / sd).sum(dim=1)  # E[max(floor(k/q + e), 0)]
    else:
        reading = level.floor()
    pmf = torch.exp(torch.xlogy(k, lam.unsqueeze(1)) - lam.unsqueeze(1) - torch.lgamma(k + 1.0))
    return step, pmf @ reading - (x - 0.5)


def decode_noisy(
    frames: torch.Tensor,
    tau: torch.Tensor,
    bits: int,
    noise: NoiseModel,
    sigmas: float = 3.0,
    return_counts: bool = False,
    shape: tuple[int, int] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Decode a sorted exposure stack under ``noise``.

    It runs on each item's exposures divided by a power of two near their geometric middle (which changes no
    rounding; the dark counts follow the unit), so that exposures in any unit within the work dtype's range decode,
    where ``tau^2`` alone would overflow or underflow.

    Args:
        frames: (B, M, n) moduli, exposures sorted ascending, integers in ``[0, 2**bits)``.
        tau: (B, M) exposures, ascending.
        bits: the bit depth ``N``.
        noise: the sensor's noise model.
        sigmas: ``z``, the gate on the predicted count's standard deviation in units of ``2**bits / 2``.
        return_counts: return the expected count at the longest exposure, ``tau_max E``, and its variance, instead
            of the radiance ``E``.
        shape: ``(H, W)``: the ``n`` pixels are whole (H, W) image planes, and each prediction uses the agreeing
            neighbours in its plane (module docstring); None decodes every pixel alone.

    Returns:
        ``(radiance, variance, used)``, each (B, n): the radiance estimate (counts per unit exposure, >= 0; or the
        counts), its variance from the noise model, and the number of frames decoded per pixel (the shortest is
        always used). All three are in :func:`work_dtype` (float64 for float64 moduli, else float32); radiance and
        variance are ``inf`` where they are beyond its range. No gradient flows to ``frames`` (the decoding works in
        place; its counts are piecewise constant in the moduli anyway), as none does through
        :func:`~torch_modulo.unwrap_multi`.
    """
    frames = frames.detach()
    work, wide = work_dtype(frames), wide_dtype(frames.device)
    up, down = exposure_unit(tau, wide)
    t = (tau.to(device=frames.device, dtype=wide) * down.unsqueeze(1)).to(work)  # (B, M): tau / s
    dark = (noise.dark_counts * up).unsqueeze(1).to(work)  # (B, 1): dark counts per unit of t
    model = _Counts.of(noise)
    table = _clip_table(t, dark, model)
    b, m, n = frames.shape
    args: tuple[float, float, float, _Counts, tuple[int, int] | None]
    if shape is None:
        gate = (2**bits / (2.0 * sigmas)) ** 2
        args = (float(2**bits), gate, gate, model, None)
    else:
        plane = shape[0] * shape[1]
        if plane == 0 or n % plane:
            raise ValueError(f"shape={shape} does not divide the {n} pixels of each frame into whole image planes")
        args = (float(2**bits), *gates(bits, sigmas), model, shape)
    if chunk_on_cpu(frames) and not torch.compiler.is_compiling() and n:
        radiance = torch.empty((b, n), dtype=work)
        variance, used = torch.empty_like(radiance), torch.empty_like(radiance)
        # Item by item (each item's exposures as numbers), in chunks whose columns depend only on n: an item decodes
        # bit for bit the same in any batch (vectorised arithmetic may round differently in a vector's tail).
        for item in range(b):
            rows = slice(item, item + 1)
            exposures = t[item].tolist()
            if shape is not None:
                outs = (radiance[rows], variance[rows], used[rows])
                _decode_bands(frames[rows], exposures, t[rows], dark[rows], table[rows], args, shape, outs)
                continue
            for cols in column_chunks(n, 1, chunk=_CHUNK, min_width=_CHUNK):
                out = _decode(frames[rows, :, cols].to(work), exposures, t[rows], dark[rows], table[rows], *args)
                radiance[rows, cols], variance[rows, cols], used[rows, cols] = out
    else:
        exposures = list(t.unsqueeze(-1).unbind(1))  # (B, 1) each
        radiance, variance, used = _decode(frames.to(work), exposures, t, dark, table, *args)
    if return_counts:  # tau_max (E - D) = (tau_max / s) (s E - s D): no unit enters
        longest = t[:, -1:]
        return (radiance - dark) * longest, variance * (longest * longest), used
    down = down.unsqueeze(1).to(work)  # exact while the radiance is within the work dtype's range
    return ((radiance - dark) * down).clamp_min(0.0), variance * down * down, used


def _decode_bands(
    x: torch.Tensor,
    exposures: list[float],
    t: torch.Tensor,
    dark: torch.Tensor,
    table: torch.Tensor,
    args: tuple[float, float, float, _Counts, tuple[int, int] | None],
    shape: tuple[int, int],
    outs: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
) -> None:
    """:func:`_decode` of one item's (1, M, n) moduli with spatial evidence, band of rows by band of rows of each
    (H, W) plane, into ``outs`` (three (1, n) views). A band is decoded with ``REACH (M - 1)`` rows of context on
    each side: each frame's decoding reaches ``REACH`` rows (its prediction and the settling of its counts), so the
    rows beyond it cannot change the band's result, which is the whole plane's."""
    h, w = shape
    m = x.shape[1]
    halo = REACH * (m - 1)
    band = max(_BAND // max(w, 1), 2 * halo, 1)
    work = outs[0].dtype
    for start in range(0, x.shape[2], h * w):  # plane by plane
        for top in range(0, h, band):
            low, high = max(top - halo, 0), min(top + band + halo, h)
            cols = slice(start + low * w, start + high * w)
            out = _decode(x[:, :, cols].to(work), exposures, t, dark, table, *args[:4], (high - low, w), low)
            keep = slice((top - low) * w, (min(top + band, h) - low) * w)
            done = slice(start + top * w, start + min(top + band, h) * w)
            for target, part in zip(outs, out, strict=True):
                target[:, done] = part[:, keep]


def _decode(
    x: torch.Tensor,
    exposures: list[float] | list[torch.Tensor],
    t: torch.Tensor,
    dark: torch.Tensor,
    table: torch.Tensor,
    period: float,
    gate: float,
    whole: float,
    model: _Counts,
    shape: tuple[int, int] | None,
    row0: int = 0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Decode (B, M, w) moduli: the estimate of ``E + dark`` in the work unit (>= ``dark``), its variance and the
    frames used, each (B, w).

    ``exposures`` holds the M exposures ``t_i`` in the work unit, as numbers (one item) or (B, 1) tensors; ``t`` is
    the same as a (B, M) tensor, for the table lookups. Without ``shape`` a frame is decoded while the predicted
    count's variance is within ``gate``; with it (whole (H, W) planes) the prediction is the neighbours' and its
    variance must be within ``gate``, the whole variance within ``whole``, and the pixels that fail only the first
    are settled against the frame's own differences (:func:`~torch_modulo.multishot.spatial.settle_counts`; ``row0``
    is the first row's index in the image)."""
    m = x.shape[1]
    counts = [x[:, 0] + 0.5]  # count + 1/2 of each frame, its rollovers added
    used = torch.ones_like(counts[0])
    active = torch.ones_like(used)  # 1 while the pixel decodes the frame, then 0
    decoded = [active]
    t0 = exposures[0]
    total = t0 * t0 / model.variance(counts[0])
    weighted = total * counts[0] / t0
    # Under torch.compile with spatial evidence the running sums are stored each frame: the neighbours' predictions
    # read them, and fused code would otherwise recompute every frame before it for each read (about 2 times slower).
    keep = stored if shape is not None and torch.compiler.is_compiling() else _same
    for i in range(1, m):
        ti = exposures[i]
        total, weighted = keep(total), keep(weighted)
        inverse = 1.0 / total
        settle = None
        if shape is None:
            expected = (weighted * inverse).mul_(ti)  # the predicted count + 1/2
            own = model.variance(expected)
            active = (own + inverse * (ti * ti)).le_(gate).mul_(active)  # masks as 0.0 / 1.0 floats (spatial.py)
        else:
            guess, spread = neighbour_prediction(weighted * inverse, inverse, shape)
            expected = guess.mul_(ti)
            own = model.variance(expected)
            spread = spread.mul_(ti * ti)
            passes = (own + spread).le_(whole).mul_(spread.le(gate)).mul_(active)
            # The pixels that fail only the prediction's gate, and would be off by at most half at a wrong count even
            # where the count is 2 deviations of the prediction below it.
            low = expected - spread.sqrt().mul_(2.0)
            candidates = (
                own.le(whole).to(own.dtype).mul_(spread.le(SETTLE_GATE * gate)).mul_(low.ge_(SETTLE_FLOOR * period))
            ).mul_(active - passes)
            active = passes + candidates
            settle = (expected, spread, own, passes, candidates)
        decoded.append(active)
        half = x[:, i] + 0.5
        k = (expected - half).div_(period).round_().clamp_min_(0.0)
        if settle is not None and shape is not None:
            k = settle_counts(half, k, *settle, shape, period, row0)
        counts.append(half.add_(k.mul_(period)))
        weight = (active * (ti * ti)).div_(own)  # the prediction's variance: independent of frame i
        total = total.add_(weight)  # in place, here and below: fewer fresh buffers, which cost more than the sums
        weighted = weighted.add_(weight.mul_(counts[i]).div_(ti))
        used = used.add_(active)
    # The least-squares fit with every used frame's weight t / Var(I) at one radiance, the clip-corrected running
    # estimate; then its clip bias corrected through the item's table.
    first = _unclip(weighted / total, used, t, table)
    norm = torch.zeros_like(first)
    raw = torch.zeros_like(first)
    for i in range(m):
        ti = exposures[i]
        slope = decoded[i] / (first * model.per_count).add_(model.floor / ti)  # t / Var(I)
        norm = norm.add_(slope * ti)
        raw = raw.add_(slope.mul_(counts[i]))
    return _unclip(raw / norm, used, t, table), 1.0 / norm, used


def _same(x: torch.Tensor) -> torch.Tensor:
    return x


@torch.library.custom_op("torch_modulo::clip_table", mutates_args=())
def _clip_table_op(t: torch.Tensor, dark: torch.Tensor, per_count: float, read: float) -> torch.Tensor:
    """:func:`_clip_table` as an operator that ``torch.compile`` calls as it is (its loops stay out of the graph)."""
    model = _Counts(per_count, read, read + 1.0 / 12.0)
    rows = [_item_table(tuple(a), d, model) for a, d in zip(t.tolist(), dark.squeeze(1).tolist(), strict=True)]
    if not rows:
        return t.new_empty((0, t.shape[1], _GRID))
    return torch.stack(rows).to(device=t.device, dtype=t.dtype)


@_clip_table_op.register_fake
def _(t: torch.Tensor, dark: torch.Tensor, per_count: float, read: float) -> torch.Tensor:
    return t.new_empty((t.shape[0], t.shape[1], _GRID))


def _clip_table(t: torch.Tensor, dark: torch.Tensor, model: _Counts) -> torch.Tensor:
    """Per item and number of used frames ``L``, the clip-bias correction of the least-squares estimate (module
    docstring) on a grid of raw estimates: (B, M, _GRID) in ``t``'s dtype and on its device, for (B, M) exposures
    ``t`` and (B, 1) dark counts in the work unit (see :func:`_item_table`)."""
    return _clip_table_op(t, dark, model.per_count, model.read)


@functools.lru_cache(maxsize=64)
def _item_table(t: tuple[float, ...], dark: float, model: _Counts) -> torch.Tensor:
    """One item's table, (M, _GRID) float64 on the CPU.

    Entry ``[L - 1, j]`` is ``t_{L-1} (F - r_j)``, the correction in counts at the longest used frame, where ``F``
    (>= the dark counts) solves ``F + B_L(F) = r_j`` for the raw estimate ``r_j = expm1(u_j) / t_{L-1}``; ``B_L`` is
    the clip bias of the mean over the ``L`` shortest frames. Newton's method from ``F = r_j`` (``F + B_L(F)``
    increases, and where it is convex the steps approach the root from above without passing it)."""
    exposures = torch.tensor(t, dtype=torch.float64)
    grid = torch.expm1(torch.linspace(0.0, math.log1p(_TOP), _GRID, dtype=torch.float64))
    out = torch.empty((len(t), _GRID), dtype=torch.float64)
    for last in range(len(t)):
        frames = exposures[: last + 1].unsqueeze(-1)  # (L, 1)
        raw = grid / t[last]  # (G,)
        fit = raw.clone()
        for _ in range(_NEWTON_STEPS):
            expected = frames * fit
            slope = frames / model.variance(expected)
            bias, gradient = model.clip_bias(expected)
            norm = (slope * frames).sum(dim=0)
            excess = fit + (slope * bias).sum(dim=0) / norm - raw
            steep = 1.0 + (slope * frames * gradient).sum(dim=0) / norm
            fit = (fit - excess / steep.clamp_min(0.25)).clamp_min(dark)
        out[last] = (fit - raw) * t[last]
    return out


def _unclip(raw: torch.Tensor, used: torch.Tensor, t: torch.Tensor, table: torch.Tensor) -> torch.Tensor:
    """The clip-corrected fit for raw estimates ``raw`` (B, w) over ``used`` frames, by linear interpolation in the
    items' tables (:func:`_clip_table`)."""
    last = used.long() - 1
    longest = torch.gather(t, 1, last)  # t of each pixel's longest used frame
    counts = raw * longest
    u = (torch.log1p(counts) * ((_GRID - 1) / math.log1p(_TOP))).clamp_(0.0, _GRID - 1.0)
    cell = u.floor().clamp_(max=_GRID - 2.0)
    index = last * _GRID + cell.long()
    flat = table.reshape(table.shape[0], -1)
    low = torch.gather(flat, 1, index)
    return raw + (low + (u - cell) * (torch.gather(flat, 1, index + 1) - low)) / longest


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
