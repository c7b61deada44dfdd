r"""Spatial evidence for the noise-aware decoder: each pixel's prediction refined by its agreeing neighbours.

The noise-aware decoder (:mod:`~torch_modulo.multishot.noisy`) predicts frame ``i``'s count from the running
radiance estimate ``E`` of the frames before it. The prediction's spread, ``tau_i^2 Var(E)``, grows with the ratio;
where the radiance is locally smooth, the estimates of its neighbours predict it with a fraction of that variance.
The prediction is the inverse-variance mean of the pixel's estimate and of the means of the opposite pairs of its
5 x 5 neighbours (the twelve lines through it: ``q`` and its mirror image through the pixel) whose both members
agree with it:

.. math:: (E_q - E_p)^2 \le a^2 (\operatorname{Var}(E_p) + \operatorname{Var}(E_q)),

``a`` = ``agree`` (2.5 by default). A pair's mean is exact on a linear slope, so the prediction is not pulled by a
gradient; across an edge, or next to an estimate with a wrong rollover count (a period off), a neighbour differs
by more than the noise and its pair is left out. The refined variance is that of the mean, ``1 / sum`` of the
inverse variances, so a pixel with no agreeing pair (a texture, a steep curved slope, an image corner) is decoded
exactly as alone.

A frame's own noise is not reduced by neighbours: the count of pixel ``p`` is only observed through its own modulus.
Once the prediction is sharp, what limits a frame is that noise, and a wrong rollover count it causes is one period
in a frame whose count is large (a few percent of the value, never a gross error). So with spatial evidence the
decoder gates the two separately (see :func:`gates`): the prediction's spread at ``sigmas`` deviations, and the
whole spread (prediction and the frame's own noise) at :data:`WHOLE_SHARE` ``* sigmas``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

__all__ = ["PLANNED_SHRINK", "WHOLE_SHARE", "gates", "neighbour_prediction"]

#: With spatial evidence, the whole spread of a predicted count (prediction and the frame's own noise) is gated at
#: this share of ``sigmas`` deviations (2 at the default 3): wrong rollover counts from the frame's own noise cost
#: one period in a bright frame, and each such frame adds many counts.
WHOLE_SHARE = 2.0 / 3.0

#: The factor by which the planner takes the neighbours to reduce the prediction's variance (the pixel and its
#: twelve pairs give 25 where all agree; agreement, texture and image borders leave fewer).
PLANNED_SHRINK = 6.0

#: The pairs of opposite neighbours, ``(dy, dx)`` and ``(-dy, -dx)``, of a 5 x 5 window.
_PAIRS = ((0, 1), (1, 0), (1, 1), (1, -1), (0, 2), (2, 0), (2, 2), (2, -2), (1, 2), (2, 1), (1, -2), (2, -1))


def gates(bits: int, sigmas: float) -> tuple[float, float]:
    """``(prediction, whole)``: the largest variances, in counts^2, of a predicted count's prediction part and of its
    whole spread for which a frame is decoded with spatial evidence: ``(2^N / (2 z))^2`` with ``z = sigmas`` and
    ``z = WHOLE_SHARE * sigmas``."""
    period = float(2**bits)
    return (period / (2.0 * sigmas)) ** 2, (period / (2.0 * WHOLE_SHARE * sigmas)) ** 2


def neighbour_prediction(
    estimate: torch.Tensor, variance: torch.Tensor, shape: tuple[int, int], agree: float = 2.5
) -> tuple[torch.Tensor, torch.Tensor]:
    """The inverse-variance mean of each pixel's radiance estimate and of the means of its agreeing pairs of opposite
    5 x 5 neighbours (module docstring), and the variance of that mean.

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
    scaled = (agree * agree) * v  # a^2 Var(E_p): the agreement test is d^2 <= a^2 Var(E_p) + a^2 Var(E_q)
    padded_e = F.pad(e, (2, 2, 2, 2))
    padded_s = F.pad(scaled, (2, 2, 2, 2), value=float("inf"))  # beyond the border: never a neighbour
    total = 1.0 / v
    acc = total * e
    for dy, dx in _PAIRS:
        near, far = (2 + dy, 2 + dx), (2 - dy, 2 - dx)
        ea = padded_e[:, near[0] : near[0] + h, near[1] : near[1] + w]
        eb = padded_e[:, far[0] : far[0] + h, far[1] : far[1] + w]
        sa = padded_s[:, near[0] : near[0] + h, near[1] : near[1] + w]
        sb = padded_s[:, far[0] : far[0] + h, far[1] : far[1] + w]
        da, db = ea - e, eb - e
        both = (da * da <= scaled + sa) & (db * db <= scaled + sb)
        # The pair's mean, (E_a + E_b) / 2, has variance (Var_a + Var_b) / 4.
        weight = both * ((4.0 * agree * agree) / (sa + sb).clamp_min(1e-30))
        total = total + weight
        acc = acc + weight * (0.5 * (ea + eb))
    return (acc / total).reshape(estimate.shape), (1.0 / total).reshape(estimate.shape)
