"""How the folder commands scale a scene, choose its exposures, and score a result against the stored truth; and,
for colour sensors, which colour filter array a frame has and which scenes a colour sensor can capture.

The rules are described in :mod:`torch_modulo.pipeline` (which re-exports :func:`plan_scene` and
:func:`fit_scale`); this module keeps them apart from the jobs that apply them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch

from torch_modulo.noise import PRESETS, NoiseModel, as_noise_model
from torch_modulo.protocols import protocol_n

__all__ = [
    "NoiseSpec",
    "colour_scene",
    "count_accuracy",
    "fit_scale",
    "frame_cfa",
    "matching_truth",
    "noise_model",
    "noise_name",
    "plan_scene",
    "radiance_accuracy",
    "restored_colour",
    "restored_confidence",
    "scene_stops",
    "shrink_scene",
    "undecodable_ratio",
    "unsafe_ratio_warnings",
]

#: A noise model as the jobs take it: a NoiseModel, a preset name, a NoiseModel's fields, or None (noise-free).
NoiseSpec = NoiseModel | str | Mapping[str, Any] | None


def noise_model(noise: NoiseSpec) -> NoiseModel | None:
    """A job option's noise (None, a preset name, NoiseModel fields or a NoiseModel) as a NoiseModel or None."""
    if isinstance(noise, Mapping):
        return NoiseModel(**noise)
    return as_noise_model(noise)


def noise_name(noise: NoiseModel | None) -> str | None:
    """The preset a noise model is, else its fields; None without noise (for reports)."""
    if noise is None:
        return None
    for name, fields in PRESETS.items():
        if NoiseModel(**fields) == noise:
            return name
    return str(noise)


def scene_stops(image: torch.Tensor) -> int:
    return protocol_n(image)[1]


def plan_scene(
    image: torch.Tensor,
    bits: int = 8,
    noise: NoiseSpec = None,
    *,
    scale: float | str = "auto",
    spatial: bool = True,
    longest_frames: int = 1,
) -> tuple[list[float], float, int]:
    """Protocol N's exposures for one scene (``simulate --exposures auto``): ``(exposures, scale, stops)``.

    The scene needs ``stops = ceil(log2(max / p) + 4)``, with ``p`` the 0.1th percentile of its positive values.
    The exposures are :func:`~torch_modulo.plan_exposures` ``(stops, bits, noise=noise, longest=L)``, with ``L``
    the exposure at which ``p`` times the radiance scale reads 16 counts. With ``scale="auto"`` the scale is
    ``16 / p`` and the longest exposure is 1; with a number, the exposures move instead. The plan is made at the
    exposures that are captured: under dark current (electrons per unit exposure) a plan made at other exposures
    and rescaled would reason about the wrong dark counts; without it, this is the plan for ``base=1`` scaled to
    end at ``L``. Where the noise-free plan would put the brightest value exactly on the rollover at the shortest
    exposure, one more stop is planned. With ``spatial`` (the default), the plan is for the decoder with spatial
    evidence (``plan_exposures``' and ``unwrap_multi``'s default: fewer frames); False plans for each pixel alone;
    ``longest_frames`` takes its longest exposure that many times (``plan_exposures(..., longest_frames=...)``).

    Args:
        image: radiance >= 0 with at least one positive value, any shape.
        bits: the sensor's bit depth.
        noise: the sensor's noise model (a :class:`~torch_modulo.noise.NoiseModel`, a preset name or its fields),
            or None.
        scale: ``"auto"`` or the radiance multiplier.
        spatial: plan for the decoder with spatial evidence (False: for each pixel decoded alone).
        longest_frames: how many frames take the longest exposure (>= 1).

    Returns:
        The exposures (ascending), the radiance scale and the stops.

    Raises:
        ValueError: a black image, or a scene the noise model cannot plan for.

    Example:
        >>> image = torch.exp2(torch.linspace(0.0, 12.0, 1000))       # 12 stops
        >>> taus, scale, stops = plan_scene(image, bits=8)
        >>> stops, len(taus), taus[-1], round(scale * float(image.max()) * taus[0])
        (16, 3, 1.0, 254)
    """
    from torch_modulo.multishot import plan_exposures

    model = noise_model(noise)
    auto_scale, stops = protocol_n(image)
    peak = float(image.max())
    factor = auto_scale if scale == "auto" else float(scale)
    longest = auto_scale / factor  # the 0.1th percentile reads 16 counts there
    for extra in (0, 1):
        taus = plan_exposures(
            stops + extra, bits, noise=model, longest=longest, spatial=spatial, longest_frames=longest_frames
        )
        if peak * factor * taus[0] * (1 + 1e-6) < 2**bits:
            break
    return taus, factor, stops + extra


