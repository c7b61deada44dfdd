"""The records of a folder of frames that :class:`~torch_modulo.sensors.FileSensor` reads: the manifest
``frames.json``, the JSON sidecars and the frames' own metadata, each value checked as it is read.

The manifest describes the frames; it never overrides what they record. Where the manifest and a frame's own
record (its sidecar, else its metadata) both give the bit depth, the exposure or the colour filter array, they must
agree; a value the manifest may not hold (a ``"dtype"`` other than a floating one) is refused; a frame missing from
the stack is named by its exposure. Each error names the manifest and the other side.

Example:
    >>> frame_bits({"bit_depth": 12}, "a.png"), describe_exposure([1.0, 16.0])
    (12, '[1, 16]')
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import torch

from torch_modulo._checks import check_bits, check_choice, check_int, check_real
from torch_modulo.cfa import check_cfa
from torch_modulo.sensors.frames import KINDS

__all__ = [
    "DTYPES",
    "MANIFEST",
    "Frame",
    "bits_value",
    "check_manifest_cfa",
    "check_manifest_shape",
    "describe_exposure",
    "first_value",
    "frame_bits",
    "frame_exposure",
    "frame_record",
    "from_source",
    "inside",
    "load_json",
    "place_frames",
    "positive_value",
    "read_manifest",
    "sidecar",
    "stored_exposures",
]

#: The folder manifest :func:`~torch_modulo.sensors.write_frames` writes and :class:`FileSensor` reads first.
MANIFEST = "frames.json"
#: The ground truth ``torch-modulo simulate`` writes into each frame stack beside its frames (radiance, not a frame).
TRUTH_FILE = "radiance.exr"
#: The dtypes a manifest's ``"dtype"`` may name.
DTYPES = {"float16": torch.float16, "bfloat16": torch.bfloat16, "float32": torch.float32, "float64": torch.float64}
_EXPOSURE_KEYS = ("exposure", "exposure_time", "ExposureTime")
_BITS_KEYS = ("bits", "bit_depth")
_T = TypeVar("_T")
#: How far a manifest's exposure may be from a frame's own record and still agree (float32 attributes round).
_EXPOSURE_TOLERANCE = 1e-6


def load_json(path: Path) -> dict[str, Any]:
    """The JSON object in ``path`` (a manifest or a sidecar); an unreadable file, bad JSON or another value is
    refused."""
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise OSError(f"cannot read {path}: {exc}") from exc
    except ValueError as exc:
        raise ValueError(f"{path} is not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise ValueError(f"{path} must hold a JSON object; got {type(data).__name__}")
    return data


def first_value(mapping: Mapping[str, Any], keys: Sequence[str]) -> Any:
    """The value of the first of ``keys`` that ``mapping`` holds (and is not None), else None."""
    for key in keys:
        if key in mapping and mapping[key] is not None:
            return mapping[key]
    return None


def from_source(check: Callable[..., _T], value: Any, *args: Any, **kwargs: Any) -> _T:
    """Run a scalar check on a value read from a file or given for one: any failure is a ``ValueError``."""
    try:
        return check(value, *args, **kwargs)
    except TypeError as exc:
        raise ValueError(str(exc)) from None


def positive_value(value: Any, what: str, source: object) -> float:
    """``value`` as a positive finite float; the error names ``what`` and ``source``."""
    return from_source(check_real, value, f"{what} from {source}", positive=True, what="a positive finite number")


def bits_value(value: Any, source: object) -> int:
    """``value`` as a bit depth (a whole float such as ``8.0`` counts); the error names ``source``."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    value = from_source(check_int, value, f"bits from {source}")
    try:
        return check_bits(value, torch.float64)
    except ValueError as exc:
        raise ValueError(f"bits from {source}: {exc}") from None


