r"""Exposure planning for multi-shot capture, noise-free and under a noise model, and the safety check of a plan.

Convention: a scene of ``stops`` stops spans radiances ``E_min .. E_max = 2**stops E_min``, where ``E_min`` reads one
count at the longest exposure and ``E_max`` does not roll over at the shortest (``base``).

Noise-free (``noise=None``), any ratio up to ``2**bits - 1`` decodes exactly, so the plan spreads the fewest such
ratios evenly. Under noise the ratio a frame may take depends on the counts and noise of the frames before it (see
:mod:`torch_modulo.multishot.noisy`): a pixel is decoded in the next frame only while ``r^2 Var(E^) tau^2 +
Var(I)`` stays under the gate. The planner walks a grid of radiances through the expected decoding and makes each
ratio as large as the pixels that still need the next frame allow. A pixel needs it until its variance is within
``tolerance**2`` of what the longest exposure alone would give it (its oracle), unless it is already at the
physical limit: a pixel whose next frame is undecodable even at ratio ``min_ratio`` is done. No neighbouring ratio
is below ``min_ratio``. Where what is left to reach the longest exposure is a shorter step, and the ratios before it,
each at most 1% longer (a gate 1% narrower in deviations: 2.97 for the default 3) and none past ``max_ratio``, reach
the longest exposure, they are stretched alike and that step is dropped (a frame saved). Else the frame before it
moves down so that the last step is ``min_ratio`` (a shorter step decodes whatever the longer one did), or, where that
step is too short to give up the room, the last frame moves up to ``min_ratio`` times the one before (every pixel that
needed it decodes that step, and the darkest read more than one count there).

A budget of ``frames`` exposures: under noise, where the plan of ``tolerance`` fits, the plan of the smallest
tolerance (>= 1) that fits (a smaller tolerance only adds frames, each bringing the pixels that still need one closer
to their oracle); where it does not, the plan of the smallest ``min_ratio`` that fits, at ``tolerance``. A larger
smallest ratio ends the brightest pixels earlier, at a physical limit a little below their best, while every other
ratio stays as large as the pixels that still need the next frame decode, so the dark and middle radiances keep
their precision. (Raising the tolerance instead lets the ratios grow past what the middle radiances decode, which
costs several times the median error and many more gross errors: docs/multishot.md, "Frames against error".) The
smallest ratio is raised only up to the ratio after which a pixel that read no signal in the shortest frame cannot
decode the next one (beyond it every dark pixel would keep only the shortest frames); where no plan up to there
fits, the budget raises the tolerance above ``tolerance`` instead, which takes ratios as large as the pixels still
far from their oracle (the darkest first) decode, and past that the largest ratios.
Noise-free, every plan within ``max_ratio`` decodes exactly and the estimate is the longest frame's, so the plan is
the fewest-frame one. Where even the largest ratios need more exposures than the budget, the planner says so and how
many they need, rather than return a plan that does not cover the scene.

By default a noisy plan is for the decoder with spatial evidence (``spatial=True``, :mod:`~torch_modulo.multishot.
spatial`): a pixel's prediction averages its agreeing neighbours, taken to shrink its variance by
:data:`~torch_modulo.multishot.spatial.PLANNED_SHRINK`, so the ratios are larger; ``spatial=False`` plans for each
pixel decoded alone.

Both plans hold at most 256 exposures. Under noise the planning runs in a power-of-two unit near ``base`` (which
changes no rounding), so any base within float64's range plans.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import cast

import torch

from torch_modulo._checks import check_bits, check_flag, check_int, check_real
from torch_modulo.multishot.spatial import PLANNED_SHRINK, WHOLE_SHARE, gates
from torch_modulo.noise import NoiseModel, as_noise_model

__all__ = [
    "brightest_unwrapped",
    "dark_rollover_message",
    "plan_exposures",
    "safe_ratio",
    "spatial_safe_ratio",
    "unsafe_ratio_message",
]

_MAX_FRAMES = 256


def _gate(bits: int, sigmas: float) -> float:
    return (2**bits / (2.0 * sigmas)) ** 2


def brightest_unwrapped(bits: int, noise: NoiseModel, sigmas: float = 3.0, exposure: float = 0.0) -> float:
    """The largest expected signal count ``c`` whose noisy reading stays ``sigmas`` deviations below ``2**bits - 1``
    in a frame of length ``exposure``.

    The frame also holds the dark counts of that exposure, ``noise.dark_counts * exposure``: they take their share
    of the counts below the rollover, and their shot noise is in the deviation. With ``exposure=0`` (or no dark
    current) ``c`` is the whole expected count. Returns 0 when the dark counts alone leave no room.

    Example:
        >>> 200 < brightest_unwrapped(8, NoiseModel()) < 215
        True
        >>> dark = NoiseModel(dark_current=20.0)                 # 20 e- per unit exposure, 1 e- per count
        >>> round(brightest_unwrapped(8, dark) - brightest_unwrapped(8, dark, exposure=2.0), 9)
        40.0
    """
    top = 2**bits - 1.0
    lo, hi = 0.0, top
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if mid + sigmas * math.sqrt(noise.count_variance(mid)) <= top:
            lo = mid
        else:
            hi = mid
    return max(lo - noise.dark_counts * exposure, 0.0)


def dark_rollover_message(bits: int, noise: NoiseModel, sigmas: float, exposure: float, name: str = "") -> str | None:
    """Why the dark counts of a shortest exposure ``exposure`` leave no count below the rollover under ``noise``
    (:func:`brightest_unwrapped` is 0 there), or None if they leave room.

    Shared by :func:`plan_exposures` and :func:`~torch_modulo.unwrap_multi`, so both say the same; callers add what
    to do. ``name`` prefixes the exposure in the message (``"base="``).

    Example:
        >>> dark_rollover_message(8, NoiseModel(dark_current=300.0), 3.0, 1.0)
        'noise NoiseModel(electrons_per_count=1.0, read_noise=1.0, dark_current=300.0, prnu=0.0, shot_noise=True): \
the dark counts of the shortest exposure 1 (300 counts) leave no count below the rollover at bits=8'
        >>> dark_rollover_message(8, NoiseModel(dark_current=30.0), 3.0, 1.0) is None
        True
    """
    if noise.dark_counts * exposure == 0 or brightest_unwrapped(bits, noise, sigmas, exposure=exposure) > 0:
        return None  # (without dark counts, what leaves no room is the noise: see plan_exposures)
    return (
        f"noise {noise}: the dark counts of the shortest exposure {name}{exposure:g} "
        f"({noise.dark_counts * exposure:g} counts) leave no count below the rollover at bits={bits}"
    )


def _largest_ratio(
    tau: torch.Tensor, radiance: torch.Tensor, variance: torch.Tensor, noise: NoiseModel, gate: float
) -> torch.Tensor:
    """Per radiance, the largest ratio ``r`` whose next frame passes the gate: ``(r tau)^2 Var + Var(I(r tau E))``."""
    a = tau**2 * variance
    b = tau * radiance / noise.electrons_per_count if noise.shot_noise else torch.zeros_like(radiance)
    c = float(noise.count_variance(0.0)) - gate
    return (-b + torch.sqrt(b * b - 4 * a * c)) / (2 * a)


#: How much longer than the gates allow each ratio of a noisy plan may be made so that the plan reaches its longest
#: exposure without a last short step (a frame for less than ``min_ratio``): 1%: 2.97 deviations for 3.
_STRETCH = 1.01

#: How much worse, in relative error, a spatial plan may leave a pixel at its physical limit than the per-pixel plan
#: (see :func:`_spatial_min_ratio`).
_LIMIT_SLACK = 1.18


def _spatial_ratio(
    tau: torch.Tensor, radiance: torch.Tensor, variance: torch.Tensor, noise: NoiseModel, bits: int, sigmas: float
) -> torch.Tensor:
    """Per radiance, the largest ratio whose next frame the decoder with spatial evidence decodes: the prediction's
    variance, ``Var / PLANNED_SHRINK`` at the next exposure, and the whole variance within the two gates of
    :func:`~torch_modulo.multishot.spatial.gates`."""
    gate, whole = gates(bits, sigmas)
    shrunk = variance / PLANNED_SHRINK
    return torch.minimum(torch.sqrt(gate / (tau**2 * shrunk)), _largest_ratio(tau, radiance, shrunk, noise, whole))


def _limit_error(ratio: float, count: float) -> float:
    """The mean of ``1 / sqrt(counts)`` of a pixel at its physical limit (shot noise), the counts summed over its
    decoded frames, on a geometric plan of ``ratio`` whose frames it decodes up to ``count``: its last frame reads
    ``count ratio^-u`` with ``u`` uniform in [0, 1] (where it falls between two frames), the earlier ones add
    ``1 / (ratio - 1)`` of that."""
    root = math.sqrt(ratio)
    return math.sqrt((ratio - 1.0) / ratio) * (root - 1.0) / (0.5 * math.log(ratio)) / math.sqrt(count)


def _spatial_min_ratio(min_ratio: float, limit: float) -> float:
    """The smallest ratio worth a frame of a spatial plan, for the per-pixel plan's ``min_ratio``.

    On a geometric plan of ratio ``r`` the prediction of a frame's count ``c`` has variance about ``(r - 1) c`` (the
    earlier frames hold ``c / (r - 1)`` counts), so a pixel alone decodes frames up to the count ``g / r`` where
    its whole variance ``r c`` meets the gate ``g``. With spatial evidence a pixel whose prediction fails its gate is
    still settled against the frame's own differences while its own noise passes the whole gate ``w``
    (:func:`~torch_modulo.multishot.spatial.settle_counts`), so it decodes frames up to ``w`` whatever the ratio. The
    result is the largest ``r`` whose :func:`_limit_error` there is within ``_LIMIT_SLACK`` times the per-pixel
    plan's at ``min_ratio``: pixels at their physical limit end about as precise, with larger ratios."""
    whole = 1.0 / WHOLE_SHARE**2  # the whole gate in units of the per-pixel gate
    target = _LIMIT_SLACK * _limit_error(min_ratio, 1.0 / min_ratio)
    low, high = min_ratio, limit
    if _limit_error(high, whole) <= target:
        return high
    for _ in range(60):
        mid = 0.5 * (low + high)
        low, high = (mid, high) if _limit_error(mid, whole) <= target else (low, mid)
    return max(low, min_ratio)


