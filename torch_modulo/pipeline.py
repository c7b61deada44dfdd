"""The per-file jobs of the ``torch-modulo`` folder commands, callable from Python: ``simulate``, ``unwrap`` and
``tonemap`` on one input each.

The jobs follow :data:`torch_modulo.batch.JobFunction`: ``job(task, options)`` reads ``task.source`` and writes
``task.outputs`` atomically; they are module-level functions so that worker processes can receive them. They read
radiance with :func:`torch_modulo.radiance.load_radiance` (re-exported here); :func:`torch_modulo.folders.folder_tasks`
lists a command's tasks for an input folder.

How ``simulate`` scales a scene and chooses its exposures (radiance in counts per unit exposure):

- **Planned exposures** (``exposures="auto"``, the command line's default; :func:`plan_scene`): as protocol N of
  the benchmarks, the 0.1th percentile of the scene's positive values reads 16 counts at the longest exposure
  (1), the scene needs ``ceil(log2(max / that percentile) + 4)`` stops, and the exposures are
  :func:`~torch_modulo.plan_exposures` for those stops, the bit depth and the noise model with ``longest=1`` (so
  that dark current is planned at the exposures captured; noise-free: the noise-free plan): by default the plan for
  the decoder with spatial evidence (``spatial=False``: for each pixel alone), which a noisy stack then records for
  ``unwrap``.
- **Given exposures, several** (:func:`fit_scale`): the brightest value reads ``2**bits - 1`` at the shortest
  exposure; under noise, the largest count whose noisy reading, with that exposure's dark counts, stays three
  standard deviations below the rollover. That frame does not roll over, as multi-shot unwrapping needs.
- **Given exposure, one** (a single-shot stack, :func:`fit_scale`): as protocol A of the single-shot benchmarks,
  the 99.9th percentile of the luminance (of all values for grey scenes) reads ``16 * 2**bits - 1`` counts (4095
  at 8 bits: 16 periods), so the frame wraps.

Each job imports the operations it runs (sensors, unwrapping, tone mapping) when it runs, so that importing this
module does not import every operation.

Example:
    >>> options = tonemap_options("log", {})
    >>> sorted(JOBS), options["op"]
    (['simulate', 'tonemap', 'unwrap'], 'log')
"""

from __future__ import annotations

import hashlib
import inspect
import os
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from torch_modulo._checks import check_choice, check_flag
from torch_modulo._scene_rules import (
    colour_scene,
    count_accuracy,
    fit_scale,
    frame_cfa,
    matching_truth,
    noise_model,
    noise_name,
    plan_scene,
    radiance_accuracy,
    restored_colour,
    restored_confidence,
    shrink_scene,
    undecodable_ratio,
    unsafe_ratio_warnings,
)
from torch_modulo._task import Task
from torch_modulo.io import read_image
from torch_modulo.radiance import NONFINITE, RADIANCE_EXTENSIONS, load_radiance
from torch_modulo.sensors.manifest import TRUTH_FILE  # the ground truth simulate writes; unwrap scores against it

if TYPE_CHECKING:
    from torch_modulo.noise import NoiseModel
    from torch_modulo.sensors import FrameStack

__all__ = [
    "DEFAULT_NOISE",
    "JOBS",
    "NONFINITE",
    "PRELOAD",
    "RADIANCE_EXTENSIONS",
    "TONEMAP_OPS",
    "TRUTH_FILE",
    "fit_scale",
    "load_radiance",
    "plan_scene",
    "scene_seed",
    "simulate_job",
    "tonemap_job",
    "tonemap_options",
    "unwrap_job",
]

#: Tone-mapping operators ``tonemap`` offers (``torch_modulo.tonemap.tonemap_<op>``).
TONEMAP_OPS = ("histogram", "reinhard", "gamma", "log", "clahe")
#: The noise model ``simulate`` uses unless told otherwise: the preset that ``SimulatedModuloSensor()`` uses.
DEFAULT_NOISE = "photon-counting"
#: Modules each command's workers import up front.
PRELOAD = {
    "simulate": ("torch_modulo.io", "torch_modulo.sensors", "torch_modulo.pipeline"),
    "unwrap": ("torch_modulo.io", "torch_modulo.sensors", "torch_modulo.multishot", "torch_modulo.pipeline"),
    "tonemap": ("torch_modulo.io", "torch_modulo.tonemap", "torch_modulo.pipeline"),
}

