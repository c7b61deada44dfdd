"""The per-file work of the ``torch-modulo`` folder commands, callable from Python: reading radiance files and the
jobs ``simulate``, ``unwrap`` and ``tonemap`` run on each input.

:func:`load_radiance` is the one way radiance files are read (the command line, :class:`torch_modulo.data.HDRFolder`
and the demo use it), with one policy for values a radiance map cannot hold:

- **Negative values** (lossy compression and sensor processing leave small ones) are clamped to 0, always.
- **NaN and infinite values** are replaced by default (``nonfinite="replace"``): NaN and -Inf by 0, +Inf by the
  largest finite value of the image (an overflowed pixel is at least as bright as the brightest one that did
  not overflow). ``nonfinite="raise"`` refuses such a file instead, naming it and how many of each it holds. A
  file with no finite value at all is refused either way: there is nothing to replace them with.

The jobs follow :data:`torch_modulo.batch.JobFunction`: ``job(task, options)`` reads ``task.source`` and writes
``task.outputs`` atomically; they are module-level functions so that worker processes can receive them.
:func:`folder_tasks` lists a command's tasks for an input folder.

Each job imports the operations it runs (sensors, unwrapping, tone mapping) when it runs, so that importing this
module (as :mod:`torch_modulo.data` does) does not import every operation.

Example:
    >>> import tempfile
    >>> from torch_modulo.io import write_image
    >>> with tempfile.TemporaryDirectory() as folder:
    ...     path = write_image(os.path.join(folder, "x.exr"), torch.tensor([[[1.0, -0.5], [float("inf"), 4.0]]]))
    ...     image, counts = load_radiance(path, with_counts=True)
    >>> image.tolist(), counts
    ([[[1.0, 0.0], [4.0, 4.0]]], {'nan': 0, 'posinf': 1, 'neginf': 0, 'negative': 1})
"""

from __future__ import annotations

import hashlib
import inspect
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from torch_modulo._checks import check_choice, check_flag
from torch_modulo.io import read_image

if TYPE_CHECKING:
    from torch_modulo.batch import Task

__all__ = [
    "JOBS",
    "MODULUS_EXTENSIONS",
    "NONFINITE",
    "PRELOAD",
    "RADIANCE_EXTENSIONS",
    "TONEMAP_OPS",
    "count_values",
    "folder_tasks",
    "load_radiance",
    "scene_seed",
    "simulate_job",
    "tonemap_job",
    "tonemap_options",
    "unwrap_job",
]

#: Radiance files ``simulate`` and ``tonemap`` read.
RADIANCE_EXTENSIONS = (".exr", ".hdr", ".pfm", ".tif", ".tiff")
#: Modulus images ``unwrap --single`` reads.
MODULUS_EXTENSIONS = (".exr", ".png", ".tif", ".tiff", ".pfm")
#: Tone-mapping operators ``tonemap`` offers (``torch_modulo.tonemap.tonemap_<op>``).
TONEMAP_OPS = ("histogram", "reinhard", "gamma", "log", "clahe")
#: What :func:`load_radiance` does with NaN and infinite values.
NONFINITE = ("replace", "raise")
#: Modules each command's workers import up front.
PRELOAD = {
    "simulate": ("torch_modulo.io", "torch_modulo.sensors", "torch_modulo.pipeline"),
    "unwrap": ("torch_modulo.io", "torch_modulo.sensors", "torch_modulo.multishot", "torch_modulo.pipeline"),
    "tonemap": ("torch_modulo.io", "torch_modulo.tonemap", "torch_modulo.pipeline"),
}

_CHANNELS = (None, 1, 3, "auto")
_TONEMAP_MODULES = {
    "histogram": "HistogramToneMap",
    "reinhard": "ReinhardToneMap",
    "gamma": "GammaToneMap",
    "log": "LogToneMap",
    "clahe": "ClaheToneMap",
}


# --------------------------------------------------------------------------------------------- radiance


def _used_channels(image: torch.Tensor, channels: int | str | None, source: object) -> torch.Tensor:
    """The channels the result is made of: all (None), or the first one or three."""
    c = image.shape[0]
    if c < 1:
        raise ValueError(f"{source} has no channels")
    if channels is None:
        return image
    return image[:3] if c >= 3 else image[:1]