def frame_exposure(metadata: Mapping[str, Any], source: object) -> float | None:
    """The exposure a frame's metadata or sidecar records, checked as :class:`FileSensor` checks it.

    Args:
        metadata: the frame's metadata (:func:`torch_modulo.io.read_metadata`) or its sidecar's JSON object.
        source: where ``metadata`` comes from, for the error message (``"the metadata of a.png"``).

    Returns:
        The value of ``"exposure"``, ``"exposure_time"`` or ``"ExposureTime"`` (the first one present), or None
        when ``metadata`` records none.

    Raises:
        ValueError: the value is not a positive finite number; the message names ``source``.

    Example:
        >>> frame_exposure({"ExposureTime": 4}, "a.png"), frame_exposure({}, "a.png")
        (4.0, None)
    """
    value = first_value(metadata, _EXPOSURE_KEYS)
    return None if value is None else positive_value(value, "exposure", source)


def frame_bits(metadata: Mapping[str, Any], source: object) -> int | None:
    """The bit depth a frame's metadata or sidecar records, checked as :class:`FileSensor` checks it.

    Args:
        metadata: the frame's metadata (:func:`torch_modulo.io.read_metadata`) or its sidecar's JSON object.
        source: where ``metadata`` comes from, for the error message.

    Returns:
        The value of ``"bits"`` or ``"bit_depth"`` (the first one present; a whole float such as ``8.0`` counts),
        or None when ``metadata`` records none.

    Raises:
        ValueError: the value is not a whole number, is below 1, or has more bits than float64 holds exactly; the
            message names ``source``.

    Example:
        >>> frame_bits({"bit_depth": 12.0}, "a.png"), frame_bits({}, "a.png")
        (12, None)
    """
    value = first_value(metadata, _BITS_KEYS)
    return None if value is None else bits_value(value, source)


def inside(manifest: Path, name: str) -> Path:
    """The frame file ``name`` listed in ``manifest``, refused when the name leads out of the manifest's folder."""
    relative = os.path.normpath(name)
    if os.path.isabs(relative) or relative == os.pardir or relative.startswith(os.pardir + os.sep):
        raise ValueError(
            f"{manifest}: frame file {name!r} points outside the stack folder {manifest.parent}; "
            "list frames by their names inside that folder"
        )
    return manifest.parent / relative


def sidecar(path: Path) -> Path | None:
    """The JSON sidecar of frame ``path`` (``<file>.json``, else ``<stem>.json``), or None."""
    for candidate in (path.with_name(path.name + ".json"), path.with_suffix(".json")):
        if candidate.is_file():
            return candidate
    return None


@dataclass
class Frame:
    """A frame file and what the manifest lists for it (None: not listed): exposure, bit depth, place."""

    path: Path
    exposure: float | None = None
    bits: int | None = None
    batch: int = 0
    index: int | None = None


def describe_exposure(values: float | Sequence[float]) -> str:
    """Exposures as a user wrote them: ``16`` rather than ``16.0``, lists as ``[1, 16]``."""
    if isinstance(values, int | float):
        return f"{values:g}"
    return "[" + ", ".join(f"{v:g}" for v in values) + "]"


def _check_dtype(data: Mapping[str, Any], manifest: Path) -> None:
    name = data.get("dtype")
    if name is not None and (not isinstance(name, str) or name not in DTYPES):
        raise ValueError(f"{manifest}: dtype must be one of {', '.join(DTYPES)}; got {name!r}")


def stored_exposures(stored: Any, where: object) -> torch.Tensor | None:
    """A manifest's ``"exposures"`` as a float64 (M,) or (B, M) tensor, or None when it lists none."""
    if stored is None:
        return None
    try:
        tau = torch.tensor(stored, dtype=torch.float64)
    except (TypeError, ValueError, RuntimeError):
        raise ValueError(f"{where}: exposures must be a list of numbers; got {stored!r}") from None
    if tau.ndim not in (1, 2) or tau.shape[-1] == 0:
        raise ValueError(f"{where}: exposures must be an (M,) or (B, M) list of numbers; got {stored!r}")
    return tau


def _places(data: Mapping[str, Any], count: int, manifest: Path) -> dict[str, tuple[int, str]]:
    """The largest ``"batch"`` and ``"index"`` a frame may have: below the frames listed, or the exposures listed."""
    listed = f"{count} frame{'s' if count > 1 else ''}"
    try:
        tau = stored_exposures(data.get("exposures"), manifest)
    except ValueError:
        tau = None  # refused, naming the value, when the stack is assembled
    if tau is None:
        return {"batch": (count - 1, listed), "index": (count - 1, listed)}
    m, b = tau.shape[-1], tau.shape[0] if tau.ndim == 2 else 1
    return {
        "batch": (max(count, b) - 1, f"{listed} and {b} scene{'s' if b > 1 else ''} of exposures"),
        "index": (max(count, m) - 1, f"{listed} and {m} exposure{'s' if m > 1 else ''}"),
    }