def spatial_safe_ratio(bits: int, noise: NoiseModel, sigmas: float) -> float:
    """:func:`safe_ratio`'s ratio for the decoder with spatial evidence: the largest ratio whose next frame
    :func:`_spatial_ratio` says the gross-error-prone pixels (up to ``c_min`` counts) still decode."""
    _, c_min = safe_ratio(bits, noise, sigmas)
    ratio = _spatial_ratio(
        torch.tensor(1.0, dtype=torch.float64),
        torch.tensor(c_min + noise.dark_counts, dtype=torch.float64),
        torch.tensor(noise.count_variance(c_min), dtype=torch.float64),
        noise,
        bits,
        sigmas,
    )
    return float(ratio)


def _noisy_plan(
    stops: float,
    bits: int,
    base: float,
    limit: float,
    noise: NoiseModel,
    sigmas: float,
    tolerance: float,
    min_ratio: float,
    shown: NoiseModel,
    most: int | None = None,
    spatial: bool = False,
) -> list[float] | None:
    """The noise-aware plan from ``base`` (see the module docstring); ``shown`` is the model the errors name. With
    ``most``, None as soon as the plan would hold more than ``most`` exposures (the budget search's early exit).

    With ``spatial``, the plan is for the decoder with spatial evidence (:mod:`~torch_modulo.multishot.spatial`):
    a frame is decodable where :func:`_spatial_ratio` allows, and ``min_ratio`` becomes :func:`_spatial_min_ratio`
    (about 5.1 for 1.5): each ratio is as large as the pixels that still need the next frame allow, and no smaller
    than where pixels at their physical limit keep about the per-pixel plan's precision."""
    gate = _gate(bits, sigmas)
    if spatial:
        min_ratio = _spatial_min_ratio(min_ratio, limit)
    first = brightest_unwrapped(bits, noise, sigmas, exposure=base)  # E_max's signal count at `base`
    longest = base * 2.0**stops / first  # E_min = 1 / longest reads one count there
    if longest <= base:
        return [float(base)]
    if not longest <= base * 2.0**500:  # the weights tau^2 / Var below stay within float64's range
        raise ValueError(
            f"stops={stops:g} under {shown} needs exposures spanning 2^{math.log2(longest / base):.0f}, beyond the "
            "2^500 the planner's weights hold in float64; plan fewer stops"
        )
    # Radiances E_min .. E_max on a log grid; E_max reads `first` counts (plus dark counts) at `base`.
    radiance = 2.0 ** torch.linspace(0.0, float(stops), max(256, int(32 * stops)), dtype=torch.float64) / longest
    radiance = radiance + noise.dark_counts
    oracle = noise.count_variance(longest * radiance) / longest**2
    tau = float(base)
    total = tau**2 / noise.count_variance(tau * radiance)
    active = torch.ones_like(radiance, dtype=torch.bool)
    plan = [tau]
    while tau < longest * (1 - 1e-12):
        if most is not None and len(plan) > most:  # (one frame more may still be stretched away below)
            return None
        if len(plan) >= _MAX_FRAMES:
            if most is not None:  # a budget search goes on to the next plan (the message names its settings)
                return None
            raise ValueError(
                f"stops={stops:g} under {shown} needs more than {_MAX_FRAMES} exposures; raise tolerance (got "
                f"{tolerance:g}) or min_ratio (got {min_ratio:g}), or plan fewer stops"
            )
        now = torch.tensor(tau, dtype=torch.float64)
        if spatial:
            ratios = _spatial_ratio(now, radiance, 1.0 / total, noise, bits, sigmas)
        else:
            ratios = _largest_ratio(now, radiance, 1.0 / total, noise, gate)
        needy = active & (1.0 / total > tolerance**2 * oracle) & (ratios >= min_ratio)
        r = float(ratios[needy].min()) if bool(needy.any()) else limit
        r = min(max(r, min_ratio), limit, longest / tau)
        tau = longest if r >= longest / tau * (1 - 1e-12) else tau * r
        active &= r <= ratios
        total = total + torch.where(active, tau**2 / noise.count_variance(tau * radiance), 0.0)
        plan.append(float(tau))
    short = len(plan) > 1 and plan[-1] < plan[-2] * min_ratio * (1 - 1e-12)
    steps = len(plan) - 2  # the ratios before the last step
    stretch = (plan[-1] / plan[-2]) ** (1.0 / steps) if short and steps > 0 else math.inf
    if stretch <= _STRETCH and max(b / a for a, b in zip(plan[:-2], plan[1:-1], strict=True)) * stretch <= limit:
        # The ratios before a short last step reach `longest` when each is a little longer (and still within
        # `limit`): drop that frame.
        plan = [t * stretch**i for i, t in enumerate(plan[:-2])] + [longest]
    elif short:
        # The last step, what is left to reach `longest`, is shorter than a frame is worth. Shorten the step before
        # it so that the last one is min_ratio (a shorter step decodes whatever the longer one did); where that step
        # is too short for it, lengthen the last frame to min_ratio: every pixel that needed it decodes a step of
        # min_ratio, and the darkest read more than one count there.
        if len(plan) > 2 and plan[-1] >= plan[-3] * min_ratio**2:
            plan[-2] = plan[-1] / min_ratio
        else:
            plan[-1] = plan[-2] * min_ratio
    return None if most is not None and len(plan) > most else plan


