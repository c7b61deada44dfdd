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
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

__all__ = ["PLANNED_SHRINK", "RADIUS", "WHOLE_SHARE", "gates", "neighbour_prediction", "stored"]

#: With spatial evidence, the whole spread of a predicted count (prediction and the frame's own noise) is gated at
#: this share of ``sigmas`` deviations (2 at the default 3): wrong rollover counts from the frame's own noise cost
#: one period in a bright frame, and each such frame adds many counts.
WHOLE_SHARE = 2.0 / 3.0

#: The factor by which the planner takes the neighbours to reduce the prediction's variance (the pixel and its four
#: pairs give 9 where all agree; agreement, texture and image borders leave fewer).
PLANNED_SHRINK = 6.0

#: The pairs of opposite neighbours, ``(dy, dx)`` and ``(-dy, -dx)``: the four lines through the pixel in its 3 x 3
#: window (horizontal, vertical, two diagonals). (The eight of a 5 x 5 window, two pixels out on the same lines,
#: decoded protocol N about as well, 4% better in the bright third under q = 1, at 1.6 times the cost.)
_PAIRS = ((0, 1), (1, 0), (1, 1), (1, -1))

#: How far a prediction reaches, in pixels.
RADIUS = max(max(abs(dy), abs(dx)) for dy, dx in _PAIRS)


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