def _shaped(image: torch.Tensor, channels: int | str | None) -> torch.Tensor:
    """Repeat grey into RGB (``channels=3``) or reduce RGB to luminance (``channels=1``)."""
    c = image.shape[0]
    if channels == 3 and c == 1:
        return image.expand(3, -1, -1).clone()
    if channels == 1 and c == 3:
        from torch_modulo.tonemap import REC709_LUMA

        weights = torch.tensor(REC709_LUMA, dtype=image.dtype).view(3, 1, 1)
        return (image * weights).sum(0, keepdim=True)
    return image


def load_radiance(
    path: str | os.PathLike[str],
    *,
    channels: int | str | None = "auto",
    nonfinite: str = "replace",
    dtype: torch.dtype = torch.float32,
    with_counts: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, dict[str, int]]:
    """Read a radiance file as a (C, H, W) tensor of finite values >= 0 (the policy in the module docstring).

    Args:
        path: an EXR, HDR, PFM or float TIFF file (anything :func:`torch_modulo.io.read_image` reads).
        channels: ``"auto"`` (default): grey files give one channel, colour files their first three (alpha, the
            other views of a multi-view file and extra layers are dropped; of two channels, the first);
            ``3``: RGB (grey repeated); ``1``: luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` (grey as is);
            ``None``: every channel as stored.
        nonfinite: ``"replace"`` (default) or ``"raise"``: what to do with NaN and infinite values.
        dtype: ``torch.float32`` (default) or ``torch.float64``.
        with_counts: also return how many values were replaced or clamped: ``{"nan", "posinf", "neginf",
            "negative"}``.

    Returns:
        The radiance, or ``(radiance, counts)`` with ``with_counts=True``.

    Raises:
        FileNotFoundError, OSError: the file cannot be read (the message names it).
        ValueError: NaN or infinite values with ``nonfinite="raise"``, no finite value at all, no channels, or a
            bad argument.

    Example:
        >>> import tempfile
        >>> from torch_modulo.io import write_image
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = write_image(os.path.join(folder, "x.exr"), torch.tensor([[[1.0, float("nan")]]]))
        ...     try:
        ...         load_radiance(path, nonfinite="raise")
        ...     except ValueError as error:
        ...         print(str(error).split(";")[0].replace(folder, "DIR"))
        DIR/x.exr holds 1 NaN or infinite value (1 NaN, 0 +Inf, 0 -Inf)
    """
    check_choice(channels, "channels", _CHANNELS, what="1, 3, 'auto' or None")
    check_choice(nonfinite, "nonfinite", NONFINITE)
    check_flag(with_counts, "with_counts")
    image = read_image(path, dtype=dtype)
    assert isinstance(image, torch.Tensor)
    image = _used_channels(image, channels, path)
    counts = {
        "nan": int(torch.isnan(image).sum()),
        "posinf": int(torch.isposinf(image).sum()),
        "neginf": int(torch.isneginf(image).sum()),
    }
    bad = counts["nan"] + counts["posinf"] + counts["neginf"]
    if bad:
        what = f"({counts['nan']} NaN, {counts['posinf']} +Inf, {counts['neginf']} -Inf)"
        if bad == image.numel():
            raise ValueError(f"{path} holds no finite value {what}: nothing to replace them with")
        if nonfinite == "raise":
            raise ValueError(
                f"{path} holds {bad} NaN or infinite value{'s' * (bad > 1)} {what}; pass nonfinite='replace' to "
                "replace NaN and -Inf by 0 and +Inf by the largest finite value"
            )
        top = max(float(image[torch.isfinite(image)].max()), 0.0)
        image = torch.nan_to_num(image, nan=0.0, posinf=top, neginf=0.0)
    counts["negative"] = int((image < 0).sum())
    image = _shaped(image.clamp_min(0.0), channels)
    return (image, counts) if with_counts else image


def _replaced(counts: Mapping[str, int]) -> list[str]:
    """A warning for the report when NaN or infinite values were replaced."""
    n = counts["nan"] + counts["posinf"] + counts["neginf"]
    if not n:
        return []
    return [
        f"replaced {n} NaN or infinite value{'s' * (n > 1)} ({counts['nan']} NaN, {counts['posinf']} +Inf, "
        f"{counts['neginf']} -Inf); --nonfinite raise refuses such files"
    ]


# ----------------------------------------------------------------------------------------------- tasks


