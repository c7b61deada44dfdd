r"""Sensor design: the error a plan of exposures gives, predicted from the noise model, for a modulo sensor and for a
conventional (clipping) sensor with the same noise, and the conventional plan that matches a modulo plan's error.

The scene is a log-uniform ramp of radiances over ``stops`` stops (the convention of
:func:`~torch_modulo.plan_exposures`): the darkest value, ``E_min = 1 / tau_max``, reads one count at the longest
exposure. Per radiance ``E`` (``c = E + D`` with the dark counts ``D`` per unit exposure) a frame of exposure ``t``
reads a count of variance ``V(t c)`` (:meth:`~torch_modulo.noise.NoiseModel.count_variance`): ``1/12`` of it is the
counter's floor, a uniform error of one count, the rest the Gaussian charge noise ``V_g``.

**Modulo sensor** (:func:`~torch_modulo.unwrap_multi` with ``noise=``): the decoder's walk under expected values,
as the planner makes it. Frame ``i`` is decoded while ``s_i^2 = t_i^2 / W_{i-1} + V(t_i c) <= (2^N / (2 z))^2``,
``W`` the running weight ``sum t_j^2 / V(t_j c)`` over the decoded frames (the estimate's variance is ``1 / W``);
its rollover count is wrong with probability ``p_i = erfc(2^N / (2 sqrt(2) s_i))`` (the Gaussian tail past half a
period), which shifts the estimate by about ``(w_i / W_i) 2^N / t_i``. That is each pixel decoded alone
(``spatial=False``). With spatial evidence (``spatial=True``, the decoder's default) the prediction's part
``t_i^2 / W_{i-1}`` is taken as shrunk by :data:`~torch_modulo.multishot.spatial.PLANNED_SHRINK`, as the planner
takes it, and the two parts are gated as the decoder gates them (:func:`~torch_modulo.multishot.spatial.gates`): a
model of a smooth scene, where the neighbours agree (on a textured one a pixel decodes as alone). The shortest
frame rolls over itself with the probability that its charge reaches ``2^N``, which leaves the estimate a period
low.

**Conventional sensor** (:func:`~torch_modulo.merge_intensity` with ``noise=``): the inverse-variance merge of the
unsaturated frames. Frame ``i`` is unsaturated with probability ``P(t_i c + g < 2^N - 1)`` (``g`` the Gaussian
charge noise); since saturation climbs with the exposure, the frames used are the ``L`` shortest with probability
``P(L) = p_{L-1} - p_L``. A value saturated in every frame is read as ``2^N - 1/2`` counts at the shortest exposure.

Per radiance the relative error of the estimate is then a mixture: each case above is a component with a weight, a
bias, a Gaussian part and the uniform part of the frame whose floor weighs most in the estimate (the other frames'
floors are counted in the Gaussian part). :attr:`Prediction.relative_error` is each radiance's rms relative error
(in the likeliest case: all rollovers right, or the likeliest set of unsaturated frames), ``sqrt(1 / W) / E``.

The summary numbers pool the ramp, as a simulation of it does: ``median_error`` is the median of ``|relative
error|`` over all values of the ramp (the ``m`` at which the mixture's ``P(|error| <= m)``, averaged over the ramp,
is one half; not the mean of per-radiance medians), and ``gross_share`` the share more than 50% off, ``1 - P(|error|
<= 1/2)``. What the model leaves out: the counts' discreteness at a few counts (Poisson, the clip at zero that the
decoders correct for), and the randomness of the modulo decoder's gate near its boundary.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from torch_modulo._checks import check_bits, check_flag, check_int, check_real
from torch_modulo.multishot.planning import brightest_unwrapped, plan_exposures
from torch_modulo.multishot.spatial import PLANNED_SHRINK, gates
from torch_modulo.noise import NoiseModel, as_noise_model

__all__ = ["Prediction", "plan_conventional", "predict_conventional", "predict_modulo"]

#: Radiances of the ramp per stop (at least :data:`_MIN_POINTS` in all).
_PER_STOP = 64
_MIN_POINTS = 512
#: Most exposures :func:`plan_conventional` considers (as :func:`~torch_modulo.plan_exposures`).
_MAX_FRAMES = 256
#: Components kept per radiance of the conventional sensor's mixture (the likeliest sets of unsaturated frames).
_KEEP = 4
_SQRT2 = math.sqrt(2.0)
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


@dataclass(frozen=True, eq=False)
class Prediction:
    """The predicted error of a plan of exposures on a log-uniform ramp of radiances (see the module docstring).

    Attributes:
        sensor: ``"modulo"`` or ``"conventional"``.
        exposures: the plan, ascending.
        radiance: (n,) float64, the ramp's radiances in counts per unit exposure, log-uniform from ``1 / tau_max``.
        relative_error: (n,) float64, each radiance's predicted rms relative error ``sqrt(Var(E^)) / E``.
        median_error: the median ``|relative error|`` over the whole ramp.
        gross_share: the share of the ramp's values more than 50% off (in [0, 1]).
        spatial: whether the modulo decoder predicted uses spatial evidence (False for a conventional sensor).
    """

    sensor: str
    exposures: tuple[float, ...]
    radiance: torch.Tensor
    relative_error: torch.Tensor
    median_error: float
    gross_share: float
    spatial: bool = False

    @property
    def frames(self) -> int:
        """The number of exposures."""
        return len(self.exposures)

    @property
    def stops(self) -> float:
        """The ramp's dynamic range, ``log2(E_max / E_min)``."""
        return math.log2(float(self.radiance[-1] / self.radiance[0]))

    def to_dict(self, grid: bool = True) -> dict[str, Any]:
        """JSON-compatible fields (and ``frames``, ``stops``); ``grid=False`` leaves out the per-radiance lists."""
        out: dict[str, Any] = {
            "sensor": self.sensor,
            "exposures": list(self.exposures),
            "frames": self.frames,
            "stops": self.stops,
            "median_error": self.median_error,
            "gross_share": self.gross_share,
            "spatial": self.spatial,
        }
        if grid:
            out["radiance"] = self.radiance.tolist()
            out["relative_error"] = self.relative_error.tolist()
        return out


