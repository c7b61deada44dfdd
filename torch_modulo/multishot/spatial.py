r"""Spatial evidence for the noise-aware decoder: each pixel's prediction refined by its agreeing neighbours.

The noise-aware decoder (:mod:`~torch_modulo.multishot.noisy`) predicts frame ``i``'s count from the running
radiance estimate ``E`` of the frames before it. The prediction's spread, ``tau_i^2 Var(E)``, grows with the ratio;
where the radiance is locally smooth, the estimates of its neighbours predict it with a fraction of that variance.
The prediction is the mean of the pixel's estimate and of both members of each opposite pair of its 3 x 3
neighbours (the four lines through it: horizontal, vertical and the two diagonals) that agree with it:

.. math:: |E_q - E_p| \le a \sqrt{2 \operatorname{Var}(E_p)} \quad \text{for both members } q,

``a`` = ``agree`` (2.5 by default; ``Var(E_q)`` is taken as ``Var(E_p)``, as on a locally flat radiance). A pair's
mean is exact on a linear slope, so the prediction is not pulled by a gradient; across an edge, or next to an
estimate with a wrong rollover count (a period off), a neighbour differs by more than the noise and its pair is
left out. The refined variance is ``Var(E_p) / (1 + 2 k)`` for ``k`` agreeing pairs, so a pixel with no agreeing
pair (a texture, a steep curved slope, an image corner) is decoded exactly as alone. What the test cannot see, a
structure below the noise of the frames so far, can still bias a prediction: the prediction's gate keeps
``sigmas`` deviations for it.

A frame's own noise is not reduced by neighbours: the count of pixel ``p`` is only observed through its own modulus.
Once the prediction is sharp, what limits a frame is that noise, and a wrong rollover count it causes is one period
in a frame whose count is large (a few percent of the value, never a gross error). So with spatial evidence the
decoder gates the two separately (see :func:`gates`): the prediction's spread at ``sigmas`` deviations, and the
whole spread (prediction and the frame's own noise) at :data:`WHOLE_SHARE` ``* sigmas``.

**The frame's own differences** (:func:`settle_counts`). A pixel whose prediction fails that gate, but whose own
noise passes the whole gate, is not given up: it is a *candidate*, and its rollover count is settled as part of an
image. Each candidate takes the count that best fits both its prediction (a Gaussian term with the prediction's and
its own variance) and the frame's own count differences to its decoded or candidate 4-neighbours (a Huber term on the
difference less the one the predictions expect, in units of the two counts' own noise): iterated conditional modes
on the two colours of a checkerboard, a period up or down per step. Where the radiance is locally smooth the
neighbours pin a count that its prediction alone leaves uncertain; a candidate's prediction must still be within
:data:`SETTLE_GATE` times the prediction's gate, and its count at least :data:`SETTLE_FLOOR` periods (2 of the
prediction's deviations below it), so that a count the step gets wrong is off by a period in a bright frame: at
most half the value, never a gross error.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F

__all__ = [
    "PLANNED_SHRINK",
    "RADIUS",
    "REACH",
    "SETTLE_FLOOR",
    "SETTLE_GATE",
    "WHOLE_SHARE",
    "gates",
    "neighbour_prediction",
    "settle_counts",
    "stored",
]

#: With spatial evidence, the whole spread of a predicted count (prediction and the frame's own noise) is gated at
#: this share of ``sigmas`` deviations (2 at the default 3): wrong rollover counts from the frame's own noise cost
#: one period in a bright frame, and each such frame adds many counts.
WHOLE_SHARE = 2.0 / 3.0

#: The factor by which the planner takes the neighbours to reduce the prediction's variance (the pixel and its four
#: pairs give 9 where all agree; agreement, texture and image borders leave fewer).
PLANNED_SHRINK = 8.0

#: :func:`settle_counts` takes candidates whose prediction's variance is within this many times the prediction's gate
#: (three times its deviation: half a period is ``sigmas / 3`` deviations); where the prediction is that loose, the
#: frame's own differences to the neighbours decide.
SETTLE_GATE = 9.0

#: :func:`settle_counts` takes candidates whose expected count is at least this many periods even 2 deviations of the
#: prediction below it: a count it gets a period wrong is then at most half off, never a gross error.
SETTLE_FLOOR = 2.0

#: :func:`settle_counts`'s rounds (each visits both colours of the checkerboard once) and the Huber threshold of its
#: pair terms, in deviations of the pair's own noise.
_ROUNDS = 2
_HUBER = 2.0

#: The pairs of opposite neighbours, ``(dy, dx)`` and ``(-dy, -dx)``: the four lines through the pixel in its 3 x 3
#: window (horizontal, vertical, two diagonals). (The eight of a 5 x 5 window, two pixels out on the same lines,
#: decoded protocol N about as well, 4% better in the bright third under q = 1, at 1.6 times the cost.)
_PAIRS = ((0, 1), (1, 0), (1, 1), (1, -1))

#: How far a prediction reaches, in pixels.
RADIUS = max(max(abs(dy), abs(dx)) for dy, dx in _PAIRS)

#: How far one frame's decoding reaches, in pixels: the prediction, then each half-round of :func:`settle_counts` one
#: pixel further.
REACH = RADIUS + 2 * _ROUNDS

#: The 4-neighbours :func:`settle_counts` compares a count with.
_NEIGHBOURS = ((0, 1), (0, -1), (1, 0), (-1, 0))


@torch.library.custom_op("torch_modulo::spatial_buffer", mutates_args=())
def stored(x: torch.Tensor) -> torch.Tensor:
    """A copy of ``x``, which ``torch.compile`` cannot see through: the decoder stores the running sums that the
    neighbours' estimates come from each frame, where fused code would otherwise recompute the whole walk over the
    frames before for each neighbour."""
    return x.clone()


@stored.register_fake
def _(x: torch.Tensor) -> torch.Tensor:
    return torch.empty_like(x)


def _pad(e: torch.Tensor, r: int) -> torch.Tensor:
    """``e`` (planes, H, W) padded by ``r`` NaN on every side: beyond the border is never a neighbour (NaN fails the
    agreement test)."""
    return F.pad(e, (r, r, r, r), value=math.nan)


@torch.library.custom_op("torch_modulo::padded_plane", mutates_args=())
def padded_plane(e: torch.Tensor, r: int) -> torch.Tensor:
    """:func:`_pad` as an operator ``torch.compile`` does not fuse: the compiled decoder reads the neighbours from
    this buffer, not by recomputing the frames before for each of them, and without bounds checks (so the fused
    code is vectorised; about 1.3 times faster than padding inside it)."""
    return _pad(e, r)


@padded_plane.register_fake
def _(e: torch.Tensor, r: int) -> torch.Tensor:
    return e.new_empty((e.shape[0], e.shape[1] + 2 * r, e.shape[2] + 2 * r))


def gates(bits: int, sigmas: float) -> tuple[float, float]:
    """``(prediction, whole)``: the largest variances, in counts^2, of a predicted count's prediction part and of its
    whole spread for which a frame is decoded with spatial evidence: ``(2^N / (2 z))^2`` with ``z = sigmas`` and
    ``z = WHOLE_SHARE * sigmas``."""
    period = float(2**bits)
    return (period / (2.0 * sigmas)) ** 2, (period / (2.0 * WHOLE_SHARE * sigmas)) ** 2


def neighbour_prediction(
    estimate: torch.Tensor, variance: torch.Tensor, shape: tuple[int, int], agree: float = 2.5
) -> tuple[torch.Tensor, torch.Tensor]:
    """The mean of each pixel's radiance estimate and of both members of its agreeing pairs of opposite 3 x 3
    neighbours (module docstring), and the variance of that mean.

    Args:
        estimate: (B, n) radiance estimates (any unit), ``n`` a whole number of (H, W) image planes.
        variance: (B, n) their variances (> 0; ``inf`` for no information).
        shape: ``(H, W)`` of the planes.
        agree: ``a``, the agreement test's width in standard deviations of the difference.

    Returns:
        ``(mean, variance)``, each (B, n) like ``estimate``. Pixels beyond the image border are not neighbours.
    """
    h, w = shape
    e = estimate.reshape(-1, h, w)
    v = variance.reshape(-1, h, w)
    # |E_q - E_p| <= a sqrt(2 Var(E_p)): the test with Var(E_q) taken as Var(E_p), as on a locally flat radiance.
    limit = v.sqrt().mul_(agree * math.sqrt(2.0))
    r = RADIUS
    # Eager, the masks are 0.0 / 1.0 floats made in place and applied by multiplication: on the CPU, boolean
    # tensors and torch.where cost several times the arithmetic they select. Compiled, the selection is fused (and
    # the in-place form more than doubled the compiled decoder's time).
    compiling = torch.compiler.is_compiling()
    padded = padded_plane(e, r) if compiling else _pad(e, r)
    pairs = torch.zeros_like(e)
    shift = torch.zeros_like(e)
    for dy, dx in _PAIRS:
        # One difference image per line, E(p + o) - E(p) over the padded plane: the pixel's difference to its near
        # neighbour p + o and, negated, to its far one p - o are two views of it.
        if dx >= 0:
            step = padded[:, dy:, dx:] - padded[:, : h + 2 * r - dy, : w + 2 * r - dx]
            near = (slice(r, r + h), slice(r, r + w))
            far = (slice(r - dy, r - dy + h), slice(r - dx, r - dx + w))
        else:
            step = padded[:, dy:, : w + 2 * r + dx] - padded[:, : h + 2 * r - dy, -dx:]
            near = (slice(r, r + h), slice(r + dx, r + dx + w))
            far = (slice(r - dy, r - dy + h), slice(r, r + w))
        diff = step[:, near[0], near[1]] - step[:, far[0], far[1]]
        size = step.abs_()  # after diff: in place
        worst = torch.maximum(size[:, near[0], near[1]], size[:, far[0], far[1]])  # NaN (beyond the border) fails
        if compiling:
            both = worst <= limit
            shift = shift + torch.where(both, diff, 0.0)
            pairs = pairs + both
        else:  # a pair that fails adds 0 x its difference, which must then be finite (so a non-finite difference
            # adds nothing even where an infinite variance passes it: the decoder's variances are finite)
            both = worst.le_(limit)
            shift.addcmul_(both, diff.nan_to_num_(0.0, 0.0, 0.0))
            pairs.add_(both)
    count = pairs.mul_(2.0).add_(1.0)  # the pixel and both members of each agreeing pair, equally weighted
    return shift.div_(count).add_(e).reshape(estimate.shape), (v / count).reshape(estimate.shape)


def _around(v: torch.Tensor, fill: float | bool) -> torch.Tensor:
    """``v`` (planes, H, W) read at each of :data:`_NEIGHBOURS`, ``fill`` beyond the border: (4, planes, H, W), from
    one padded copy."""
    h, w = v.shape[-2:]
    padded = F.pad(v.to(torch.float32) if v.dtype == torch.bool else v, (1, 1, 1, 1), value=float(fill))
    out = torch.stack([padded[:, 1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy, dx in _NEIGHBOURS])
    return out > 0.5 if v.dtype == torch.bool else out


def _huber(z: torch.Tensor) -> torch.Tensor:
    a = z.abs()
    return torch.where(a <= _HUBER, 0.5 * z * z, _HUBER * a - 0.5 * _HUBER * _HUBER)


def settle_counts(
    half: torch.Tensor,
    rollovers: torch.Tensor,
    expected: torch.Tensor,
    spread: torch.Tensor,
    own: torch.Tensor,
    decided: torch.Tensor,
    candidates: torch.Tensor,
    shape: tuple[int, int],
    period: float,
    row0: int = 0,
) -> torch.Tensor:
    """The candidates' rollover counts of one frame, settled against the frame's own differences (module docstring).

    Args:
        half: (B, n) the frame's moduli + 1/2, ``n`` a whole number of (H, W) planes.
        rollovers: (B, n) each pixel's rollover count nearest its prediction.
        expected: (B, n) the predicted counts (+ 1/2); ``spread`` and ``own`` their prediction's and own variances.
        decided: (B, n) 1.0 where the gates decoded the frame (its count is kept and anchors its candidates).
        candidates: (B, n) 1.0 where the count is to be settled.
        shape: ``(H, W)``.
        period: ``2^N``.
        row0: the first row's index in the whole image (the checkerboard's colours follow the image, so a band of
            rows settles as the whole plane does).

    Returns:
        (B, n) the rollover counts: the candidates' settled, the others' as given.
    """
    h, w = shape
    cand = candidates.reshape(-1, h, w) > 0
    compiling = torch.compiler.is_compiling()
    if not compiling and not bool(cand.any()):
        return rollovers
    own_ = own.reshape(-1, h, w)
    rows = torch.arange(row0, row0 + h, device=cand.device)
    cols = torch.arange(w, device=cand.device)
    frame = _Frame(
        half.reshape(-1, h, w),
        rollovers.reshape(-1, h, w),
        expected.reshape(-1, h, w),
        2.0 * (spread.reshape(-1, h, w) + own_),
        own_,
        cand | (decided.reshape(-1, h, w) > 0),
        cand,
        ((rows[:, None] + cols[None, :]) % 2).expand_as(cand),
    )
    settled = _settle_dense(frame, period) if compiling else _settle_sparse(frame, period)
    return settled.reshape(rollovers.shape)


class _Frame(NamedTuple):
    """One frame's (planes, H, W) arrays for :func:`settle_counts`: the moduli + 1/2, the rollover counts, the
    predictions, the prediction's Gaussian term's denominator ``2 (V_pred + V_own)``, the own variances, where a
    neighbour takes part (decided or candidate), the candidates, and the checkerboard's colours."""

    base: torch.Tensor
    k: torch.Tensor
    mu: torch.Tensor
    unary: torch.Tensor
    own: torch.Tensor
    inside: torch.Tensor
    cand: torch.Tensor
    colour: torch.Tensor