def _brightest_count(bits: int, noise: NoiseModel | None, exposure: float) -> float:
    """The largest expected signal count at ``exposure`` whose reading, with that exposure's dark counts, stays three
    deviations below the rollover (``2**bits - 1`` without noise)."""
    from torch_modulo.multishot import brightest_unwrapped

    top = 2.0**bits - 1
    if noise is None or noise.is_noiseless:
        return top
    if brightest_unwrapped(bits, noise) < 1:
        raise ValueError(f"noise {noise} leaves no count below the rollover at bits={bits}: use more bits")
    lo = brightest_unwrapped(bits, noise, exposure=exposure)
    if lo < 1:
        raise ValueError(
            f"noise {noise}: the dark counts of the shortest exposure {exposure:g} "
            f"({noise.dark_counts * exposure:g} counts) leave no count below the rollover at bits={bits}; "
            "use shorter exposures"
        )
    return lo


def fit_scale(image: torch.Tensor, bits: int, exposures: Sequence[float], noise: NoiseSpec = None) -> float:
    """The radiance scale of ``simulate --scale auto`` for given exposures (see :mod:`torch_modulo.pipeline`).

    Several exposures: the brightest value reads ``2**bits - 1`` at the shortest (under noise, the largest count
    whose reading, with the dark counts of that exposure, stays three standard deviations below the rollover). One
    exposure: the 99.9th percentile of the luminance (of all values for grey or two-channel images) reads
    ``16 * 2**bits - 1`` counts, so the frame wraps.

    Args:
        image: radiance >= 0, (C, H, W) or any shape (luminance is taken where C = 3).
        bits: the sensor's bit depth.
        exposures: the exposures, one or more.
        noise: the sensor's noise model (as for :func:`plan_scene`), or None.

    Raises:
        ValueError: a black image, or noise that leaves no count below the rollover.

    Example:
        >>> image = torch.tensor([[[1.0, 2.0, 4.0]]])
        >>> fit_scale(image, 8, [1.0, 16.0]) * 4.0                    # the brightest reads 255 at exposure 1
        255.0
    """
    peak = float(image.max()) if image.numel() else 0.0
    if not peak > 0:
        raise ValueError(f"the image is black (maximum {peak}): nothing to scale")
    taus = [float(t) for t in exposures]
    if len(taus) > 1:
        return _brightest_count(bits, noise_model(noise), min(taus)) / (peak * min(taus))
    values = image
    if image.dim() >= 3 and image.shape[-3] == 3:
        from torch_modulo.tonemap import REC709_LUMA

        values = torch.einsum("...chw,c->...hw", image.double(), torch.tensor(REC709_LUMA, dtype=torch.float64))
    p = float(np.percentile(values.detach().double().cpu().numpy(), 99.9))
    if not p > 0:
        p = float(values.max())
    return (16 * 2.0**bits - 1) / (p * taus[0])