def read_manifest(manifest: Path) -> tuple[list[Frame], dict[str, Any]]:
    """The frames a manifest lists, and its JSON object, every value checked (the module docstring's rules).

    Raises:
        ValueError: no frames, a bad entry, a place outside the stack, a bad exposure, bit depth, kind, metadata,
            colour filter array or dtype; each message names the manifest and the value.
    """
    data = load_json(manifest)
    entries = data.get("frames")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f'{manifest} must list the frames: "frames": [{{"file": ..., "exposure": ...}}]')
    places = _places(data, len(entries), manifest)
    frames = []
    for i, entry in enumerate(entries):
        if isinstance(entry, str):
            entry = {"file": entry}
        if not isinstance(entry, dict) or not isinstance(entry.get("file"), str):
            raise ValueError(f'{manifest}: frame {i} must be a file name or an object with "file"; got {entry!r}')
        frame = Frame(inside(manifest, entry["file"]))
        where = f"{manifest} (frame {entry['file']})"
        if entry.get("exposure") is not None:
            frame.exposure = positive_value(entry["exposure"], "exposure", where)
        if entry.get("bits") is not None:
            frame.bits = bits_value(entry["bits"], where)
        for key in ("batch", "index"):
            if key in entry:
                # A place past the stack cannot be filled: refuse it before the stack's (batch, exposure) grid is
                # laid out, which is as large as the biggest place.
                top, listed = places[key]
                what = f"an int in [0, {top}] (the manifest lists {listed})"
                setattr(frame, key, from_source(check_int, entry[key], f"{where}: {key!r}", 0, top, what=what))
        frames.append(frame)
    if data.get("bits") is not None:
        bits = bits_value(data["bits"], manifest)
        for frame in frames:
            frame.bits = frame.bits if frame.bits is not None else bits
    if data.get("kind") is not None:
        check_choice(data["kind"], f"{manifest}: kind", KINDS)
    if data.get("metadata") is not None and not isinstance(data["metadata"], dict):
        raise ValueError(f"{manifest}: metadata must be an object; got {type(data['metadata']).__name__}")
    top_cfa, inner = data.get("cfa"), (data.get("metadata") or {}).get("cfa")
    for key, pattern in (("cfa", top_cfa), ("metadata['cfa']", inner)):
        if pattern is not None:
            from_source(check_cfa, pattern, f"{manifest}: {key}")
    if top_cfa is not None and inner is not None and top_cfa != inner:
        raise ValueError(f"{manifest}: cfa {top_cfa!r} disagrees with the metadata's cfa {inner!r}")
    _check_dtype(data, manifest)
    return frames, data


def _disagreement(manifest: Path, frame: Path, key: str, listed: str, recorded: str, source: object) -> ValueError:
    return ValueError(
        f"{manifest}: {key} {listed} for frame {frame.name}, but {source} records {key} {recorded}: the manifest "
        "describes the frames and never overrides them; correct whichever is wrong"
    )


def frame_record(
    frame: Frame,
    side: Mapping[str, Any],
    side_path: Path | None,
    embedded: Mapping[str, Any],
    manifest: Path | None,
) -> tuple[float | None, int | None]:
    """The exposure and bit depth of a frame: the manifest's where it lists them, else the frame's own record (its
    sidecar's, else its metadata's); where both give one, they must agree.

    Raises:
        ValueError: a bad value, or the manifest and the frame's record disagree (both named).
    """
    own = f"the metadata of {frame.path}"
    tau, tau_source = frame_exposure(side, side_path), str(side_path)
    if tau is None:
        tau, tau_source = frame_exposure(embedded, own), own
    bits, bits_source = frame_bits(side, side_path), str(side_path)
    if bits is None:
        bits, bits_source = frame_bits(embedded, own), own
    if manifest is not None and frame.exposure is not None and tau is not None:
        if not math.isclose(frame.exposure, tau, rel_tol=_EXPOSURE_TOLERANCE):
            listed, recorded = describe_exposure(frame.exposure), describe_exposure(tau)
            raise _disagreement(manifest, frame.path, "exposure", listed, recorded, tau_source)
    if manifest is not None and frame.bits is not None and bits is not None and frame.bits != bits:
        raise _disagreement(manifest, frame.path, "bits", str(frame.bits), str(bits), bits_source)
    return (frame.exposure if frame.exposure is not None else tau), (frame.bits if frame.bits is not None else bits)