def count_values(task: Task) -> float:
    """What a task costs when ranks share the work: the number of values (pixels times channels) of its input
    file, or of the image files in its input folder (from the files' headers; 0 for unreadable ones)."""
    import OpenImageIO as oiio

    source = Path(task.source)
    files = [source] if not source.is_dir() else sorted(p for p in source.iterdir() if not p.name.startswith("."))
    total = 0
    for path in files:
        if path.suffix.lower() == ".json" or not path.is_file():
            continue
        image = oiio.ImageInput.open(str(path))
        if image is None:
            oiio.geterror()  # clear the error OpenImageIO keeps for the next caller
            continue
        spec = image.spec()
        total += spec.width * spec.height * spec.nchannels
        image.close()
    return float(total)


def folder_tasks(
    command: str, source: Path, out: Path, *, single: bool = False, confidence: bool = False
) -> tuple[list[Task], str]:
    """The tasks of folder command ``command`` (sorted by input name) and a description of the inputs it wants.

    ``simulate``: every radiance file -> the frame-stack folder ``out/<name>/``; ``tonemap``: every radiance file
    -> ``out/<name>.png``; ``unwrap``: every frame stack (folder with a ``frames.json``) -> ``out/<stack>.exr``,
    or with ``single`` every modulus image -> ``out/<name>.exr`` (and ``out/<name>.confidence.exr`` with
    ``confidence``). Output paths mirror the input's subfolders.

    Raises:
        FileNotFoundError: ``source`` does not exist.
        OSError: a folder cannot be listed.
    """
    from torch_modulo.batch import Task, discover

    def suffix_match(extensions: Sequence[str]) -> Callable[[Path], bool]:
        return lambda p: p.is_file() and p.suffix.lower() in extensions

    if command in ("simulate", "tonemap"):
        found = discover(source, suffix_match(RADIANCE_EXTENSIONS))
        wanted = f"radiance files ({' '.join(RADIANCE_EXTENSIONS)})"
    elif single:
        found = discover(source, suffix_match(MODULUS_EXTENSIONS))
        wanted = f"modulus images ({' '.join(MODULUS_EXTENSIONS)})"
    else:
        found = discover(source, lambda p: p.is_dir() and (p / "frames.json").is_file())
        wanted = "frame stacks (folders with a frames.json manifest)"
    tasks = []
    for name, path in found:
        rel = Path(name)
        if command == "simulate":
            target = out / rel.with_suffix("")
        elif command == "unwrap":
            target = out / (rel.with_suffix(".exr") if single else rel.with_name(rel.name + ".exr"))
        else:
            target = out / rel.with_suffix(".png")
        targets = [target]
        if command == "unwrap" and single and confidence:
            targets.append(target.with_name(f"{target.stem}.confidence.exr"))
        tasks.append(Task(name, str(path), tuple(str(t) for t in targets)))
    return tasks, wanted


# ------------------------------------------------------------------------------------------------ jobs


def scene_seed(seed: int, name: str) -> int:
    """A per-scene seed from the run's seed and the input's name: the same on every worker, rank and rerun.

    Example:
        >>> scene_seed(0, "a.exr") == scene_seed(0, "a.exr") != scene_seed(1, "a.exr")
        True
    """
    return int.from_bytes(hashlib.sha256(f"{seed}:{name}".encode()).digest()[:8], "little") % (2**63)


def simulate_job(task: Task, options: Mapping[str, Any]) -> dict[str, Any]:
    """Job of ``torch-modulo simulate``: one HDR file -> one frame-stack folder (atomic).

    Options: ``bits``, ``exposures``, ``noise`` (:class:`~torch_modulo.sensors.NoiseModel` fields or None),
    ``seed``, ``scale`` (``"auto"`` or a number), ``format``, ``truth`` and, optionally, ``nonfinite``.
    """
    from torch_modulo.batch import atomic_output_dir
    from torch_modulo.io import write_image
    from torch_modulo.sensors import FrameStack, NoiseModel, SimulatedModuloSensor, write_frames

    bits = int(options["bits"])
    taus = [float(t) for t in options["exposures"]]
    nonfinite = options.get("nonfinite", "replace")
    image, counts = load_radiance(task.source, nonfinite=nonfinite, dtype=torch.float64, with_counts=True)
    peak = float(image.max())
    if options["scale"] == "auto":
        if peak <= 0:
            raise ValueError(f"{task.source} is black (maximum {peak}): --scale auto cannot scale it")
        scale = (2**bits - 1) / (peak * min(taus))
    else:
        scale = float(options["scale"])
    # Round to float32 first: radiance.exr (float32) then holds exactly the radiance the frames were captured from.
    radiance = (image * scale).float().double()
    noise = NoiseModel(**options["noise"]) if options["noise"] is not None else None
    seed = scene_seed(int(options["seed"]), task.name)
    stack = SimulatedModuloSensor(bits, noise, seed=seed)(radiance.unsqueeze(0), taus)
    metadata = {
        **stack.metadata,
        "source": task.name,
        "radiance_scale": scale,
        "unit": "counts per unit exposure",
        "bits": bits,
        "exposures": taus,
    }
    dtype = torch.float32 if bits <= 24 else torch.float64
    stack = FrameStack(stack.moduli.to(dtype), stack.exposures, bits, metadata, kind=stack.kind)
    with atomic_output_dir(task.outputs[0]) as folder:
        write_frames(stack, folder, format=options["format"])
        if options["truth"]:
            write_image(
                folder / "radiance.exr",
                radiance.float(),
                {"source": task.name, "radiance_scale": scale, "unit": "counts per unit exposure"},
            )
    info: dict[str, Any] = {
        "shape": list(image.shape),
        "radiance_scale": scale,
        "negatives_clamped": counts["negative"],
    }
    return _with_replaced(info, counts)