_TONEMAP_MODULES = {
    "histogram": "HistogramToneMap",
    "reinhard": "ReinhardToneMap",
    "gamma": "GammaToneMap",
    "log": "LogToneMap",
    "clahe": "ClaheToneMap",
}


def _replaced(counts: Mapping[str, int]) -> list[str]:
    """A warning for the report when NaN or infinite values were replaced."""
    n = counts["nan"] + counts["posinf"] + counts["neginf"]
    if not n:
        return []
    return [
        f"replaced {n} NaN or infinite value{'s' * (n > 1)} ({counts['nan']} NaN, {counts['posinf']} +Inf, "
        f"{counts['neginf']} -Inf); --nonfinite raise refuses such files"
    ]


# ------------------------------------------------------------------------------------------------ jobs


def scene_seed(seed: int, name: str) -> int:
    """A per-scene seed from the run's seed and the input's name: the same on every worker, rank and rerun.

    Example:
        >>> scene_seed(0, "a.exr") == scene_seed(0, "a.exr") != scene_seed(1, "a.exr")
        True
    """
    return int.from_bytes(hashlib.sha256(f"{seed}:{name}".encode()).digest()[:8], "little") % (2**63)


def _spatial_plan(options: Mapping[str, Any], noise: NoiseModel | None) -> tuple[bool, list[str]]:
    """Whether :func:`simulate_job` plans for the decoder with spatial evidence (option ``spatial``, default True),
    and a note where it was asked for and there is no noise to plan for."""
    spatial = check_flag(options.get("spatial", True), "spatial")
    if spatial and (noise is None or noise.is_noiseless):  # without noise every ratio up to 2^bits - 1 decodes
        note = "spatial: no noise model, so the noise-free plan (spatial evidence is noise-aware decoding)"
        return False, [note] if "spatial" in options else []
    return spatial, []