@dataclass(frozen=True)
class _Mixture:
    """Per radiance (rows), components (columns) of the relative error: weight, bias, Gaussian sd, uniform width."""

    weight: torch.Tensor
    bias: torch.Tensor
    sd: torch.Tensor
    width: torch.Tensor

    def within(self, m: float) -> torch.Tensor:
        """Per radiance, ``P(|error| <= m)``."""
        return (self.weight * (_cdf(m, self) - _cdf(-m, self))).sum(dim=1).clamp(0.0, 1.0)


def _psi(x: torch.Tensor) -> torch.Tensor:
    """``x Phi(x) + phi(x)``: the integral of the Gaussian CDF ``Phi``."""
    return x * 0.5 * torch.erfc(-x / _SQRT2) + torch.exp(-0.5 * x * x) * _INV_SQRT_2PI


def _cdf(x: float, mix: _Mixture) -> torch.Tensor:
    """``P(b + s Z + a U <= x)`` per component (``Z`` standard Gaussian, ``U`` uniform on [-1/2, 1/2])."""
    s, a, y = mix.sd, mix.width, x - mix.bias
    gaussian = 0.5 * torch.erfc(-y / (_SQRT2 * s.clamp_min(1e-300)))
    uniform = (y / a.clamp_min(1e-300) + 0.5).clamp(0.0, 1.0)
    safe = s.clamp_min(1e-300)
    both = safe / a.clamp_min(1e-300) * (_psi((y + 0.5 * a) / safe) - _psi((y - 0.5 * a) / safe))
    out = torch.where(a <= 1e-4 * s, gaussian, torch.where(s <= 1e-4 * a, uniform, both))
    return torch.where((a == 0) & (s == 0), (y >= 0).to(y.dtype), out)


def _pooled(mix: _Mixture) -> tuple[float, float]:
    """The median of ``|relative error|`` over the ramp (by bisection on ``log m``) and the share above 1/2."""
    low, high = -60.0, 20.0  # log2 of the median
    for _ in range(60):
        mid = 0.5 * (low + high)
        if float(mix.within(2.0**mid).mean()) < 0.5:
            low = mid
        else:
            high = mid
    return 2.0 ** (0.5 * (low + high)), float(1.0 - mix.within(0.5).mean())


def _checked(
    exposures: Sequence[float] | torch.Tensor, bits: int, noise: NoiseModel | str | None
) -> tuple[list[float], int, NoiseModel]:
    if isinstance(exposures, torch.Tensor):
        exposures = exposures.detach().cpu().reshape(-1).tolist()
    if isinstance(exposures, str) or not isinstance(exposures, Sequence):
        raise TypeError(f"exposures must be a sequence of numbers; got {type(exposures).__name__}")
    if not exposures:
        raise ValueError("exposures must hold at least one exposure; got none")
    taus = sorted(check_real(t, "exposures", positive=True) for t in exposures)
    model = as_noise_model(noise)
    if model is None:
        raise ValueError(
            "noise must be a NoiseModel or a preset name; got None (for a noise-free sensor predict with "
            "NoiseModel(shot_noise=False, read_noise=0.0): its only error is the counter's floor)"
        )
    return taus, check_bits(bits, torch.float64), model