def shrink_scene(
    image: torch.Tensor, max_side: int | None, crop: Sequence[int] | None, source: object
) -> tuple[torch.Tensor, dict[str, Any]]:
    """A (C, H, W) scene made smaller for ``simulate``: area-averaged by the smallest integer factor that brings its
    longer side to at most ``max_side`` (:func:`torch_modulo.protocols.downsample_area`, as the benchmarks shrink
    scenes), then cropped to its centre ``crop`` (height, width); and what was done, for the report.

    Raises:
        ValueError: the scene (after ``max_side``) is smaller than ``crop``; the message names ``source``.

    Example:
        >>> scene, facts = shrink_scene(torch.ones(1, 12, 16), 8, (4, 6), "a.exr")
        >>> tuple(scene.shape), facts
        ((1, 4, 6), {'shrunk': [12, 16, 6, 8], 'cropped': [4, 6]})
    """
    from torch_modulo.protocols import downsample_area

    facts: dict[str, Any] = {}
    h, w = image.shape[-2:]
    if max_side is not None:
        image = downsample_area(image, int(max_side))
        if tuple(image.shape[-2:]) != (h, w):
            facts["shrunk"] = [h, w, *image.shape[-2:]]
    if crop is not None:
        ch, cw = (int(v) for v in crop)
        h, w = image.shape[-2:]
        if ch > h or cw > w:
            after = " after --max-side" if "shrunk" in facts else ""
            raise ValueError(f"{source} is {h} x {w}{after}, smaller than --crop {ch} x {cw}")
        top, left = (h - ch) // 2, (w - cw) // 2
        image = image[..., top : top + ch, left : left + cw]
        facts["cropped"] = [ch, cw]
    return image, facts


def undecodable_ratio(taus: Sequence[float], bits: int) -> str | None:
    """Why rollover counting cannot decode exposures ``taus`` at ``bits`` bits, or None when it can: two neighbours
    more than ``2**bits`` apart, or more than ``2**bits - 1`` apart by a ratio that is not a whole number (Eq. 6
    decodes ratios up to ``2**bits - 1``, and whole ratios up to ``2**bits``, exactly).

    Example:
        >>> undecodable_ratio([1, 1000, 1e6], 8)
        'exposures 1 and 1000 are 1000 times apart, more than 2^8 = 256'
        >>> undecodable_ratio([1, 255.5], 8)
        'exposures 1 and 255.5 are 255.5 times apart, more than 2^8 - 1 = 255 and not a whole ratio'
        >>> undecodable_ratio([1, 16, 256], 8) is None
        True
    """
    ordered = sorted(float(t) for t in taus)
    for a, b in zip(ordered, ordered[1:], strict=False):
        ratio, apart = b / a, f"exposures {a:g} and {b:g} are {b / a:g} times apart"
        if ratio > 2.0**bits:
            return f"{apart}, more than 2^{bits} = {2**bits}"
        if ratio > 2.0**bits - 1 and not float(ratio).is_integer():
            return f"{apart}, more than 2^{bits} - 1 = {2**bits - 1} and not a whole ratio"
    return None


def unsafe_ratio_warnings(
    taus: Sequence[float], bits: int, noise: NoiseModel | None, image: torch.Tensor, spatial: bool = True
) -> list[str]:
    """A warning when given exposures have a neighbouring ratio the noise model says is unsafe for the decoder
    (with ``spatial``, the default, the one with spatial evidence; else each pixel alone), naming a plan."""
    if noise is None or noise.is_noiseless or len(taus) < 2:
        return []
    from torch_modulo.multishot import unsafe_ratio_message

    ordered = sorted(taus)
    message = unsafe_ratio_message(
        max(b / a for a, b in zip(ordered, ordered[1:], strict=False)), bits, noise, spatial=spatial
    )
    if message is None:
        return []
    stops = scene_stops(image)
    try:  # what --exposures auto plans (the longest exposure 1: under dark current the count depends on it)
        auto, _, stops = plan_scene(image, bits, noise, spatial=spatial)
        plan = f"{len(auto)} exposures"
    except ValueError as error:
        plan = f"none possible: {error}"
    flag = "" if spatial else ", spatial=False"
    return [
        f"{message}, e.g. --exposures auto (for this scene plan_exposures({stops}, bits={bits}, noise=noise, "
        f"longest=1{flag}): {plan})"
    ]