def _choice(
    counts: torch.Tensor,
    k: torch.Tensor,
    mu: torch.Tensor,
    unary: torch.Tensor,
    pairs: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor],
    period: float,
) -> torch.Tensor:
    """The step (-1, 0 or +1 period) of least energy for counts ``counts`` (rollover counts ``k``): the prediction's
    term and, per neighbour, the Huber pair term; ``pairs`` stacks along a first dimension of 4 the neighbours'
    (whether each takes part, the pair's scale, the expected difference, its counts). Every argument is the pixels'
    own (dense planes or the gathered candidates)."""
    there, scale, expect, other = pairs
    moved = torch.stack([counts, counts - period, counts + period])  # no move first: a tie keeps the count
    terms = torch.where(there, _huber((moved.unsqueeze(1) - other - expect) * scale), 0.0)  # (3, 4, ...)
    energy = (moved - mu).square() / unary + terms[:, 0] + terms[:, 1] + terms[:, 2] + terms[:, 3]
    down = (energy[1] < energy[0]) & (k >= 1)
    best = torch.where(down, energy[1], energy[0])
    up = energy[2] < best
    return torch.where(up, 1.0, torch.where(down, -1.0, 0.0))


def _settle_dense(f: _Frame, period: float) -> torch.Tensor:
    """:func:`settle_counts` on whole (planes, H, W) arrays, with static shapes (under ``torch.compile``)."""
    base, k, mu, unary, own, inside, cand, colour = f
    fixed = (_around(inside, False), (own + _around(own, 1.0)).rsqrt(), mu - _around(mu, 0.0))
    for _ in range(_ROUNDS):
        for side in (0, 1):
            counts = base + k * period
            choice = _choice(counts, k, mu, unary, (*fixed, _around(counts, 0.0)), period)
            k = torch.where(cand & (colour == side), k + choice, k)
    return k