def simulate_job(task: Task, options: Mapping[str, Any]) -> dict[str, Any]:
    """Job of ``torch-modulo simulate``: one HDR file -> one frame-stack folder (atomic).

    Options: ``bits``, ``exposures`` (``"auto"``: :func:`plan_scene`; or a list), ``noise`` (None, a preset name
    or :class:`~torch_modulo.sensors.NoiseModel` fields), ``seed``, ``scale`` (``"auto"`` or a number),
    ``format``, ``truth`` and, optionally, ``nonfinite``, ``cfa``, ``linear``, ``force_exposures``, ``max_side``,
    ``crop``, ``spatial`` and ``longest_frames``. The scaling rules are in the module docstring.

    ``spatial`` (with a noise model; default True): plan for the decoder with spatial evidence (about half the
    frames of the per-pixel plan; given exposures are checked against its safe ratio instead), or with False for
    each pixel decoded alone; a noisy stack records which in its metadata (``"spatial"``), so that
    :func:`unwrap_job` decodes it that way. ``longest_frames`` (an int >= 1, with ``"auto"`` exposures):
    the plan's longest exposure taken that many times (under noise the repeats collect light).

    ``max_side`` (an int) shrinks the scene first by area averaging, by the smallest integer factor that brings its
    longer side to at most that (:func:`torch_modulo.protocols.downsample_area`, as the benchmarks do); ``crop``
    ((height, width)) then keeps its centre; a scene smaller than the crop is refused, naming it.

    Given exposures with two neighbours more than ``2**bits`` apart, which rollover counting cannot decode, are
    refused before anything is written, unless ``force_exposures`` is True (the report then warns).

    A display-referred input (an 8/16-bit PNG or TIFF: a photo's sRGB-encoded integers) is refused, naming it,
    unless ``linear`` is True (the caller says its integers are linear radiance, as a raw camera export's are).

    With ``cfa`` (``"RGGB"``, ``"BGGR"``, ``"GRBG"`` or ``"GBRG"``) the sensor is a colour sensor: the frames are
    mosaics (1, H, W) with the pattern in the stack's metadata, and the truth stays RGB. A scene that is not RGB is
    refused; an odd height or width loses its last row or column (noted in the report).
    """
    from torch_modulo._atomic import replace_folder
    from torch_modulo.io import write_image
    from torch_modulo.sensors import FrameStack, SimulatedModuloSensor, stack_files, write_frames

    bits = int(options["bits"])
    nonfinite = options.get("nonfinite", "replace")
    noise = noise_model(options["noise"])
    spatial, notes = _spatial_plan(options, noise)
    if options["exposures"] != "auto" and (too_far := undecodable_ratio(options["exposures"], bits)):
        if not check_flag(options.get("force_exposures", False), "force_exposures"):
            raise ValueError(
                f"{too_far}: unwrap cannot count the rollovers between them, so nothing was written; choose "
                "exposures at most 2^bits apart, --exposures auto, or force_exposures=True (--force-exposures)"
            )
        notes.append(f"{too_far}: unwrap cannot count the rollovers between them (written as forced)")
    linear = check_flag(options.get("linear", False), "linear")  # display-referred files are refused unless True
    image, counts = load_radiance(
        task.source, nonfinite=nonfinite, dtype=torch.float64, with_counts=True, linear=linear
    )
    if not float(image.max()) > 0:
        raise ValueError(f"{task.source} is black (maximum {float(image.max())}): there is nothing to capture")
    image, facts = shrink_scene(image, options.get("max_side"), options.get("crop"), task.source)
    cfa = options.get("cfa")
    if cfa is not None:
        image, cropped = colour_scene(image, cfa, task.source)
        notes += cropped
        facts["cfa"] = cfa
    if options["exposures"] == "auto":
        repeats = options.get("longest_frames", 1)  # plan_exposures checks it
        plan = plan_scene(image, bits, noise, scale=options["scale"], spatial=spatial, longest_frames=repeats)
        taus, scale, facts["stops"] = plan
        facts["scaling"] = "auto exposures (protocol N)"
    else:
        taus = [float(t) for t in options["exposures"]]
        fixed = options["scale"] != "auto"
        scale = float(options["scale"]) if fixed else fit_scale(image, bits, taus, noise)
        facts["scaling"] = "fixed" if fixed else ("single shot (protocol A)" if len(taus) == 1 else "below rollover")
        notes += unsafe_ratio_warnings(taus, bits, noise, image, spatial=spatial)
    # The noisy plan records the decoder it is for (with spatial evidence or each pixel alone), so unwrap decodes it
    # so (one frame has nothing to decode).
    recorded = {"spatial": spatial} if noise is not None and not noise.is_noiseless and len(taus) > 1 else {}
    # Round to float32 first: radiance.exr (float32) then holds exactly the radiance the frames were captured from.
    radiance = (image * scale).float().double()
    seed = scene_seed(int(options["seed"]), task.name)
    stack = SimulatedModuloSensor(bits, noise, seed=seed, cfa=cfa)(radiance.unsqueeze(0), taus)
    metadata = {
        **stack.metadata,
        "source": task.name,
        "radiance_scale": scale,
        "unit": "counts per unit exposure",
        "bits": bits,
        "exposures": taus,
        **facts,
        **recorded,
    }
    dtype = torch.float32 if bits <= 24 else torch.float64
    stack = FrameStack(stack.moduli.to(dtype), stack.exposures, bits, metadata, kind=stack.kind, cfa=stack.cfa)

    def build(folder: Path) -> None:
        write_frames(stack, folder, format=options["format"])
        if options["truth"]:
            write_image(
                folder / TRUTH_FILE,
                radiance.float(),
                {"source": task.name, "radiance_scale": scale, "unit": "counts per unit exposure"},
            )

    # Swapped in whole; a previous stack's files (and truth) are replaced, anything else in the folder is kept.
    final = Path(task.outputs[0])
    replace_folder(final, build, stack_files(final) | {TRUTH_FILE})
    info: dict[str, Any] = {
        "shape": list(image.shape),
        "radiance_scale": scale,
        "exposures": taus,
        "noise": noise_name(noise),
        **facts,
        **recorded,
        "negatives_clamped": counts["negative"],
    }
    info = _with_replaced(info, counts)
    if notes:
        info["warnings"] = info.get("warnings", []) + notes
    return info