def radiance_accuracy(estimate: torch.Tensor, truth: torch.Tensor) -> dict[str, float]:
    """Relative error against the truth over the values it holds above 0: median and share more than 50% off."""
    mask = truth > 0
    if not bool(mask.any()):
        return {}
    rel = (estimate.double()[mask] - truth[mask]).abs() / truth[mask]
    return {"median_relative_error": float(rel.median()), "gross_share": float((rel > 0.5).double().mean())}


def count_accuracy(
    counts: torch.Tensor, modulus: torch.Tensor, truth: torch.Tensor, exposure: float, bits: int
) -> dict[str, float]:
    """Exact-k and PSNR of restored counts against the truth's: the frame's modulus plus the multiple of ``2**bits``
    nearest to ``exposure * truth`` (``floor(exposure * truth)`` for a noise-free frame). Both after aligning each
    channel's global rollover offset, as the benchmarks score single shot (``protocols.score_scene``)."""
    from torch_modulo.metrics import exact_k_share, psnr
    from torch_modulo.protocols import align_offsets

    period = 2.0**bits
    m = modulus.double()
    reference = m + period * torch.round((truth * exposure - m) / period)
    reference = torch.where(reference < 0, reference + period, reference)
    restored = counts.double()
    return {
        "exact_k": float(exact_k_share(restored, reference, bits)[0]),
        "psnr_db": float(
            psnr(align_offsets(restored, reference, bits), reference, peak=max(float(reference.max()), 1.0))[0]
        ),
    }


# ------------------------------------------------------------------------------------------- colour sensors


def colour_scene(image: torch.Tensor, cfa: str, source: object) -> tuple[torch.Tensor, list[str]]:
    """The part of a (C, H, W) scene a colour sensor with pattern ``cfa`` captures, and a note when it was cropped.

    The scene must be RGB; an odd height or width loses its last row or column (a mosaic holds whole 2 x 2 cells).

    Raises:
        ValueError: not three channels (the message names ``source`` and says to drop ``--cfa``), or a scene
            smaller than one 2 x 2 cell.

    Example:
        >>> scene, notes = colour_scene(torch.ones(3, 5, 4), "RGGB", "a.exr")
        >>> tuple(scene.shape), notes
        ((3, 4, 4), ['cropped 5 x 4 to 4 x 4: a mosaic holds whole 2 x 2 cells (the truth is cropped too)'])
    """
    c, h, w = image.shape[-3:]
    if c != 3:
        raise ValueError(
            f"{source} is not an RGB scene ({c} channel{'s' * (c != 1)}): --cfa {cfa} simulates a colour sensor, "
            "whose filters need red, green and blue radiance; simulate grey scenes without --cfa"
        )
    even_h, even_w = h - h % 2, w - w % 2
    if (even_h, even_w) == (h, w):
        return image, []
    if not (even_h and even_w):
        raise ValueError(f"{source} is {h} x {w}: too small for a mosaic ({cfa}: whole 2 x 2 cells)")
    note = f"cropped {h} x {w} to {even_h} x {even_w}: a mosaic holds whole 2 x 2 cells (the truth is cropped too)"
    return image[..., :even_h, :even_w], [note]