def check_manifest_cfa(data: Mapping[str, Any], manifest: Path | None, frames: Mapping[str, Path]) -> None:
    """Refuse a manifest whose colour filter array is not the one its frames record (``frames``: pattern -> the
    first frame that records it)."""
    listed = data.get("cfa") or (data.get("metadata") or {}).get("cfa")
    recorded = next(iter(frames), None)
    if manifest is not None and listed is not None and recorded is not None and listed != recorded:
        source = f"the metadata of {frames[recorded]}"
        raise _disagreement(manifest, frames[recorded], "cfa", repr(listed), repr(recorded), source)


def check_manifest_shape(data: Mapping[str, Any], manifest: Path | None, shape: Sequence[int]) -> None:
    """Refuse a manifest whose ``"shape"`` (B, M, C, H, W) is not the shape of the frames it lists."""
    listed = data.get("shape")
    if manifest is not None and listed is not None and list(listed) != list(shape):
        raise ValueError(
            f"{manifest}: shape {listed} disagrees with the frames' (B, M, C, H, W) {list(shape)}; the manifest "
            "describes the frames and never overrides them"
        )


def _missing(
    where: object, slot: tuple[int, int], frames: Sequence[Frame], taus: Sequence[float], tau: torch.Tensor | None
) -> str:
    """The error for an empty place of the stack: the exposure missing, where the manifest lists its exposures."""
    b, m = slot
    if tau is not None:
        wanted = tau.expand(max(b + 1, tau.shape[0] if tau.ndim == 2 else 1), tau.shape[-1])[b].tolist()
        found = [t for f, t in zip(frames, taus, strict=True) if f.batch == b]
        absent = list(wanted)
        for t in found:
            close = [w for w in absent if math.isclose(w, t, rel_tol=_EXPOSURE_TOLERANCE)]
            if close:
                absent.remove(close[0])
        if absent:
            return (
                f"{where}: no frame for exposure {describe_exposure(absent[0])} of scene {b} (the manifest's "
                f"exposures are {describe_exposure(wanted)}, its frames' {describe_exposure(found)}): list that "
                'frame, or remove its exposure from "exposures"'
            )
    return f"{where}: no frame for (batch, exposure) {slot}"


def place_frames(
    frames: Sequence[Frame], taus: Sequence[float], stored: torch.Tensor | None, where: object
) -> tuple[dict[tuple[int, int], int], int, int]:
    """Each frame's place (batch, exposure index) -> its position in ``frames``, and the stack's B and M.

    Frames without an index follow each other in order; ``stored`` (the manifest's exposures, or None) sets the
    smallest B and M. An empty place is refused, naming its exposure where ``stored`` gives it.
    """
    slots: dict[tuple[int, int], int] = {}
    counters: dict[int, int] = {}
    for n, frame in enumerate(frames):
        m = frame.index if frame.index is not None else counters.get(frame.batch, 0)
        counters[frame.batch] = max(counters.get(frame.batch, 0), m + 1)
        if (frame.batch, m) in slots:
            raise ValueError(f"{where}: two frames for batch {frame.batch}, exposure {m}")
        slots[(frame.batch, m)] = n
    b, m_count = max(counters) + 1, max(counters.values())
    if stored is not None:
        b, m_count = max(b, stored.shape[0] if stored.ndim == 2 else 1), max(m_count, stored.shape[-1])
    missing = next(((i, j) for i in range(b) for j in range(m_count) if (i, j) not in slots), None)
    if missing is not None:
        raise ValueError(_missing(where, missing, frames, taus, stored) + f" of a {b} x {m_count} stack")
    return slots, b, m_count