def plan_exposures(
    stops: float,
    bits: int = 8,
    *,
    base: float | None = None,
    longest: float | None = None,
    max_ratio: float | None = None,
    noise: NoiseModel | str | None = None,
    sigmas: float = 3.0,
    tolerance: float = 1.2,
    min_ratio: float = 1.5,
    frames: int | None = None,
    spatial: bool = True,
    longest_frames: int = 1,
) -> list[float]:
    """The fewest exposures whose modulo captures decode a scene of ``stops`` stops reliably, or the best plan within
    a budget of ``frames`` exposures.

    A scene spans ``E_max / E_min = 2**stops``, where ``E_min`` reads one count at the longest exposure and
    ``E_max`` must not roll over at the shortest exposure ``base``. Without noise, neighbouring ratios of up to
    ``max_ratio`` are spread evenly. With a ``noise`` model the shortest exposure keeps ``E_max`` (plus the dark
    counts of that exposure) ``sigmas`` deviations below the rollover, and each ratio is as large as the pixels
    that still need the next frame allow (see the module docstring), so that :func:`~torch_modulo.unwrap_multi`
    with the same ``noise`` decodes every radiance to within ``tolerance`` of what its longest frame alone would
    give, or to its physical limit.

    Plan in the unit the frames are captured in. Dark current is in electrons per unit exposure, so under dark
    current a plan depends on its absolute exposures: a plan rescaled afterwards (``[t / plan[-1] for t in plan]``)
    is a plan for other dark counts, and may not decode. Give ``longest`` to fix the longest exposure instead of
    the shortest: the plan is then made with the base that ends it at ``longest`` (where its last step is raised to
    ``min_ratio``, it ends a little past ``longest`` and is scaled back to it). Without dark current every plan
    is the ``base=1`` plan scaled, and ``longest`` gives exactly that plan times ``longest / plan[-1]``.

    With ``frames=K`` the plan holds at most ``K`` exposures (see the module docstring for which): under noise the
    one of the smallest tolerance down to 1 that fits, else of the smallest ``min_ratio`` that fits (up to the ratio
    a pixel that read no signal still decodes), else of the smallest larger tolerance; noise-free the fewest-frame
    plan.

    With ``longest_frames=L`` the longest exposure is taken ``L`` times (the budget ``frames`` counts them): the
    repeats collect light where every pixel that decodes the longest frame reads the most. Under noise a repeat can
    be worth more than the smaller ratios it replaces (docs/multishot.md, "Repeating the longest exposure").

    Args:
        stops: the scene's dynamic range, ``log2(E_max / E_min)``, >= 0.
        bits: the sensor's bit depth.
        base: the shortest exposure; default 1 (unless ``longest`` is given).
        longest: the longest exposure, instead of ``base``.
        max_ratio: the largest neighbouring ratio; default ``2**bits - 1`` (2 for a 1-bit counter).
        noise: the sensor's :class:`~torch_modulo.noise.NoiseModel` (or a preset name), or None for a noise-free
            sensor.
        sigmas: the decoding gate in standard deviations (the same as :func:`~torch_modulo.unwrap_multi`'s).
        tolerance: with noise, how far above its oracle standard deviation a pixel may end (>= 1).
        min_ratio: with noise, the smallest ratio worth a frame (> 1): no neighbouring ratio of the plan is smaller
            (the last frame may then lie past the exposure where ``E_min`` reads one count).
        frames: a budget of exposures (>= 1), or None for the fewest that meet ``tolerance``.
        spatial: with noise, plan for the decoder with spatial evidence (``unwrap_multi``'s default): its
            predictions average agreeing neighbours and the counts its prediction leaves uncertain are settled
            against the frame's own differences, so the plan takes larger ratios (at least about 5.1 with the
            default ``min_ratio``) and about a third of the frames. False: the plan for each pixel decoded alone
            (``unwrap_multi(..., spatial=False)``), which needs more frames but no neighbours: for images
            narrower than 3 pixels, or scenes of fine texture throughout (docs/multishot.md).
        longest_frames: how many frames take the longest exposure (>= 1). Only noise-aware decoding gains from the
            repeats: the noise-free decoders read the longest frame alone.

    Returns:
        Exposures in ascending order, starting at ``base`` (or ending at ``longest``).

    Raises:
        TypeError: an argument of the wrong type.
        ValueError: a value out of range, both ``base`` and ``longest``, a noise model that no exposure plan can
            decode (also: dark counts at ``base`` that reach the rollover), a plan of more than 256 exposures,
            exposures beyond float64's range, or ``frames`` fewer than even the largest ratios need (the message
            says how many they need).

    Example:
        >>> plan_exposures(24, bits=8, max_ratio=256)     # the paper: three 8-bit captures cover 24 stops
        [1.0, 256.0, 65536.0]
        >>> len(plan_exposures(24, bits=8))               # with ratios <= 255 it takes four
        4
        >>> plan = plan_exposures(16, bits=8, noise="q16")  # 16 e- per count, 16 e- read noise
        >>> len(plan) > 3, max(b / a for a, b in zip(plan, plan[1:])) < 32
        (True, True)
        >>> len(plan_exposures(16, bits=8, noise="q16", spatial=False)) > len(plan)  # each pixel alone: more frames
        True
        >>> dark = NoiseModel(dark_current=5.0)           # 5 e- per unit exposure: plan where the frames are taken
        >>> taus = plan_exposures(16, bits=8, noise=dark, longest=1.0, spatial=False)
        >>> same = plan_exposures(16, bits=8, noise=dark, base=taus[0], spatial=False)  # made at its own shortest
        >>> taus[-1], len(same) == len(taus) and all(abs(a / b - 1) < 1e-9 for a, b in zip(taus, same))
        (1.0, True)
        >>> len(plan_exposures(16, bits=8, noise="q16", frames=4))  # the best plan of at most four exposures
        4
    """
    stops = check_real(stops, "stops", 0.0)
    spatial = check_flag(spatial, "spatial")
    bits = check_bits(bits, torch.float64)
    if base is not None and longest is not None:
        raise ValueError(f"give base or longest, not both; got base={base!r} and longest={longest!r}")
    base = 1.0 if base is None else check_real(base, "base", positive=True)
    if longest is not None:
        longest = check_real(longest, "longest", positive=True)
    longest_frames = check_int(longest_frames, "longest_frames", 1, _MAX_FRAMES)
    if frames is not None:
        frames = check_int(frames, "frames", 1)
        if frames < longest_frames:
            raise ValueError(f"frames={frames} cannot hold the longest_frames={longest_frames} repeats of one exposure")
    repeats = longest_frames - 1  # the budget counts them: the plan before them has `frames - repeats`
    if max_ratio is None:
        limit = 2.0**bits - 1 if bits > 1 else 2.0  # a 1-bit counter decodes integer ratios up to 2 exactly
    else:
        limit = check_real(max_ratio, "max_ratio")
        if not 1 < limit <= 2**bits:
            raise ValueError(f"max_ratio must be in (1, 2^bits = {2**bits}]; got {max_ratio!r}")
    if stops - bits + math.log2(base) >= 1023:
        raise ValueError(
            f"stops={stops:g} from base={base:g} needs exposures beyond float64's range (about 2^1023); "
            "express exposures in a larger unit (a smaller base) or plan fewer stops"
        )
    model = as_noise_model(noise)
    if model is not None:
        sigmas = check_real(sigmas, "sigmas", positive=True)
        tolerance = check_real(tolerance, "tolerance", 1.0)
        min_ratio = check_real(min_ratio, "min_ratio")
        if not 1 < min_ratio <= limit:
            raise ValueError(f"min_ratio must be in (1, max_ratio = {limit:g}]; got {min_ratio}")
        if longest is not None and model.dark_counts > 0:
            base = _base_for_longest(stops, bits, longest, model, sigmas)
        gate = _gate(bits, sigmas)
        if model.count_variance(0.0) >= gate:
            raise ValueError(
                f"noise {model} leaves no margin at bits={bits}: its read noise alone exceeds the decoding gate "
                f"(2^bits / (2 sigmas))^2 = {gate:g}; use more bits or fewer sigmas"
            )
        message = dark_rollover_message(bits, model, sigmas, base, "base=")
        if message is not None:
            raise ValueError(f"{message}; use a shorter base (or longest)")
        # Plan in a unit near the base (a power of two: no rounding changes), where tau**2 stays in float64's range;
        # the dark current per unit exposure follows the unit.
        unit = 2.0 ** (math.frexp(base)[1] - 1)
        scaled = dataclasses.replace(model, dark_current=model.dark_current * unit) if model.dark_current else model

        def make(tol: float, ratio: float, most: int | None = None) -> list[float] | None:
            found = _noisy_plan(
                stops, bits, base / unit, limit, scaled, sigmas, tol, ratio, model, most, spatial=spatial
            )
            return None if found is None else [t * unit for t in found]

        if frames is None:
            plan = cast(list[float], make(tolerance, min_ratio))  # never None without a budget
        else:
            # The largest ratio after which a pixel that read no signal (its dark counts alone) in the shortest
            # frame still decodes the next one.
            now = torch.tensor(base / unit, dtype=torch.float64)
            dark = torch.tensor(scaled.dark_counts, dtype=torch.float64)
            blank = torch.tensor(scaled.count_variance(float(now * dark)), dtype=torch.float64) / now**2
            if spatial:
                reach = float(_spatial_ratio(now, dark, blank, scaled, bits, sigmas))
            else:
                reach = float(_largest_ratio(now, dark, blank, scaled, _gate(bits, sigmas)))
            scene = f"stops={stops:g} at bits={bits} under {model}"
            plan = _within_budget(make, frames - repeats, scene, tolerance, min_ratio, limit, reach, repeats)
        if not math.isfinite(plan[-1]):
            raise ValueError(
                f"stops={stops:g} from base={base:g} under {model} needs exposures beyond float64's range (about "
                "2^1024); express exposures in a larger unit (a smaller base) or plan fewer stops"
            )
    else:
        plan = _noise_free_plan(stops, bits, base, limit)
        if frames is not None and len(plan) + repeats > frames:
            need = len(plan) + repeats
            raise ValueError(
                f"frames={frames} is too few: stops={stops:g} at bits={bits} needs {need} exposures even with "
                f"ratios of max_ratio={limit:g}; allow {need} frames, raise max_ratio or plan fewer stops"
            )
    if len(plan) + repeats > _MAX_FRAMES:
        raise ValueError(
            f"a plan of {len(plan)} exposures with longest_frames={longest_frames} holds {len(plan) + repeats} frames, "
            f"more than {_MAX_FRAMES}; take the longest exposure fewer times"
        )
    plan += [plan[-1]] * repeats
    if longest is None:
        return plan
    return [t * longest / plan[-1] for t in plan]