def _with_replaced(info: dict[str, Any], counts: Mapping[str, int]) -> dict[str, Any]:
    lines = _replaced(counts)
    if lines:
        info["nonfinite_replaced"] = {k: counts[k] for k in ("nan", "posinf", "neginf")}
        info["warnings"] = lines
    return info


def _read_stack(source: str, bits: int | None) -> FrameStack:
    """The one-scene frame stack in folder ``source``."""
    from torch_modulo.sensors import FileSensor

    # The frames' own dtype (float32 for stacks from simulate: exact up to 24 bits).
    stack = FileSensor(source, bits=bits).read()
    if stack.batch_size != 1:
        raise ValueError(f"{source} holds {stack.batch_size} scenes; unwrap expects one scene per stack")
    return stack


def _truth(folder: str | os.PathLike[str]) -> torch.Tensor | None:
    """The stack's stored ground truth (float64), or None when it is absent (see :func:`matching_truth`)."""
    path = Path(folder) / TRUTH_FILE
    return read_image(path, dtype=torch.float64) if path.is_file() else None


def _unwrap_stack(task: Task, options: Mapping[str, Any]) -> tuple[torch.Tensor, dict[str, Any], dict[str, Any]]:
    """Multi shot: rollover counting (noise-aware with a noise model) or the merge of an intensity stack; mosaics
    are unwrapped per photosite, then demosaiced."""
    from torch_modulo.multishot import merge_intensity, unwrap_multi

    stack = _read_stack(task.source, options["bits"])
    if stack.kind == "modulo" and stack.num_exposures == 1:  # counting needs two frames: it would return I_m / tau
        raise ValueError(
            f"{task.source} holds one modulo frame; rollover counting needs several: unwrap it with --single"
        )
    cfa = frame_cfa(options.get("cfa"), stack.cfa, task.source, stack.moduli.shape[-3:])
    choice = options.get("noise", "stack")
    noise = noise_model(stack.metadata.get("noise") if choice == "stack" else choice)
    if noise is not None and noise.is_noiseless:
        noise = None  # every term off: the sensor read floor(tau E), which the noise-free rule decodes exactly
    notes: list[str] = []
    rule = options["method"]
    spatial = False
    if stack.kind == "intensity":
        radiance = merge_intensity(stack.frames, stack.exposures, stack.bits, noise=noise)[0]
        rule = "merge_intensity"
        if options.get("spatial"):
            notes.append("spatial evidence is for modulo stacks: this intensity stack was merged as it is")
    else:
        if noise is not None and rule == "paper":
            notes.append(
                "--method paper decodes Eqs. 6-7 as printed and takes no noise model: the stack's noise model "
                f"({noise_name(noise)}) was not used; --method robust decodes with it"
            )
            noise = None
        choice = options.get("spatial")  # None: as the stack was planned (spatial where it records nothing)
        spatial = check_flag(stack.metadata.get("spatial", True) if choice is None else choice, "spatial")
        if spatial and noise is None:
            if choice or stack.metadata.get("spatial"):  # asked for, or planned for, not the default alone
                notes.append("spatial evidence is noise-aware decoding, and no noise model is used: decoded noise-free")
            spatial = False
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            radiance = unwrap_multi(
                stack.moduli, stack.exposures, stack.bits, rule, noise=noise, spatial=spatial, cfa=cfa
            )[0]
        notes += [str(w.message) for w in caught]
    recorded = {"spatial": spatial} if noise is not None and stack.kind != "intensity" else {}
    radiance, colour = restored_colour(radiance, cfa, demosaic=options.get("demosaic", True))
    metadata = {
        "source": task.name,
        "bits": stack.bits,
        "exposures": stack.exposure_matrix()[0].tolist(),
        "method": rule,
        "noise": noise.to_dict() if noise is not None else None,
        **recorded,
        "kind": stack.kind,
        "unit": "counts per unit exposure",
        **colour,
    }
    if "radiance_scale" in stack.metadata:
        metadata["radiance_scale"] = stack.metadata["radiance_scale"]
    info: dict[str, Any] = {"noise": noise_name(noise), **recorded}
    truth = matching_truth(_truth(task.source), radiance.shape, cfa)
    if truth is not None:
        info["accuracy"] = radiance_accuracy(radiance, truth)
    if notes:
        info["warnings"] = notes
    return radiance, metadata, info