def _settle_sparse(f: _Frame, period: float) -> torch.Tensor:
    """:func:`settle_counts` on the candidates alone, gathered by index (eager: the work follows their number, the
    same arithmetic as :func:`_settle_dense`, so the same result)."""
    base, k, mu, unary, own, inside, cand, colour = f
    h, w = k.shape[-2:]
    n = k.numel()
    flat_k = k.reshape(-1).clone()
    flat_base, flat_mu, flat_own, flat_inside = (v.reshape(-1) for v in (base, mu, own, inside))
    dy, dx = (torch.tensor(d, device=k.device).view(4, 1) for d in zip(*_NEIGHBOURS, strict=True))
    sides = []
    for side in (0, 1):
        index = (cand & (colour == side)).reshape(-1).nonzero().squeeze(1)
        y, x = (index // w) % h + dy, index % w + dx  # the neighbours' rows and columns, (4, candidates)
        others = (index + dy * w + dx).clamp(0, n - 1)
        there = (y >= 0) & (y < h) & (x >= 0) & (x < w) & flat_inside[others]
        scale = (flat_own[index] + torch.where(there, flat_own[others], 1.0)).rsqrt()
        expect = flat_mu[index] - torch.where(there, flat_mu[others], 0.0)
        sides.append(
            (index, others, (there, scale, expect), flat_mu[index], unary.reshape(-1)[index], flat_base[index])
        )
    for _ in range(_ROUNDS):
        for index, others, fixed, mu_i, unary_i, base_i in sides:
            k_i = flat_k[index]
            other = flat_base[others] + flat_k[others] * period
            flat_k[index] = k_i + _choice(base_i + k_i * period, k_i, mu_i, unary_i, (*fixed, other), period)
    return flat_k.reshape(k.shape)