def _within_budget(
    make: Callable[[float, float, int | None], list[float] | None],
    frames: int,
    scene: str,
    tolerance: float,
    min_ratio: float,
    limit: float,
    reach: float,
    repeats: int = 0,
) -> list[float]:
    """``make(tolerance, min_ratio, most)`` within a budget of ``frames`` exposures (the module docstring): the
    smallest tolerance from 1 up to ``tolerance`` whose plan fits; else the smallest ``min_ratio`` from ``min_ratio``
    up to ``reach`` (and ``limit``) whose plan fits; else the smallest tolerance above ``tolerance`` whose plan fits.
    Each by bisection on its logarithm (a tolerance of 2^64 plans as an infinite one: the largest ratios, the fewest
    frames). An error names the budget and the need with ``repeats`` more (the repeats of the longest exposure
    that follow the plan)."""
    asked, frames = frames + repeats, min(frames, _MAX_FRAMES)

    def smallest(fits: Callable[[float], list[float] | None], low: float, high: float) -> list[float] | None:
        """The plan of the smallest value in [low, high] that ``fits`` (fewer frames as it grows), or None."""
        best = fits(low)
        if best is not None or low >= high:
            return best
        best = fits(high)
        if best is None:
            return None
        low, high = math.log(low), math.log(high)  # too many frames at `low`; `high` fits
        for _ in range(40):
            mid = 0.5 * (low + high)
            found = fits(math.exp(mid))
            low, high, best = (mid, high, best) if found is None else (low, mid, found)
        return best

    plan = smallest(lambda tol: make(tol, min_ratio, frames), 1.0, tolerance)
    if plan is None and min_ratio <= reach:
        # Above `reach` a pixel that read nothing in a frame could not decode the next: every dark pixel would keep
        # only the shortest frames. (The last step of a plan may be longer than its smallest ratio.)
        plan = smallest(lambda ratio: make(tolerance, ratio, frames), min_ratio, min(limit, reach))
        if plan is not None and max((b / a for a, b in zip(plan, plan[1:], strict=False)), default=1.0) > reach:
            plan = None
    if plan is None:  # the tolerance lets each ratio grow as far as the pixels still far from their oracle decode
        plan = smallest(lambda tol: make(tol, min_ratio, frames), tolerance, 2.0**64)
    if plan is None:
        need = len(make(tolerance, limit, None) or []) + repeats
        raise ValueError(
            f"frames={asked} is too few: {scene} needs {need} exposures even with ratios of max_ratio={limit:g}; "
            f"allow {need} frames, raise max_ratio or plan fewer stops"
        )
    return plan