def _single_frame(
    task: Task, options: Mapping[str, Any]
) -> tuple[torch.Tensor, int, float, torch.Tensor | None, str | None]:
    """The modulus image ``unwrap --single`` unwraps, its bit depth, exposure, stored truth (or None) and colour
    filter array (or None)."""
    if Path(task.source).is_dir():  # a frame stack of one exposure, as `simulate --exposures T` writes
        stack = _read_stack(task.source, options["bits"])
        if stack.num_exposures != 1 or stack.kind != "modulo":
            raise ValueError(
                f"{task.source} holds {stack.num_exposures} {stack.kind} frames; --single unwraps one modulo frame: "
                "unwrap this stack without --single, or simulate a single-shot stack with one exposure "
                "(e.g. --exposures 1)"
            )
        image = stack.moduli[0, 0]
        exposure = float(stack.exposure_matrix()[0, 0])
        cfa = frame_cfa(options.get("cfa"), stack.cfa, task.source, image.shape)
        return image, stack.bits, exposure, _truth(task.source), cfa
    from torch_modulo.sensors import frame_bits, frame_exposure

    image, meta = read_image(task.source, with_metadata=True)
    where = f"the metadata of {task.source}"  # read as FileSensor reads a frame's: checked, never coerced
    bits = options["bits"]
    if bits is None:
        bits = frame_bits(meta, where)
        if bits is None:
            raise ValueError(f"no bit depth in the metadata of {task.source}: pass --bits")
    exposure = options["exposure"]
    if exposure is None:
        stored = frame_exposure(meta, where)
        exposure = 1.0 if stored is None else stored
    cfa = frame_cfa(options.get("cfa"), meta.get("cfa"), task.source, image.shape)
    return image, int(bits), float(exposure), None, cfa


def _unwrap_single_job(task: Task, options: Mapping[str, Any]) -> tuple[torch.Tensor, dict[str, Any], dict[str, Any]]:
    from torch_modulo.folders import CONFIDENCE_UNIT
    from torch_modulo.io import write_image
    from torch_modulo.metrics import psnr
    from torch_modulo.singleshot import unwrap_single

    image, bits, exposure, truth, cfa = _single_frame(task, options)
    method = {"method": options["solver"]} if options["solver"] is not None else {}
    counts, solved = unwrap_single(
        image.unsqueeze(0),
        bits,
        workers=options["_solver_workers"],
        cfa=cfa,
        return_info=True,
        **method,
        **options.get("solver_options", {}),
    )
    counts = counts[0]
    radiance, colour = restored_colour(counts.double() / exposure, cfa, demosaic=options.get("demosaic", True))
    metadata = {
        "source": task.name,
        "bits": bits,
        "exposure": exposure,
        "method": "single",
        "solver": options["solver"] or "default",
        **({"solver_options": options["solver_options"]} if options.get("solver_options") else {}),
        **({"learned_version": options["learned_version"]} if options.get("learned_version") else {}),
        "unit": "counts per unit exposure",
        **colour,
    }
    if options.get("confidence"):
        if solved.confidence is not None and cfa is None:  # the learned method's own, from the same run
            confidence = solved.confidence[0]
        else:
            confidence = restored_confidence(counts.double(), bits, cfa)
        write_image(task.outputs[1], confidence.float(), {**metadata, "unit": CONFIDENCE_UNIT})
    info: dict[str, Any] = {}
    counts_truth = matching_truth(truth, counts.shape, cfa)
    if counts_truth is not None:
        scored = [counts, image, counts_truth]
        if cfa is not None:  # at the photosites, each colour plane with its own global offset (as each channel)
            from torch_modulo.cfa import split_planes

            scored = [split_planes(x) for x in scored]
        info["accuracy"] = count_accuracy(scored[0], scored[1], scored[2], exposure, bits)
        if cfa is not None and truth is not None and radiance.shape == truth.shape and radiance.shape[0] == 3:
            peak = max(float(truth.max()), 1.0 / exposure)
            info["accuracy"]["colour_psnr_db"] = float(psnr(radiance, truth, peak=peak)[0])
    return radiance, metadata, info