def _with_replaced(info: dict[str, Any], counts: Mapping[str, int]) -> dict[str, Any]:
    warnings = _replaced(counts)
    if warnings:
        info["nonfinite_replaced"] = {k: counts[k] for k in ("nan", "posinf", "neginf")}
        info["warnings"] = warnings
    return info


def unwrap_job(task: Task, options: Mapping[str, Any]) -> dict[str, Any]:
    """Job of ``torch-modulo unwrap``: one frame stack (or, single shot, one modulus image) -> one radiance EXR.

    Options: ``single``, ``bits`` (None: from the files), ``exposure`` (single shot; None: from the metadata,
    else 1), ``method`` (the multi-shot rule), ``solver`` (the single-shot method; None: the default),
    ``confidence`` and ``_solver_workers`` (processes of the single-shot solver).
    """
    from torch_modulo.io import write_image

    if options["single"]:
        image, meta = read_image(task.source, with_metadata=True)
        bits = options["bits"]
        if bits is None:
            bits = meta.get("bits", meta.get("bit_depth"))
            if bits is None:
                raise ValueError(f"no bit depth in the metadata of {task.source}: pass --bits")
        exposure = options["exposure"] or meta.get("exposure") or 1.0
        from torch_modulo.singleshot import unwrap_confidence, unwrap_single

        method = {"method": options["solver"]} if options["solver"] is not None else {}
        counts = unwrap_single(image.unsqueeze(0), int(bits), workers=options["_solver_workers"], **method)[0]
        radiance = counts.double() / float(exposure)
        metadata = {
            "source": task.name,
            "bits": int(bits),
            "exposure": float(exposure),
            "method": "single",
            "solver": options["solver"] or "default",
            "unit": "counts per unit exposure",
        }
        if options.get("confidence"):
            confidence = unwrap_confidence(counts.double(), int(bits))
            write_image(task.outputs[1], confidence.float(), {**metadata, "unit": "confidence in [0, 1]"})
    else:
        from torch_modulo.multishot import merge_intensity, unwrap_multi
        from torch_modulo.sensors import FileSensor

        # The frames' own dtype (float32 for stacks from simulate: exact up to 24 bits; unwrap_multi decides in
        # float64 internally, and the EXR stores float32 anyway).
        stack = FileSensor(task.source, bits=options["bits"]).read()
        if stack.batch_size != 1:
            raise ValueError(f"{task.source} holds {stack.batch_size} scenes; unwrap expects one scene per stack")
        if stack.kind == "intensity":
            radiance = merge_intensity(stack.frames, stack.exposures, stack.bits)[0]
            rule = "merge_intensity"
        else:
            radiance = unwrap_multi(stack.moduli, stack.exposures, stack.bits, options["method"])[0]
            rule = options["method"]
        metadata = {
            "source": task.name,
            "bits": stack.bits,
            "exposures": stack.exposure_matrix()[0].tolist(),
            "method": rule,
            "kind": stack.kind,
            "unit": "counts per unit exposure",
        }
        if "radiance_scale" in stack.metadata:
            metadata["radiance_scale"] = stack.metadata["radiance_scale"]
    write_image(task.outputs[0], radiance.float(), metadata)
    return {"shape": list(radiance.shape), "method": metadata["method"]}


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
    """
    from torch_modulo import tonemap
    from torch_modulo.io import write_image

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