def _noise_free_plan(stops: float, bits: int, base: float, limit: float) -> list[float]:
    span_log2 = stops - bits
    if span_log2 <= 0:
        return [float(base)]
    count = 1 + math.ceil(span_log2 / math.log2(limit) - 1e-12)
    if count > _MAX_FRAMES:
        raise ValueError(
            f"stops={stops:g} at bits={bits} with max_ratio={limit!r} needs {count} exposures, more than "
            f"{_MAX_FRAMES}; raise max_ratio or plan fewer stops"
        )
    step = 2.0 ** (span_log2 / (count - 1))
    return [float(base * step**i) for i in range(count)]


def _base_for_longest(stops: float, bits: int, longest: float, noise: NoiseModel, sigmas: float) -> float:
    """The base whose noisy plan ends at ``longest``: ``longest = base 2**stops / s(base)`` with ``s(base) = c -
    D base`` (:func:`brightest_unwrapped` at ``base``, ``c`` its whole count, ``D`` the dark counts per unit
    exposure), solved for the base. Above ``longest`` the plan is the single frame ``base``, which then fits the
    scene at ``longest`` too."""
    whole = brightest_unwrapped(bits, noise, sigmas)
    return longest * whole / (2.0**stops + longest * noise.dark_counts)


def safe_ratio(bits: int, noise: NoiseModel, sigmas: float = 3.0) -> tuple[float, float]:
    """The largest neighbouring ratio that keeps every gross-error-prone pixel decodable under ``noise``.

    A pixel that stops decoding at ``c`` counts keeps a relative error of about ``sqrt(Var(c)) / c``; below the
    count ``c_min`` where ``sigmas`` such deviations reach half the value, that risks errors above 50%. Such a pixel
    must reach the next frame: ``r^2 Var(c_min) + Var(r c_min)`` within the gate.

    Returns:
        ``(ratio, c_min)``.

    Example:
        >>> ratio, c_min = safe_ratio(8, NoiseModel())
        >>> 5 < ratio < 8, 30 < c_min < 45
        (True, True)
    """
    lo, hi = 0.0, 2.0**bits
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if sigmas * math.sqrt(noise.count_variance(mid)) <= 0.5 * mid:
            hi = mid
        else:
            lo = mid
    c_min = hi
    ratio = _largest_ratio(
        torch.tensor(1.0, dtype=torch.float64),
        torch.tensor(c_min + noise.dark_counts, dtype=torch.float64),
        torch.tensor(noise.count_variance(c_min), dtype=torch.float64),
        noise,
        _gate(bits, sigmas),
    )
    return float(ratio), c_min