def unwrap_job(task: Task, options: Mapping[str, Any]) -> dict[str, Any]:
    """Job of ``torch-modulo unwrap``: one frame stack (or, single shot, one modulus image) -> one radiance EXR.

    Options: ``single``, ``bits`` (None: from the files), ``exposure`` (single shot, loose images; None: from the
    metadata, else 1), ``method`` (the multi-shot rule), ``noise`` (multi shot: ``"stack"``, the default, decodes
    with the noise model recorded in the stack's metadata, noise-free where there is none; None: noise-free; or a
    preset name or :class:`~torch_modulo.sensors.NoiseModel` fields), ``solver`` (the single-shot method; None:
    the default), ``confidence``, ``_solver_workers`` (processes of the single-shot solver) and, optionally,
    ``solver_options`` (keyword options of the method, JSON values), ``learned_version`` (recorded in the metadata;
    it keeps outputs of an earlier ``"learned"`` from counting as complete), ``cfa``, ``demosaic`` and ``spatial``
    (multi shot with a noise model: True decodes with spatial evidence, ``unwrap_multi``'s default, a mosaic's colour
    planes apart; False each pixel alone; None or absent: as the stack's metadata records (``"spatial"``, as
    ``simulate_job`` writes it for its plan), with spatial evidence where it records nothing).

    With ``single``, the input is a modulus image or a frame stack of one exposure (as ``simulate`` writes it).
    Where a stack holds its ground truth (:data:`TRUTH_FILE`), the result is scored against it: single shot by
    the share of exact rollover counts and the PSNR of the counts (:func:`torch_modulo.metrics.exact_k_share`,
    :func:`torch_modulo.metrics.psnr`), multi shot by the median relative error and the share of values more
    than 50% off. The scores and the decoder's warnings are in the returned info (the report).

    Mosaics of a colour sensor: the pattern is the stack's (:attr:`~torch_modulo.sensors.FrameStack.cfa`) or the
    image's metadata's, or the option ``cfa`` (a pattern that disagrees with the recorded one is refused). The
    mosaic is unwrapped (multi shot per photosite, single shot with ``unwrap_single(..., cfa=...)``), then
    demosaiced (:func:`torch_modulo.cfa.demosaic`) to RGB radiance (3, H, W); with ``demosaic`` False the
    restored mosaic (1, H, W) is written instead. Single shot scores the rollover counts at the photosites
    (against the mosaicked truth, each of the four colour planes with its own global offset, as the channels of an
    RGB image) and adds ``colour_psnr_db``, the PSNR of the demosaiced radiance against the RGB truth; multi shot
    scores what it writes, RGB against the RGB truth (a mosaic against the mosaicked truth).
    """
    from torch_modulo.io import write_image

    job = _unwrap_single_job if options["single"] else _unwrap_stack
    radiance, metadata, info = job(task, options)
    write_image(task.outputs[0], radiance.float(), metadata)
    colour = {"cfa": metadata["cfa"]} if "cfa" in metadata else {}
    return {"shape": list(radiance.shape), "method": metadata["method"], **colour, **info}