def frame_cfa(given: str | None, recorded: object, source: object, shape: Sequence[int]) -> str | None:
    """The colour filter array of a frame: ``recorded`` (its stack's or metadata's) unless ``given`` (``--cfa``).

    Args:
        given: the pattern the user gave, or None.
        recorded: the pattern the frame records, or None.
        source: the frame's file or stack (named in errors).
        shape: the frame's (C, H, W) shape.

    Returns:
        The pattern, or None for frames that are not mosaics.

    Raises:
        ValueError: ``given`` and ``recorded`` disagree (both named), an unknown pattern, or a frame that is not a
            mosaic (one channel, an even height and width).

    Example:
        >>> frame_cfa(None, "RGGB", "stack", (1, 4, 6)), frame_cfa("GRBG", None, "a.png", (1, 4, 6))
        ('RGGB', 'GRBG')
    """
    from torch_modulo.cfa import check_cfa

    if given is not None and recorded is not None and given != recorded:
        raise ValueError(
            f"{source} records the colour filter array {recorded!r} but --cfa {given} was given: drop --cfa, "
            f"or pass --cfa {recorded}"
        )
    if given is None and recorded is None:
        return None
    pattern = check_cfa(given, "--cfa") if given is not None else check_cfa(recorded, f"the cfa of {source}")
    c, h, w = shape[-3:]
    if c != 1 or h % 2 or w % 2:
        raise ValueError(
            f"{source} is not a mosaic (cfa {pattern}): a mosaic has one channel and an even height and width "
            f"(whole 2 x 2 cells); got {c} x {h} x {w}"
        )
    return pattern


def matching_truth(truth: torch.Tensor | None, shape: Sequence[int], cfa: str | None) -> torch.Tensor | None:
    """The stored truth as a result of ``shape`` is scored against: as is, mosaicked (an RGB truth of a restored
    mosaic), or None when it does not fit.

    Example:
        >>> rgb = torch.arange(3.0).view(3, 1, 1).expand(3, 2, 2)
        >>> matching_truth(rgb, (1, 2, 2), "RGGB")[0].tolist()
        [[0.0, 1.0], [1.0, 2.0]]
    """
    if truth is None:
        return None
    if tuple(truth.shape) == tuple(shape):
        return truth
    if cfa is not None and shape[0] == 1 and tuple(truth.shape) == (3, *shape[1:]):
        from torch_modulo.cfa import mosaic

        return mosaic(truth, cfa)
    return None


def restored_colour(
    values: torch.Tensor, cfa: str | None, *, demosaic: bool = True
) -> tuple[torch.Tensor, dict[str, Any]]:
    """A restored mosaic (1, H, W) demosaiced to RGB (3, H, W) unless ``demosaic`` is False, and the output
    metadata that says what was done. Values that are not a mosaic (``cfa`` None) are returned as they are.

    Example:
        >>> rgb, meta = restored_colour(torch.full((1, 2, 2), 5.0), "RGGB")
        >>> tuple(rgb.shape), meta
        ((3, 2, 2), {'cfa': 'RGGB', 'demosaic': 'malvar'})
    """
    if cfa is None:
        return values, {}
    if not demosaic:
        return values, {"cfa": cfa, "demosaic": "none"}
    from torch_modulo.cfa import DEMOSAIC_METHODS
    from torch_modulo.cfa import demosaic as demosaic_counts

    return demosaic_counts(values.unsqueeze(0), cfa)[0], {"cfa": cfa, "demosaic": DEMOSAIC_METHODS[0]}


def restored_confidence(counts: torch.Tensor, bits: int, cfa: str | None) -> torch.Tensor:
    """:func:`~torch_modulo.unwrap_confidence` of restored counts (C, H, W); of a mosaic, per colour plane
    (photosites of one colour are each other's neighbours there), put back in place as (1, H, W).

    Example:
        >>> restored_confidence(torch.zeros(1, 4, 4), 8, "RGGB").unique().tolist()
        [1.0]
    """
    from torch_modulo.singleshot import unwrap_confidence

    if cfa is None:
        return unwrap_confidence(counts, bits)
    from torch_modulo.cfa import merge_planes, split_planes

    return merge_planes(unwrap_confidence(split_planes(counts), bits))