def unsafe_ratio_message(
    worst: float, bits: int, noise: NoiseModel, sigmas: float = 3.0, spatial: bool = True
) -> str | None:
    """Why a largest neighbouring ratio ``worst`` is unsafe under ``noise`` for the decoder with spatial evidence
    (the default: :func:`spatial_safe_ratio`), or with ``spatial=False`` for each pixel decoded alone (see
    :func:`safe_ratio`), or None if safe.

    Callers add what to use instead.

    Example:
        >>> unsafe_ratio_message(4.0, 8, NoiseModel(), spatial=False) is None
        True
        >>> unsafe_ratio_message(256.0, 8, NoiseModel(), spatial=False).startswith("exposure ratio 256 is unsafe")
        True
        >>> unsafe_ratio_message(12.0, 8, NoiseModel()) is None  # with spatial evidence
        True
    """
    if spatial:
        ratio = spatial_safe_ratio(bits, noise, sigmas)
        if worst <= ratio * (1 + 1e-9):
            return None
        return (
            f"exposure ratio {worst:g} is unsafe under {noise} even with spatial evidence: dark pixels cannot be "
            f"decoded in the longer frame and keep errors of 50% or more; keep ratios <= {ratio:.3g}"
        )
    ratio, c_min = safe_ratio(bits, noise, sigmas)
    if worst <= ratio * (1 + 1e-9):
        return None
    return (
        f"exposure ratio {worst:g} is unsafe under {noise}: pixels that read up to {c_min:.0f} counts in the "
        f"shorter frame cannot be decoded in the longer one and keep errors of 50% or more; keep ratios <= "
        f"{ratio:.3g}"
    )