def _tuples(params: Mapping[str, Any]) -> dict[str, Any]:
    """JSON keeps tuples as lists; the tone-mapping functions want tuples (``grid_size=(8, 8)``)."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in params.items()}


def tonemap_options(op: str, params: Mapping[str, Any], *, srgb: bool = False, depth: int = 8) -> dict[str, Any]:
    """The options of :func:`tonemap_job`, checked before any file is read.

    Args:
        op: one of :data:`TONEMAP_OPS`.
        params: keyword arguments of ``torch_modulo.tonemap.tonemap_<op>`` (JSON values: lists for tuples).
        srgb: apply the sRGB transfer function.
        depth: PNG bits per sample, 8 or 16.

    Raises:
        ValueError, TypeError: an unknown operator or parameter, or a value the operator refuses.

    Example:
        >>> tonemap_options("reinhard", {"key": 0.36})
        {'op': 'reinhard', 'params': {'key': 0.36}, 'srgb': False, 'depth': 8}
    """
    from torch_modulo import tonemap

    check_choice(op, "op", TONEMAP_OPS)
    check_flag(srgb, "srgb")
    check_choice(depth, "depth", (8, 16))
    function = getattr(tonemap, f"tonemap_{op}")
    allowed = [p for p in inspect.signature(function).parameters if p not in ("hdr", "srgb")]
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        raise ValueError(f"tonemap_{op} has no parameter {unknown[0]!r}; its parameters are {', '.join(allowed)}")
    getattr(tonemap, _TONEMAP_MODULES[op])(**_tuples(params), srgb=srgb)  # the module twin checks the values
    return {"op": op, "params": dict(params), "srgb": srgb, "depth": depth}


def tonemap_job(task: Task, options: Mapping[str, Any]) -> dict[str, Any]:
    """Job of ``torch-modulo tonemap``: one radiance file -> one PNG.

    Options: ``op`` (one of :data:`TONEMAP_OPS`), ``params`` (the operator's keyword arguments), ``srgb``,
    ``depth`` (8 or 16 bits) and, optionally, ``nonfinite``.

    A file whose own record says it is not radiance (a frame of a modulo camera, a confidence map:
    :func:`torch_modulo.folders.not_radiance`) is refused; the command line skips such files and reports them.
    """
    from torch_modulo import tonemap
    from torch_modulo.folders import not_radiance
    from torch_modulo.io import write_image

    reason = not_radiance(task.source)
    if reason is not None:
        raise ValueError(f"{task.source} is not radiance: {reason}")

    hdr, counts = load_radiance(task.source, nonfinite=options.get("nonfinite", "replace"), with_counts=True)
    operator = getattr(tonemap, f"tonemap_{options['op']}")
    display = operator(hdr.unsqueeze(0), **_tuples(options["params"]), srgb=options["srgb"])[0]
    metadata = {"source": task.name, "op": options["op"], "params": options["params"], "srgb": options["srgb"]}
    write_image(task.outputs[0], display, metadata, dtype=f"uint{options['depth']}", normalized=True)
    return _with_replaced({"shape": list(hdr.shape)}, counts)


#: The job of each folder command.
JOBS: dict[str, Callable[[Task, Mapping[str, Any]], dict[str, Any]]] = {
    "simulate": simulate_job,
    "unwrap": unwrap_job,
    "tonemap": tonemap_job,
}


#: Names that moved to :mod:`torch_modulo.folders` with the command line's listing of a folder's tasks.
_MOVED = ("MODULUS_EXTENSIONS", "count_values", "folder_tasks")


def __getattr__(name: str) -> Any:
    if name in _MOVED:
        warnings.warn(
            f"torch_modulo.pipeline.{name} is deprecated; use torch_modulo.folders.{name}",
            DeprecationWarning,
            stacklevel=2,
        )
        from torch_modulo import folders

        return getattr(folders, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