def _ramp(taus: list[float], stops: float | None, brightest: float) -> torch.Tensor:
    """The log-uniform radiances from ``1 / tau_max`` over ``stops`` stops (default: up to ``brightest``)."""
    if stops is None:
        stops = max(math.log2(max(brightest, 1e-300) * taus[-1]), 0.0)
    stops = check_real(stops, "stops", 0.0)
    points = max(_MIN_POINTS, math.ceil(_PER_STOP * stops))
    return torch.exp2(torch.linspace(0.0, stops, points, dtype=torch.float64)) / taus[-1]


def _parts(noise: NoiseModel, t: float, c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """A frame's count variance ``V(t c)`` and the Gaussian charge sd ``sqrt(V - 1/12)``."""
    variance = noise.count_variance(t * c)
    return variance, (variance - 1.0 / 12.0).clamp_min(0.0).sqrt()


def _upper(x: torch.Tensor, sd: torch.Tensor) -> torch.Tensor:
    """``P(x + sd Z >= 0)``; a step where ``sd`` is 0."""
    return torch.where(sd > 0, 0.5 * torch.erfc(-x / (_SQRT2 * sd.clamp_min(1e-300))), (x >= 0).to(x.dtype))


def predict_modulo(
    exposures: Sequence[float] | torch.Tensor,
    bits: int,
    noise: NoiseModel | str,
    sigmas: float = 3.0,
    stops: float | None = None,
    spatial: bool = True,
) -> Prediction:
    """The predicted error of the noise-aware multi-shot decoder on a log-uniform ramp (module docstring).

    Args:
        exposures: the plan (any order; in the unit the frames are captured in).
        bits: the counter's bit depth ``N``.
        noise: the sensor's :class:`~torch_modulo.noise.NoiseModel` or a preset name.
        sigmas: the decoding gate (as :func:`~torch_modulo.unwrap_multi`'s).
        stops: the ramp's dynamic range from ``E_min = 1 / tau_max``; default: up to the brightest radiance the
            shortest exposure holds ``sigmas`` deviations below the rollover (as :func:`plan_exposures` plans it).
        spatial: predict the decoder with spatial evidence (``unwrap_multi``'s default) on a smooth ramp; False:
            each pixel decoded alone (``unwrap_multi(..., spatial=False)``, and what the spatial decoder gets where
            no neighbour agrees, on a fine texture).

    Returns:
        A :class:`Prediction`.

    Raises:
        TypeError: an argument of the wrong type.
        ValueError: no exposures, an exposure <= 0, ``noise`` None, or a value out of range.

    Example:
        >>> taus = plan_exposures(16, 8, noise="q16", longest=1.0)
        >>> p = predict_modulo(taus, 8, "q16", stops=16)
        >>> p.frames == len(taus), 0.0 < p.median_error < 0.05, 0.0 <= p.gross_share < 0.1
        (True, True, True)
    """
    taus, bits, model = _checked(exposures, bits, noise)
    sigmas = check_real(sigmas, "sigmas", positive=True)
    radiance = _ramp(taus, stops, brightest_unwrapped(bits, model, sigmas, exposure=taus[0]) / taus[0])
    period, gate = 2.0**bits, (2.0**bits / (2.0 * sigmas)) ** 2
    whole, shrink = (gates(bits, sigmas)[1], PLANNED_SHRINK) if check_flag(spatial, "spatial") else (gate, 1.0)
    c = radiance + model.dark_counts
    variance, charge = _parts(model, taus[0], c)
    weights = [taus[0] ** 2 / variance]
    total = weights[0]
    wrong = [_upper(taus[0] * c - period, charge)]  # the shortest frame rolls over itself
    shifts = [torch.full_like(c, -period / taus[0])]
    active = torch.ones_like(c, dtype=torch.bool)
    for t in taus[1:]:
        variance, _ = _parts(model, t, c)
        prediction = t * t / (total * shrink)
        spread = prediction + variance
        active = active & (spread <= whole) & (prediction <= gate)
        weight = torch.where(active, t * t / variance, 0.0)
        total = total + weight
        wrong.append(torch.where(active, torch.erfc(period / (2.0 * _SQRT2 * spread.sqrt())), 0.0))
        shifts.append(weight / total * period / t)
        weights.append(weight)
    sd = total.rsqrt()
    # The largest of the frames' floor widths in the estimate, (w_i / W) / t_i, in radiance units.
    width = torch.stack([w / t for w, t in zip(weights, taus, strict=True)]).amax(dim=0) / total
    gaussian = (sd * sd - width * width / 12.0).clamp_min(0.0).sqrt() / radiance
    p = torch.stack(wrong, dim=1).clamp(0.0, 1.0)
    shift = torch.stack(shifts, dim=1) / radiance.unsqueeze(1)
    right = (1.0 - p.sum(dim=1, keepdim=True)).clamp_min(0.0)
    # Components: all rollovers right; frame 0 rolled over (a period low); frame i >= 1 one period off, either way.
    weight = torch.cat([right, p[:, :1], 0.5 * p[:, 1:], 0.5 * p[:, 1:]], dim=1)
    bias = torch.cat([torch.zeros_like(right), shift[:, :1], shift[:, 1:], -shift[:, 1:]], dim=1)
    size = weight.shape[1]
    mix = _Mixture(
        weight, bias, gaussian.unsqueeze(1).expand(-1, size), (width / radiance).unsqueeze(1).expand(-1, size)
    )
    median, gross = _pooled(mix)
    return Prediction("modulo", tuple(taus), radiance, sd / radiance, median, gross, shrink > 1.0)


def predict_conventional(
    exposures: Sequence[float] | torch.Tensor,
    bits: int,
    noise: NoiseModel | str,
    stops: float | None = None,
) -> Prediction:
    """The predicted error of the noise-optimal merge of a conventional sensor's unsaturated frames (module
    docstring) on a log-uniform ramp.

    Args:
        exposures: the plan (any order).
        bits: the sensor's bit depth (it saturates at ``2**bits - 1``).
        noise: the sensor's :class:`~torch_modulo.noise.NoiseModel` or a preset name.
        stops: the ramp's dynamic range from ``E_min = 1 / tau_max``; default: up to the radiance that reads
            ``2**bits - 1`` at the shortest exposure.

    Returns:
        A :class:`Prediction`; its ``relative_error`` is that of the likeliest set of unsaturated frames.

    Raises:
        TypeError: an argument of the wrong type.
        ValueError: no exposures, an exposure <= 0, ``noise`` None, or a value out of range.

    Example:
        >>> p = predict_conventional([1 / 256, 1 / 16, 1.0], 8, "q16", stops=16)
        >>> 0.0 < p.median_error < 0.1, p.frames
        (True, 3)
    """
    taus, bits, model = _checked(exposures, bits, noise)
    top = 2.0**bits - 1.0
    radiance = _ramp(taus, stops, (top - model.dark_counts * taus[0]) / taus[0])
    c = radiance + model.dark_counts
    unsaturated, weights = [], []
    for t in taus:
        variance, charge = _parts(model, t, c)
        unsaturated.append(_upper(top - t * c, charge))
        weights.append(t * t / variance)
    p = torch.cummin(torch.stack(unsaturated, dim=1), dim=1).values  # saturation climbs with the exposure
    prob = torch.cat([1.0 - p[:, :1], p - torch.cat([p[:, 1:], torch.zeros_like(p[:, :1])], dim=1)], dim=1)
    total = torch.stack(weights, dim=1).cumsum(dim=1)  # (n, M): W of the L = 1 .. M shortest frames
    # The largest floor width (w_i / W_L) / t_i among the L shortest frames, in radiance units.
    width = torch.cummax(torch.stack([w / t for w, t in zip(weights, taus, strict=True)], dim=1), dim=1).values / total
    sd = (total.rsqrt() ** 2 - width * width / 12.0).clamp_min(0.0).sqrt()
    # Component 0: saturated in every frame, read as top + 1/2 counts at the shortest exposure (a point).
    low = ((top + 0.5) / taus[0] - c) / radiance
    r = radiance.unsqueeze(1)
    bias = torch.cat([low.unsqueeze(1), torch.zeros_like(sd)], dim=1)
    sd = torch.cat([torch.zeros_like(low).unsqueeze(1), sd / r], dim=1)
    width = torch.cat([torch.zeros_like(low).unsqueeze(1), width / r], dim=1)
    keep = prob.topk(min(_KEEP, prob.shape[1]), dim=1).indices
    kept = [x.gather(1, keep) for x in (prob, bias, sd, width)]
    kept[0] = kept[0] / kept[0].sum(dim=1, keepdim=True).clamp_min(1e-300)
    median, gross = _pooled(_Mixture(*kept))
    likeliest = prob[:, 1:].argmax(dim=1, keepdim=True)
    relative = total.rsqrt().gather(1, likeliest).squeeze(1) / radiance
    return Prediction("conventional", tuple(taus), radiance, relative, median, gross)


def conventional_exposures(shortest: float, frames: int, longest: float = 1.0) -> list[float]:
    """``frames`` exposures in geometric progression from ``shortest`` to ``longest``.

    Example:
        >>> conventional_exposures(1 / 16, 3)
        [0.0625, 0.25, 1.0]
    """
    if frames == 1:
        return [longest]
    step = (longest / shortest) ** (1.0 / (frames - 1))
    return [shortest * step**i for i in range(frames - 1)] + [longest]


def plan_conventional(
    stops: float,
    bits: int,
    noise: NoiseModel | str,
    *,
    sigmas: float = 3.0,
    shortest: float | None = None,
    target_median: float | None = None,
    frames: int | None = None,
) -> list[float]:
    """Exposures for a conventional (clipping) sensor with the same noise as a modulo sensor's plan: a geometric
    progression from the modulo plan's shortest exposure to 1.0, with the fewest frames whose predicted median error
    (:func:`predict_conventional` on the scene's ramp) meets ``target_median``.

    The predicted median falls as frames are added (each radiance then has an unsaturated frame nearer saturation),
    so the fewest frames are found by bisection on the count.

    Args:
        stops: the scene's dynamic range (``E_min`` reads one count at exposure 1.0).
        bits: the bit depth of both sensors.
        noise: their :class:`~torch_modulo.noise.NoiseModel` or a preset name.
        sigmas: the modulo decoder's gate, for the default ``shortest`` and ``target_median``.
        shortest: the shortest exposure (default: that of ``plan_exposures(stops, bits, noise=noise, sigmas=sigmas,
            longest=1.0)``), in (0, 1].
        target_median: the median relative error to meet (default: the modulo plan's predicted median,
            :func:`predict_modulo`).
        frames: the most frames to consider (default 256).

    Returns:
        Exposures in ascending order, ending at 1.0 (a single 1.0 when ``shortest`` is 1).

    Raises:
        TypeError: an argument of the wrong type.
        ValueError: a value out of range, or a target that no plan of at most ``frames`` frames meets (the message
            gives the predicted median with that many).

    Example:
        >>> taus = plan_conventional(12, 8, "q16", target_median=0.02)
        >>> taus[-1], predict_conventional(taus, 8, "q16", stops=12).median_error <= 0.02
        (1.0, True)
    """
    stops = check_real(stops, "stops", 0.0)
    bits = check_bits(bits, torch.float64)
    model = as_noise_model(noise)
    if model is None:
        raise ValueError("noise must be a NoiseModel or a preset name; got None")
    sigmas = check_real(sigmas, "sigmas", positive=True)
    budget = _MAX_FRAMES if frames is None else check_int(frames, "frames", 1, _MAX_FRAMES)
    modulo: list[float] | None = None
    if shortest is None:
        modulo = plan_exposures(stops, bits, noise=model, sigmas=sigmas, longest=1.0)
        shortest = modulo[0]
    shortest = check_real(shortest, "shortest", positive=True, high=1.0)
    if target_median is None:
        modulo = modulo or plan_exposures(stops, bits, noise=model, sigmas=sigmas, longest=1.0)
        target_median = predict_modulo(modulo, bits, model, sigmas, stops).median_error
    target = check_real(target_median, "target_median", positive=True)
    if shortest == 1.0:
        return [1.0]

    def median(count: int) -> float:
        return predict_conventional(conventional_exposures(shortest, count), bits, model, stops).median_error

    most = median(budget)
    if most > target:
        raise ValueError(
            f"target_median={target:g} is not met by a conventional plan of at most {budget} frames for "
            f"stops={stops:g} at bits={bits} under {model}: {budget} frames give a predicted median of {most:.4g}"
        )
    low, high = 0, budget  # `high` frames meet the target, `low` do not (0: none)
    while high - low > 1:
        mid = (low + high) // 2
        if median(mid) <= target:
            high = mid
        else:
            low = mid
    return conventional_exposures(shortest, high)
