"""The single-shot measurement protocols: scenes, protocols A, A10 and B, and their scores.

One module turns a radiance map into a benchmark number, so that the benchmarks (``benchmarks/``), the examples and
anyone reproducing a published number use the same code.

Scenes:

- :func:`list_scenes`: every ``.exr``/``.hdr`` file below a folder, sorted by path; ``split="train"`` or
  ``"validation"`` keeps one side of the split (:data:`TRAIN_SOURCES`, :data:`VALIDATION_SOURCES`,
  :func:`scene_split`). :data:`DEV_SCENES` is where a source checkout finds the development scenes.
- :func:`load_scene`: read an HDR file, zero NaN/Inf and negatives, and downsample it by whole-pixel area averaging
  until its longer side is at most ``max_side`` (:func:`downsample_area`).

Protocols (12-bit or 10-bit true counts ``I``; the 8-bit modulus is ``I mod 256``):

- :func:`protocol_a`: the paper's setting: luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` scaled so that its
  99.9th percentile is ``peak`` (4095: a 12-bit scene), clipped to ``[0, peak]`` and floored.
- :func:`protocol_a10`: protocol A with the 99.9th percentile at 1023 (10 bits, at most four rollovers).
- :func:`protocol_b`: the UnModNet setting: RGB min-max scaled to [0, 1], the exposure ``e`` chosen by bisection so
  that ``share`` (20%) of the pixels roll over (``floor(clip(x e, 0, 1) * peak) >= period``) in at least one
  channel; the counts are ``floor(clip(x e, 0, 1) * peak)`` per channel.
- :func:`protocol_counts` and :data:`PROTOCOL_PEAKS` select a protocol by name; the peak is also the PSNR peak.
- :func:`protocol_n` (multi shot under noise): the radiance scale that makes the 0.1th percentile of the positive
  values read 16 counts at exposure 1, and the stops the scene needs, ``ceil(log2(max / that percentile) + 4)``;
  :func:`protocol_n_scores` scores a radiance estimate (relative errors, by third of the radiance too).

Scores (per scene, :func:`score_scene`): each channel's global rollover offset is aligned with the truth first
(:func:`align_offsets`: the most common difference of the rollover counts ``k = floor(I / 2^N)``); then *exact-k*
is the share of values whose ``k`` is right, *rolled-over right* (:func:`rolled_over_right`) the same share over the
values whose true ``k`` is above 0 only (a method that unwraps nothing scores 0 there), and PSNR compares the
aligned counts with the truth.

:func:`parse_method` reads the method specifications the benchmarks take (``"guided:denoise=0.7"``).
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np
import torch

from torch_modulo._checks import (
    check_choice,
    check_finite,
    check_floating,
    check_image_shape,
    check_int,
    check_real,
)
from torch_modulo.io import read_image
from torch_modulo.tonemap import luminance

__all__ = [
    "DEV_SCENES",
    "HDR_SUFFIXES",
    "PROTOCOL_PEAKS",
    "RADIANCE_BANDS",
    "SPLITS",
    "TRAIN_SOURCES",
    "VALIDATION_SOURCES",
    "SceneScore",
    "align_offsets",
    "downsample_area",
    "list_scenes",
    "load_scene",
    "parse_method",
    "protocol_a",
    "protocol_a10",
    "protocol_b",
    "protocol_counts",
    "protocol_n",
    "protocol_n_levels",
    "protocol_n_scores",
    "rolled_over_right",
    "scene_split",
    "score_scene",
]

#: File endings of the radiance maps the protocols read.
HDR_SUFFIXES = (".exr", ".hdr")

#: The development scenes of a source checkout: ``shared/data/hdr`` in the folder that holds the repository. One
#: sub-folder per source; nothing there is copied into the repository.
DEV_SCENES = Path(__file__).resolve().parents[2] / "shared" / "data" / "hdr"

#: Sources (first folder below the scenes folder) a learned method may train on: CC0 and BSD-licensed scenes.
TRAIN_SOURCES = ("openexr-images", "polyhaven-cc0")

#: Sources kept aside to validate learned methods on.
VALIDATION_SOURCES = ("hdr-samples", "hdr-toolbox", "light-probes", "qt-preview")

#: What :func:`list_scenes` can keep.
SPLITS = ("all", "train", "validation")

#: The single-shot protocols by name, with their largest count (also the PSNR peak).
PROTOCOL_PEAKS: dict[str, float] = {"A": 4095.0, "A10": 1023.0, "B": 4095.0}

Split = Literal["train", "validation", "other"]


# --------------------------------------------------------------------------------------------------------------------
# scenes
# --------------------------------------------------------------------------------------------------------------------


def scene_split(path: str | os.PathLike[str], folder: str | os.PathLike[str]) -> Split:
    """The side of the split a scene below ``folder`` is on, from its source (the first folder below ``folder``).

    Args:
        path: a scene file below ``folder``.
        folder: the scenes folder (:data:`DEV_SCENES` for the development scenes).

    Returns:
        ``"train"`` for :data:`TRAIN_SOURCES`, ``"validation"`` for :data:`VALIDATION_SOURCES`, else ``"other"``.

    Raises:
        ValueError: ``path`` is not below ``folder``.

    Example:
        >>> scene_split("hdr/qt-preview/landscape.hdr", "hdr"), scene_split("hdr/polyhaven-cc0/park.exr", "hdr")
        ('validation', 'train')
        >>> scene_split("hdr/mine.exr", "hdr")
        'other'
    """
    try:
        parts = Path(path).relative_to(Path(folder)).parts
    except ValueError:
        raise ValueError(f"path must be below folder {str(folder)!r}; got {str(path)!r}") from None
    source = parts[0] if len(parts) > 1 else ""
    if source in TRAIN_SOURCES:
        return "train"
    if source in VALIDATION_SOURCES:
        return "validation"
    return "other"


def list_scenes(folder: str | os.PathLike[str], split: str = "all") -> list[Path]:
    """Every .exr/.hdr file below ``folder``, sorted by path; with ``split``, only one side of the split. Hidden files
    (``.name.exr``, such as the ``._`` files macOS leaves) are skipped, as :class:`~torch_modulo.data.HDRFolder`
    skips them.

    Args:
        folder: the scenes folder (:data:`DEV_SCENES` for the development scenes); missing gives an empty list.
        split: ``"all"`` (default), ``"train"`` or ``"validation"`` (see :func:`scene_split`).

    Raises:
        ValueError: ``split`` is not one of :data:`SPLITS`.
    """
    split = check_choice(split, "split", SPLITS)
    scenes = sorted(
        p
        for p in Path(folder).rglob("*")
        if p.suffix.lower() in HDR_SUFFIXES and not p.name.startswith(".") and p.is_file()
    )
    if split == "all":
        return scenes
    return [p for p in scenes if scene_split(p, folder) == split]


def downsample_area(image: torch.Tensor, max_side: int) -> torch.Tensor:
    """Average whole-pixel blocks by the smallest integer factor that brings the longer side to <= ``max_side``.

    Rows and columns that do not fill a block are dropped; a side shorter than the factor becomes one pixel, the
    mean of all of it (a 3 x 2000 panorama strip at 512 becomes 1 x 500, not empty).

    Example:
        >>> downsample_area(torch.arange(16.0).view(1, 4, 4), 2)
        tensor([[[ 2.5000,  4.5000],
                 [10.5000, 12.5000]]])
    """
    check_floating(image, "image")
    check_image_shape(image, "image", min_dims=3, max_dims=3)
    max_side = check_int(max_side, "max_side", 1)
    c, h, w = image.shape
    f = max(h, w) // (max_side + 1) + 1  # the smallest f with max(h, w) // f <= max_side (incomplete blocks drop)
    if f == 1:
        return image
    fh, fw = min(f, h), min(f, w)
    h2, w2 = h // fh, w // fw
    return image[:, : h2 * fh, : w2 * fw].reshape(c, h2, fh, w2, fw).mean(dim=(2, 4))


def load_scene(path: str | os.PathLike[str], max_side: int | None = 512) -> torch.Tensor:
    """(C, H, W) float64 radiance of an HDR file: RGB (first three channels) or one luminance channel.

    NaN, infinities and negative values (lossy compression) become 0; with ``max_side`` the image is area-averaged
    down (:func:`downsample_area`).
    """
    image = read_image(path)
    image = image[:3] if image.shape[0] >= 3 else image[:1]
    image = torch.nan_to_num(image.double(), nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0.0)
    return downsample_area(image, max_side) if max_side is not None else image


# --------------------------------------------------------------------------------------------------------------------
# protocols
# --------------------------------------------------------------------------------------------------------------------


def protocol_a(image: torch.Tensor, peak: float = 4095.0) -> torch.Tensor:
    """(1, H, W) counts: luminance scaled so its 99.9th percentile is ``peak``, clipped to [0, peak], floored.

    Args:
        image: (C, H, W) radiance, C = 1 (luminance itself) or 3 (linear RGB).
        peak: the count the 99.9th percentile maps to, and the largest count.

    Example:
        >>> protocol_a(torch.full((3, 2, 2), 0.5)).flatten().tolist()
        [4095.0, 4095.0, 4095.0, 4095.0]
    """
    check_floating(image, "image")
    check_image_shape(image, "image", min_dims=3, max_dims=3)
    if image.shape[0] not in (1, 3):
        raise ValueError(f"image must have 1 or 3 channels; got {image.shape[0]}")
    check_finite(image, "image")
    peak = check_real(peak, "peak", positive=True)
    y = luminance(image[None])[0, 0]
    p = float(np.percentile(y.detach().cpu().double().numpy(), 99.9))
    if p <= 0:
        p = float(y.max()) or 1.0
    return torch.floor(torch.clamp(y * (peak / p), 0.0, peak))[None]


def protocol_a10(image: torch.Tensor) -> torch.Tensor:
    """(1, H, W) counts of protocol A with the 99.9th percentile at 1023 (10 bits): :func:`protocol_a` with peak 1023.

    Example:
        >>> protocol_a10(torch.full((1, 2, 2), 3.0)).flatten().tolist()
        [1023.0, 1023.0, 1023.0, 1023.0]
    """
    return protocol_a(image, peak=PROTOCOL_PEAKS["A10"])


def protocol_b(image: torch.Tensor, share: float = 0.2, peak: float = 4095.0, period: float = 256.0) -> torch.Tensor:
    """(C, H, W) counts of min-max scaled RGB at the exposure that makes ``share`` of the pixels roll over.

    Warns:
        UserWarning: no exposure makes ``share`` of the pixels roll over (most pixels are at the minimum); the
        counts are then those of the largest exposure tried (``2**40``).

    Example:
        >>> counts = protocol_b(torch.linspace(0, 1, 100).view(1, 1, 100))
        >>> round(float((counts >= 256).double().mean()), 2)
        0.2
    """
    check_floating(image, "image")
    check_image_shape(image, "image", min_dims=3, max_dims=3)
    check_finite(image, "image")
    share = check_real(share, "share")
    if not 0.0 < share < 1.0:
        raise ValueError(f"share must be in (0, 1); got {share}")
    peak = check_real(peak, "peak", positive=True)
    period = check_real(period, "period", positive=True)
    if not period <= math.floor(peak):  # the counts are floor(x e peak): below the period, nothing can roll over
        raise ValueError(f"period must be at most floor(peak); got period={period}, peak={peak}")
    lo, hi = float(image.min()), float(image.max())
    x = (image - lo) / (hi - lo) if hi > lo else torch.zeros_like(image)

    def counts(e: float) -> torch.Tensor:
        return torch.floor(torch.clamp(x * e, 0.0, 1.0) * peak)

    def rolled(e: float) -> float:
        return float((counts(e) >= period).any(dim=0).double().mean())

    e_lo, e_hi = 1e-6, 1.0
    while rolled(e_hi) < share and e_hi < 2.0**40:
        e_lo, e_hi = e_hi, e_hi * 2
    reached = rolled(e_hi)
    if reached < share:  # too few distinct bright values: every lit pixel is saturated, and still short
        warnings.warn(
            f"at most {reached:.3f} of the pixels can roll over (protocol B asks for {share}): the counts are "
            "those of the largest exposure tried, every pixel above the minimum saturated",
            UserWarning,
            stacklevel=2,
        )
        return counts(e_hi)
    for _ in range(60):
        mid = math.sqrt(e_lo * e_hi)
        if rolled(mid) < share:
            e_lo = mid
        else:
            e_hi = mid
    return counts(e_hi)


def protocol_counts(image: torch.Tensor, protocol: str) -> torch.Tensor:
    """The true counts of protocol ``"A"``, ``"A10"`` or ``"B"`` (8-bit modulus: period 256) for a (C, H, W) scene.

    Example:
        >>> protocol_counts(torch.full((3, 1, 2), 2.0), "A10").tolist()
        [[[1023.0, 1023.0]]]
    """
    protocol = check_choice(protocol, "protocol", PROTOCOL_PEAKS)
    if protocol == "B":
        return protocol_b(image, peak=PROTOCOL_PEAKS["B"])
    return protocol_a(image, peak=PROTOCOL_PEAKS[protocol])


def protocol_n_levels(image: torch.Tensor) -> tuple[float, float]:
    """Protocol N's reference levels of a radiance map: the 0.1th percentile of its positive values, and its maximum.

    Raises:
        TypeError: the image is not a floating tensor.
        ValueError: the image has NaN or infinite values, or no positive value (negative values are ignored).

    Example:
        >>> protocol_n_levels(torch.tensor([0.0, 1.0, 2.0, 4.0]))
        (1.002, 4.0)
    """
    check_floating(image, "image")
    check_finite(image, "image")
    positive = image[image > 0].double()
    if not positive.numel():
        raise ValueError(
            f"the image is black (maximum {float(image.max()) if image.numel() else 0.0}): nothing to scale"
        )
    sample = positive[:: max(1, positive.numel() // 4_000_000)]  # torch.quantile takes at most 2^24 values
    return float(torch.quantile(sample, 0.001)), float(positive.max())


def protocol_n(image: torch.Tensor) -> tuple[float, int]:
    """Protocol N's scaling of a radiance map: ``(scale, stops)``.

    ``scale`` makes the 0.1th percentile of the positive values read 16 counts at exposure 1 (the longest
    exposure); the scene then needs ``stops = ceil(log2(max / that percentile) + 4)``.

    Example:
        >>> scale, stops = protocol_n(torch.exp2(torch.linspace(0.0, 12.0, 1000)))   # 12 stops
        >>> round(scale, 3), stops
        (15.867, 16)
    """
    low, peak = protocol_n_levels(image)
    return 16.0 / low, math.ceil(math.log2(peak / low) + 4)


# --------------------------------------------------------------------------------------------------------------------
# scores
# --------------------------------------------------------------------------------------------------------------------

#: The thirds of a scene's radiance (by rank) that :func:`protocol_n_scores` reports a median for.
RADIANCE_BANDS = ("dark", "mid", "bright")


def protocol_n_scores(estimate: torch.Tensor, truth: torch.Tensor) -> dict[str, float]:
    """Protocol N's scores of a radiance estimate, over the values whose true radiance is positive: ``median`` and
    ``p99`` of the relative error, ``gross`` (the share more than 50% off) and the median in each third of the
    scene's radiance by rank (:data:`RADIANCE_BANDS`; NaN for an empty third).

    Example:
        >>> truth = torch.tensor([1.0, 2.0, 4.0, 0.0])
        >>> protocol_n_scores(truth * 1.1, truth)["gross"], protocol_n_scores(truth * 2.0, truth)["gross"]
        (0.0, 1.0)
    """
    mask = truth > 0
    values = truth[mask]
    rel = ((estimate[mask] - values).abs() / values).float()
    out = {
        "median": float(rel.median()),
        "p99": float(torch.quantile(rel[:: max(1, rel.numel() // 4_000_000)], 0.99)),
        "gross": float((rel > 0.5).double().mean()),
    }
    order = torch.argsort(values)
    for name, part in zip(RADIANCE_BANDS, torch.tensor_split(order, 3), strict=True):
        out[name] = float(rel[part].median()) if part.numel() else float("nan")
    return out


class SceneScore(NamedTuple):
    """The scores of one restored scene (see :func:`score_scene`)."""

    #: Share of values whose rollover count is right, after aligning each channel's offset.
    exact_k: float
    #: The same share over the values whose true rollover count is above 0; NaN when none is.
    rolled_over_right: float
    #: PSNR of the aligned counts against the truth, in dB (+inf when they are identical).
    psnr: float


def _rollover_differences(restored: torch.Tensor, truth: torch.Tensor, bits: int) -> tuple[torch.Tensor, int]:
    """Checked ``k_restored - k_truth`` as (planes, H * W) float64, and the period ``2^bits``."""
    check_floating(restored, "restored")
    check_floating(truth, "truth")
    check_image_shape(restored, "restored", min_dims=2)
    if restored.shape != truth.shape:
        raise ValueError(
            f"restored and truth must have the same shape; got {tuple(restored.shape)} and {tuple(truth.shape)}"
        )
    if restored.numel() == 0:
        raise ValueError(f"restored and truth must hold values; got shape {tuple(restored.shape)}")
    check_finite(restored, "restored")
    check_finite(truth, "truth")
    period = 2 ** check_int(bits, "bits", 1, 52)
    h, w = restored.shape[-2:]
    k_r = torch.floor(restored.detach().double() / period).reshape(-1, h * w)
    k_t = torch.floor(truth.detach().double() / period).reshape(-1, h * w).to(k_r.device)
    return k_r - k_t, period


def _plane_offsets(d: torch.Tensor) -> torch.Tensor:
    """The most common value of each row of ``d`` (ties: the smallest), (planes,)."""
    offsets = torch.empty(d.shape[0], dtype=d.dtype, device=d.device)
    for i, row in enumerate(d):
        values, counts = torch.unique(row, return_counts=True)  # sorted: argmax picks the smallest tied mode
        offsets[i] = values[counts.argmax()]
    return offsets


def align_offsets(restored: torch.Tensor, truth: torch.Tensor, bits: int = 8) -> torch.Tensor:
    """``restored`` with each channel shifted by whole periods so that its most common rollover count matches.

    Single-shot unwrapping recovers the rollover count ``k = floor(I / 2^bits)`` up to a constant per channel; the
    constant is the most common difference ``k_restored - k_truth`` over the channel (ties go to the smallest), as
    in :func:`torch_modulo.exact_k_map`.

    Args:
        restored: restored counts, (..., H, W); every (H, W) plane is a channel.
        truth: the true counts, same shape.
        bits: sensor bit depth ``N``; the period is ``2^N``.

    Returns:
        The shifted counts, shape and dtype of ``restored``.

    Raises:
        TypeError: an input is not a floating tensor, or ``bits`` is not an integer.
        ValueError: shapes differ, an input is empty or not finite, or ``bits`` is out of [1, 52].

    Example:
        >>> truth = torch.tensor([[10.0, 300.0], [600.0, 20.0]])
        >>> align_offsets(truth + torch.tensor([[512.0, 512.0], [0.0, 512.0]]), truth)
        tensor([[ 10., 300.],
                [ 88.,  20.]])
    """
    d, period = _rollover_differences(restored, truth, bits)
    shift = (_plane_offsets(d) * period).to(restored.device, restored.dtype)
    planes = restored.reshape(d.shape[0], -1) - shift[:, None]
    return planes.reshape(restored.shape)


def rolled_over_right(restored: torch.Tensor, truth: torch.Tensor, bits: int = 8) -> float:
    """Share of the values that roll over (true ``k > 0``) whose aligned rollover count is right; NaN if none do.

    What a modulo camera exists for: a method that unwraps nothing scores 0 here, however high its exact-k.

    Args:
        restored: restored counts, (..., H, W); every (H, W) plane is aligned on its own (:func:`align_offsets`).
        truth: the true counts, same shape.
        bits: sensor bit depth ``N``; the period is ``2^N``.

    Example:
        >>> truth = torch.tensor([[10.0, 300.0, 600.0, 20.0]])
        >>> rolled_over_right(torch.tensor([[10.0, 300.0, 344.0, 20.0]]), truth)
        0.5
        >>> rolled_over_right(torch.remainder(truth, 256), truth)
        0.0
    """
    return score_scene(restored, truth, bits).rolled_over_right


def score_scene(restored: torch.Tensor, truth: torch.Tensor, bits: int = 8, peak: float = 4095.0) -> SceneScore:
    """Exact-k, rolled-over right and PSNR of one restored scene against its true counts.

    Args:
        restored: restored counts, (..., H, W); every (H, W) plane is aligned on its own (:func:`align_offsets`).
        truth: the true counts, same shape.
        bits: sensor bit depth ``N``; the period is ``2^N``.
        peak: the PSNR peak (the protocol's largest count, :data:`PROTOCOL_PEAKS`).

    Returns:
        A :class:`SceneScore` of Python floats.

    Example:
        >>> truth = torch.tensor([[10.0, 300.0], [600.0, 20.0]])
        >>> score = score_scene(truth + 256 * torch.tensor([[1.0, 1.0], [0.0, 1.0]]), truth)
        >>> score.exact_k, score.rolled_over_right, round(score.psnr, 2)
        (0.75, 0.5, 30.1)
    """
    d, period = _rollover_differences(restored, truth, bits)
    peak = check_real(peak, "peak", positive=True)
    offsets = _plane_offsets(d)
    ok = d == offsets[:, None]
    rolled = (truth.detach().double() >= period).reshape(ok.shape).to(ok.device)
    n_rolled = int(rolled.sum())
    aligned = restored.detach().double().reshape(d.shape) - (offsets * period)[:, None]
    mse = float((aligned - truth.detach().double().reshape(d.shape).to(aligned.device)).square().mean())
    return SceneScore(
        exact_k=float(ok.double().mean()),
        rolled_over_right=float(ok[rolled].double().mean()) if n_rolled else math.nan,
        psnr=math.inf if mse == 0 else 10.0 * math.log10(peak * peak / mse),
    )


# --------------------------------------------------------------------------------------------------------------------
# methods
# --------------------------------------------------------------------------------------------------------------------


def parse_method(spec: str) -> tuple[str, dict[str, object]]:
    """Split a method specification ``"name:key=value,key=value"`` into the name and its keyword options.

    Values become ``bool`` (``True``/``False``, any case), ``int`` or ``float`` where they read as one, else stay
    strings; spaces around keys and values are dropped.

    Raises:
        ValueError: the name is empty or an option has no ``=``.

    Example:
        >>> parse_method("fast:init=quality,window=0,denoise=0.7")
        ('fast', {'init': 'quality', 'window': 0, 'denoise': 0.7})
        >>> parse_method("guided")
        ('guided', {})
        >>> parse_method("learned: levels=false")
        ('learned', {'levels': False})
    """
    if not isinstance(spec, str):
        raise TypeError(f"spec must be a string; got {spec!r}")
    name, _, rest = spec.partition(":")
    if not name:
        raise ValueError(f"spec must start with a method name; got {spec!r}")
    options: dict[str, object] = {}
    for item in filter(None, (part.strip() for part in rest.split(","))):
        key, sep, value = item.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not key:
            raise ValueError(f"method options must read key=value; got {item!r} in {spec!r}")
        parsed: object = value
        if value.lower() in ("true", "false"):
            parsed = value.lower() == "true"
        else:
            for cast in (int, float):
                try:
                    parsed = cast(value)
                    break
                except ValueError:
                    continue
        options[key] = parsed
    return name, options
