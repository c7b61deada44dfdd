"""Frames of a real modulo camera from disk, and FrameStacks written to disk so that they read back identically.

Where :class:`FileSensor` finds each frame's exposure and the bit depth: the arguments override everything; the
records below describe the frames and must agree where several give a value (a manifest's ``"bits": 9`` over frames
that record 8 bits is refused, naming both, as are a disagreeing ``"cfa"``, exposure or ``"shape"`` and an unknown
``"dtype"``; see :mod:`torch_modulo.sensors.manifest`):

1. the arguments ``exposures=`` (one per file, in file order) and ``bits=``;
2. a folder manifest ``frames.json`` (written by :func:`write_frames`; also easy to write by hand)::

       {"bits": 8, "frames": [{"file": "short.png", "exposure": 1.0},
                              {"file": "long.png",  "exposure": 16.0}]}

   Optional keys: ``"kind"`` (``"modulo"`` or ``"intensity"``), ``"cfa"`` (the colour filter array of mosaicked
   frames: ``"RGGB"``, ``"BGGR"``, ``"GRBG"`` or ``"GBRG"``), ``"metadata"`` (a dict), ``"exposures"`` (the
   stack's exposures as (M,) or (B, M) lists), and per frame ``"batch"`` and ``"index"`` (its place in a
   (B, M, C, H, W) stack, counted from 0 and below the number of frames listed; by default frames are the
   exposures of one scene, in the listed order). Frame files are named relative to the manifest's folder and may
   not lead out of it (``../x.png`` or ``/x.png`` is refused);
3. a JSON sidecar per frame, ``<file>.json`` or ``<stem>.json`` (``short.png.json`` or ``short.json``), with
   ``"exposure"`` and ``"bits"``;
4. the frame's own metadata (EXR attributes, or the metadata :func:`torch_modulo.io.write_image` stores in PNG and
   TIFF): ``"exposure"`` (or ``"exposure_time"``, ``"ExposureTime"``) and ``"bits"`` (or ``"bit_depth"``).

The colour filter array of a colour sensor's mosaics (:attr:`FrameStack.cfa`) is found the same way: the ``cfa=``
argument, the manifest's ``"cfa"`` (or its metadata's), a sidecar's or the frame's own ``"cfa"``; frames without
one are not mosaics.

Image frames (.exr, .png, .tif, .tiff, .pfm, .hdr) are read with :func:`torch_modulo.io.read_image`: integer files
give their raw values (a 12-bit camera frame stored in a 16-bit PNG reads as 0..4095). Headerless raw dumps are
described by a :class:`RawFormat` (width, height, bit depth, byte order); packed formats (e.g. 12 bits in 1.5
bytes) are not supported: unpack them to 8/16/32-bit containers first.

A directory is read in file-name order, skipping hidden files (names starting with ``.``, such as the temporary
files of an atomic write) and JSON files. Every error names the file.
"""

from __future__ import annotations

import errno
import json
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from torch_modulo._atomic import replace_folder
from torch_modulo._checks import check_bits, check_choice, check_int, check_modulus
from torch_modulo.cfa import check_cfa
from torch_modulo.io import read_image, write_image
from torch_modulo.sensors.frames import KINDS, FrameStack
from torch_modulo.sensors.manifest import (
    DTYPES,
    MANIFEST,
    Frame,
    bits_value,
    check_manifest_cfa,
    check_manifest_shape,
    frame_bits,
    frame_exposure,
    frame_record,
    from_source,
    load_json,
    place_frames,
    positive_value,
    read_manifest,
    sidecar,
    stored_exposures,
)

__all__ = [
    "IMAGE_EXTENSIONS",
    "MANIFEST",
    "FileSensor",
    "RawFormat",
    "frame_bits",
    "frame_exposure",
    "stack_files",
    "write_frames",
]

#: Image files a folder is searched for.
IMAGE_EXTENSIONS = (".exr", ".png", ".tif", ".tiff", ".pfm", ".hdr")
_FORMAT_TAG = "torch_modulo.frames"


@dataclass(frozen=True)
class RawFormat:
    """Layout of a headerless raw frame: ``height * width * channels`` unsigned integers, row-major, channels
    interleaved (H, W, C), after ``offset`` header bytes to skip.

    Args:
        width, height: frame size in pixels.
        bits: the sensor's bit depth (values must be below ``2**bits``).
        byteorder: ``"little"`` or ``"big"``.
        channels: samples per pixel.
        sample_bytes: bytes per sample, 1, 2 or 4; default the smallest that holds ``bits``.
        offset: bytes to skip at the start of each file.
        extensions: file extensions that mark raw frames (a file's last suffix is matched, case-insensitively):
            a sequence of extensions or a single one (``".raw"``); stored lower case with a leading dot
            (``"RAW"`` becomes ``".raw"``).

    Raises:
        TypeError: a size, the bit depth or the offset is not an integer, or an extension not a string.
        ValueError: a value out of range, an unknown byte order, a sample size that cannot hold ``bits``, or an
            extension that no file name can end in (empty, with a further dot, a path separator or whitespace).

    Example:
        >>> RawFormat(width=640, height=512, bits=12).frame_bytes
        655360
    """

    width: int
    height: int
    bits: int
    byteorder: str = "little"
    channels: int = 1
    sample_bytes: int | None = None
    offset: int = 0
    extensions: tuple[str, ...] = (".raw", ".bin")

    def __post_init__(self) -> None:
        for name in ("width", "height", "channels"):
            check_int(getattr(self, name), f"RawFormat.{name}", 1, what="a positive int")
        bits = check_int(check_bits(self.bits, torch.float64), "RawFormat.bits", high=32, what="at most 32")
        check_choice(self.byteorder, "RawFormat.byteorder", ("little", "big"), what="'little' or 'big'")
        smallest = 1 if bits <= 8 else 2 if bits <= 16 else 4
        nbytes = smallest if self.sample_bytes is None else self.sample_bytes
        what = f"1, 2 or 4 and hold {bits} bits (at least {smallest})"
        check_choice(nbytes, "RawFormat.sample_bytes", (1, 2, 4), what=what)
        if nbytes < smallest:
            raise ValueError(f"RawFormat.sample_bytes must be {what}; got {nbytes!r}")
        check_int(self.offset, "RawFormat.offset", 0, what="an int >= 0")
        object.__setattr__(self, "sample_bytes", nbytes)
        object.__setattr__(self, "extensions", _raw_extensions(self.extensions))

    @property
    def numpy_dtype(self) -> np.dtype:
        return np.dtype(f"{'<' if self.byteorder == 'little' else '>'}u{self.sample_bytes}")

    @property
    def frame_bytes(self) -> int:
        """Expected file size in bytes, header included."""
        return self.offset + self.width * self.height * self.channels * int(self.sample_bytes or 0)

    def read(self, path: str | os.PathLike[str]) -> torch.Tensor:
        """Read one raw frame as a float64 (C, H, W) tensor of its integer values."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(errno.ENOENT, "raw frame not found", str(path))
        size = path.stat().st_size
        if size != self.frame_bytes:
            raise ValueError(
                f"raw frame {path} has {size} bytes; expected {self.frame_bytes} for {self.width}x{self.height}x"
                f"{self.channels} samples of {self.sample_bytes} bytes plus {self.offset} header bytes"
            )
        data = np.fromfile(path, dtype=self.numpy_dtype, offset=self.offset)
        array = data.reshape(self.height, self.width, self.channels).astype(np.float64)
        return torch.from_numpy(array).permute(2, 0, 1).contiguous()


def _raw_extensions(extensions: object) -> tuple[str, ...]:
    """``RawFormat.extensions`` as a tuple of lower-case suffixes with their leading dot, each one a file can have."""
    if isinstance(extensions, str):
        extensions = (extensions,)  # one extension, not its characters
    if isinstance(extensions, bytes | bytearray) or not isinstance(extensions, Iterable):
        raise TypeError(f"RawFormat.extensions must be a str or a sequence of str; got {type(extensions).__name__}")
    out = []
    for ext in extensions:
        if not isinstance(ext, str):
            raise TypeError(f"RawFormat.extensions must hold str; got {ext!r} ({type(ext).__name__})")
        suffix = "." + ext.lower().removeprefix(".")
        # Files are matched by their last suffix (Path.suffix): these could never match one.
        if suffix == "." or "." in suffix[1:] or any(c in suffix for c in "/\\") or any(c.isspace() for c in suffix):
            raise ValueError(
                f"RawFormat.extensions must be file suffixes such as '.raw' (one dot, no separators or spaces); "
                f"got {ext!r}"
            )
        out.append(suffix)
    return tuple(out)


# ---------------------------------------------------------------------------------------------- reading


class FileSensor:
    """A sensor adapter for frames on disk: a folder or a list of files in, a :class:`FrameStack` out.

    Args:
        source: a folder (read with its ``frames.json`` manifest if present, otherwise every image or raw file in
            name order) or a sequence of files (taken in the given order).
        bits: the sensor's bit depth; overrides the files' metadata.
        exposures: one exposure per file, in file order; overrides the files' metadata.
        raw: how to read headerless raw dumps (files with ``raw.extensions``); None when there are none.
        kind: ``"modulo"`` or ``"intensity"``; default the manifest's, else ``"modulo"``.
        cfa: the colour filter array of mosaicked frames (``"RGGB"``, ``"BGGR"``, ``"GRBG"``, ``"GBRG"``);
            default the manifest's, else a sidecar's or the frames' own metadata's, else None (not mosaics).
        dtype: floating dtype of the frames; default the manifest's (what :func:`write_frames` was given), else
            ``torch.float32``. Bits above 24 need ``torch.float64``.
        device: where the frames go.

    Raises (on construction, for a bad ``source`` or arguments; on :meth:`read`, for bad files):
        FileNotFoundError: the folder or a file is missing.
        OSError: a file cannot be read (not an image, truncated, ...).
        ValueError: no frames, missing or bad exposure or bit depth, frames of different sizes, values not
            integers in ``[0, 2**bits)``, a raw file of the wrong size, a bad manifest (an unknown ``"dtype"``, a
            missing frame, named by its exposure), a manifest whose bits, exposure, colour filter array or shape
            disagree with what the frames record (both named), an unknown or disagreeing colour filter array, or
            one given for frames that are not mosaics.

    Example:
        >>> import tempfile
        >>> from torch_modulo.sensors import SimulatedModuloSensor, write_frames
        >>> stack = SimulatedModuloSensor(bits=8, seed=0)(torch.rand(1, 3, 8, 8) * 300, [1.0, 16.0])
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     _ = write_frames(stack, folder, format="png")
        ...     FileSensor(folder).read() == stack
        True
    """

    def __init__(
        self,
        source: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
        *,
        bits: int | None = None,
        exposures: Sequence[float] | torch.Tensor | None = None,
        raw: RawFormat | None = None,
        kind: str | None = None,
        cfa: str | None = None,
        dtype: torch.dtype | None = None,
        device: torch.device | str | None = None,
    ) -> None:
        if raw is not None and not isinstance(raw, RawFormat):
            raise TypeError(f"raw must be a RawFormat or None; got {type(raw).__name__}")
        if dtype is not None and dtype not in DTYPES.values():
            raise TypeError(f"dtype must be a floating torch dtype; got {dtype}")
        if kind is not None:
            check_choice(kind, "kind", KINDS)
        self.raw = raw
        self.bits = bits_value(bits, "the bits argument") if bits is not None else None
        if exposures is not None:
            values = exposures.tolist() if isinstance(exposures, torch.Tensor) else list(exposures)
            self.exposures: list[float] | None = [
                positive_value(v, "exposure", "the exposures argument") for v in values
            ]
        else:
            self.exposures = None
        self.kind = kind
        self.cfa = check_cfa(cfa) if cfa is not None else None
        self.dtype = dtype
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        self.manifest: dict[str, Any] | None = None
        self.manifest_path: Path | None = None
        self.frames = self._list(source)
        if self.exposures is not None and len(self.exposures) != len(self.frames):
            raise ValueError(
                f"exposures has {len(self.exposures)} values for {len(self.frames)} frames "
                f"({', '.join(f.path.name for f in self.frames)})"
            )

    @property
    def files(self) -> list[Path]:
        """The frame files, in the order they are read."""
        return [f.path for f in self.frames]

    def _list(self, source: object) -> list[Frame]:
        if isinstance(source, str | os.PathLike):
            folder = Path(source)
            if not folder.exists():
                raise FileNotFoundError(errno.ENOENT, "frame folder or file not found", str(folder))
            if folder.is_file():
                return [Frame(folder)]
            manifest = folder / MANIFEST
            if manifest.is_file():
                return self._from_manifest(manifest)
            extensions = IMAGE_EXTENSIONS + (self.raw.extensions if self.raw is not None else ())
            paths = sorted(
                p
                for p in folder.iterdir()
                if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in extensions
            )
            if not paths:
                raise ValueError(
                    f"no frames in {folder}: expected files ending in {', '.join(extensions)}"
                    + ("" if self.raw is not None else " (pass raw=RawFormat(...) for headerless raw dumps)")
                )
            return [Frame(p) for p in paths]
        if isinstance(source, Sequence) and not isinstance(source, bytes):
            paths = []
            for item in source:
                if not isinstance(item, str | os.PathLike):
                    raise TypeError(f"frame files must be str or os.PathLike; got {type(item).__name__}")
                paths.append(Path(item))
            if not paths:
                raise ValueError("no frames: the list of files is empty")
            return [Frame(p) for p in paths]
        raise TypeError(f"source must be a folder, a file or a list of files; got {type(source).__name__}")

    def _from_manifest(self, manifest: Path) -> list[Frame]:
        frames, self.manifest = read_manifest(manifest)
        self.manifest_path = manifest
        return frames

    def _read_frame(self, frame: Frame) -> tuple[torch.Tensor, dict[str, Any]]:
        path = frame.path
        if not path.exists():
            raise FileNotFoundError(errno.ENOENT, "frame file not found", str(path))
        if self.raw is not None and path.suffix.lower() in self.raw.extensions:
            return self.raw.read(path), {"bits": self.raw.bits}
        return read_image(path, with_metadata=True, dtype=torch.float64)

    def read(self) -> FrameStack:
        """Read every frame and return them as one :class:`FrameStack` (validated)."""
        images: list[torch.Tensor] = []
        taus: list[float] = []
        bits_seen: dict[int, Path] = {}
        patterns: dict[str, Path] = {}
        for i, frame in enumerate(self.frames):
            image, embedded = self._read_frame(frame)
            sidecar_path = sidecar(frame.path)
            side = load_json(sidecar_path) if sidecar_path is not None else {}
            if images and image.shape != images[0].shape:
                raise ValueError(
                    f"frame {frame.path} has shape {tuple(image.shape)} (C, H, W) but {self.frames[0].path} has "
                    f"{tuple(images[0].shape)}: all frames must have the same size"
                )
            # The manifest's values where it lists them (they must agree with the frame's own), else the frame's;
            # the arguments override both.
            listed = replace(
                frame,
                exposure=None if self.exposures is not None else frame.exposure,
                bits=None if self.bits is not None else frame.bits,
            )
            recorded_tau, recorded_bits = frame_record(listed, side, sidecar_path, embedded, self.manifest_path)
            tau = self.exposures[i] if self.exposures is not None else recorded_tau
            if tau is None:
                raise ValueError(
                    f"no exposure for frame {frame.path}: give exposures=[...], list it in {MANIFEST}, write a "
                    f'sidecar {frame.path.name}.json with "exposure", or store "exposure" in the file\'s metadata'
                )
            bits = self.bits if self.bits is not None else recorded_bits
            if bits is None:
                raise ValueError(
                    f'no bit depth for frame {frame.path}: give bits=..., put "bits" in {MANIFEST} or a sidecar '
                    f'{frame.path.name}.json, or store "bits" in the file\'s metadata'
                )
            if bits_seen and bits not in bits_seen:
                other_bits, other = next(iter(bits_seen.items()))
                raise ValueError(
                    f"frame {frame.path} has bits={bits} but {other} has bits={other_bits}: one stack has one bit depth"
                )
            bits_seen.setdefault(bits, frame.path)
            _frame_cfa(patterns, frame.path, side.get("cfa"), embedded.get("cfa"), sidecar_path)
            check_modulus(image, bits, f"frame {frame.path}")
            images.append(image)
            taus.append(tau)
        if self.cfa is None:
            check_manifest_cfa(self.manifest or {}, self.manifest_path, patterns)
        return self._assemble(images, taus, next(iter(bits_seen)), next(iter(patterns), None))

    def _assemble(self, images: list[torch.Tensor], taus: list[float], bits: int, frames_cfa: str | None) -> FrameStack:
        data = self.manifest or {}
        where = self.manifest_path
        kind = self.kind or data.get("kind") or "modulo"
        metadata = dict(data.get("metadata") or {})
        cfa = self.cfa or data.get("cfa") or metadata.get("cfa") or frames_cfa
        metadata.pop("cfa", None)
        stored = stored_exposures(data.get("exposures"), where) if self.exposures is None else None
        slots, b, m_count = place_frames(self.frames, taus, stored, where)
        moduli = torch.stack([torch.stack([images[slots[(i, j)]] for j in range(m_count)]) for i in range(b)])
        tau = torch.tensor([[taus[slots[(i, j)]] for j in range(m_count)] for i in range(b)], dtype=torch.float64)
        if stored is not None:
            if stored.shape not in ((m_count,), (b, m_count)) or not torch.equal(stored.expand(b, m_count), tau):
                raise ValueError(
                    f"{where}: exposures {data['exposures']} disagree with the frames' exposures {tau.tolist()}"
                )
            tau = stored
        elif b == 1:
            tau = tau[0]
        check_manifest_shape(data, where, moduli.shape)
        dtype = self.dtype or DTYPES.get(data.get("dtype") or "float32", torch.float32)
        moduli = moduli.to(device=self.device, dtype=dtype)
        if cfa is not None and (moduli.shape[-3] != 1 or moduli.shape[-2] % 2 or moduli.shape[-1] % 2):
            shape, folder = tuple(moduli.shape[-3:]), where or self.frames[0].path.parent
            raise ValueError(f"frames in {folder} are not mosaics (cfa={cfa!r}), (1, even H, even W); got {shape}")
        return FrameStack(moduli, tau, bits, metadata, kind=kind, cfa=cfa)

    __call__ = read

    def __repr__(self) -> str:
        return f"FileSensor({len(self.frames)} frames, first {self.frames[0].path})"


# ---------------------------------------------------------------------------------------------- writing


def _frame_cfa(patterns: dict[str, Path], path: Path, sidecar: Any, embedded: Any, sidecar_path: Path | None) -> None:
    """Note the pattern a frame's sidecar (first) or own metadata names; frames that disagree are refused."""
    value, source = (sidecar, sidecar_path) if sidecar is not None else (embedded, f"the metadata of {path}")
    if value is None:
        return
    pattern = from_source(check_cfa, value, f"cfa from {source}")
    if patterns and pattern not in patterns:
        other_cfa, other = next(iter(patterns.items()))
        raise ValueError(f"frame {path} has cfa={pattern!r} but {other} has cfa={other_cfa!r}: one stack, one pattern")
    patterns.setdefault(pattern, path)


def _json_ready(value: Any, where: str) -> Any:
    try:
        json.dumps(value, allow_nan=True)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{where} must be JSON-serialisable to be written: {exc}") from None
    return value


def write_frames(
    stack: FrameStack,
    folder: str | os.PathLike[str],
    *,
    format: str = "exr",
    prefix: str = "frame",
) -> Path:
    """Write a :class:`FrameStack` to a folder so that ``FileSensor(folder).read()`` gives it back exactly.

    One file per frame, ``{prefix}_b{batch:03d}_m{index:02d}.{ext}``, each with its exposure and bit depth (and the
    colour filter array of mosaics, :attr:`FrameStack.cfa`) in its own metadata, plus the manifest ``frames.json``
    with the bit depth, kind, pattern, exposures, metadata and layout.

    The stack is written atomically: everything goes to a hidden folder beside ``folder``, which then takes
    ``folder``'s place in one rename. If anything fails, ``folder`` is left as it was: the previous stack whole,
    or no folder at all. Other files in ``folder`` are kept; the previous stack's frames (those its manifest
    lists) and files of the same names as the new frames are replaced.

    Args:
        stack: the frames.
        folder: destination folder (created if missing, with its parents).
        format: ``"exr"`` (half for bits <= 11, else float; up to 24 bits), ``"png"`` or ``"tiff"`` (8-bit for
            bits <= 8, else 16-bit; up to 16 bits).
        prefix: file name prefix.

    Returns:
        The manifest's path.

    Raises:
        TypeError: ``stack`` is not a FrameStack, or its metadata is not JSON-serialisable.
        ValueError: an empty stack (a batch of 0), an unknown format, or a bit depth the format cannot hold.
        OSError: a frame or the manifest could not be written (a full disk, no permission); ``folder`` is then
            unchanged.

    Example:
        >>> import tempfile
        >>> stack = FrameStack(torch.tensor([[[[0.0, 5.0]]], [[[9.0, 250.0]]]]), [1.0, 4.0], bits=8)
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     manifest = write_frames(stack, folder)
        ...     sorted(p.name for p in manifest.parent.iterdir())
        ['frame_b000_m00.exr', 'frame_b000_m01.exr', 'frames.json']
    """
    if not isinstance(stack, FrameStack):
        raise TypeError(f"stack must be a FrameStack; got {type(stack).__name__}")
    if stack.batch_size == 0:
        # A folder of no frames has no manifest FileSensor can read back (it must list the frames).
        raise ValueError(
            f"stack has no frames (a batch of 0, shape {tuple(stack.shape)}): a folder of frames needs at least one "
            "scene; nothing was written"
        )
    formats = {"exr": ".exr", "png": ".png", "tiff": ".tif", "tif": ".tif"}
    check_choice(format, "format", formats)
    if not isinstance(prefix, str) or not prefix or os.sep in prefix or prefix.startswith("."):
        raise ValueError(f"prefix must be a plain, non-hidden file name prefix; got {prefix!r}")
    bits = stack.bits
    ext = formats[format]
    if ext == ".exr":
        if bits > 24:
            raise ValueError(f"EXR frames hold at most 24 bits exactly (float32); got bits={bits}")
        dtype = "half" if bits <= 11 else "float"
    else:
        if bits > 16:
            raise ValueError(f"{format.upper()} frames hold at most 16 bits; got bits={bits} (use format='exr')")
        dtype = "uint8" if bits <= 8 else "uint16"
    metadata = _json_ready(stack.metadata, "stack.metadata")
    folder = Path(folder)
    taus = stack.exposure_matrix().tolist()
    moduli = stack.moduli.detach().cpu()
    manifest: dict[str, Any] = {
        "format": _FORMAT_TAG,
        "version": 1,
        "bits": bits,
        "kind": stack.kind,
        "shape": list(stack.shape),
        "dtype": str(stack.dtype).replace("torch.", ""),
        "exposures": stack.exposures.tolist(),
        "metadata": metadata,
        "frames": [],
    }
    frame_meta: dict[str, Any] = {"bits": bits}
    if stack.cfa is not None:
        manifest["cfa"] = frame_meta["cfa"] = stack.cfa

    def build(tmp: Path) -> None:
        for b in range(stack.batch_size):
            for m in range(stack.num_exposures):
                name = f"{prefix}_b{b:03d}_m{m:02d}{ext}"
                write_image(tmp / name, moduli[b, m], {"exposure": taus[b][m], **frame_meta}, dtype=dtype)
                manifest["frames"].append({"file": name, "batch": b, "index": m, "exposure": taus[b][m]})
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=1, allow_nan=True))

    replace_folder(folder, build, stack_files(folder))
    return folder / MANIFEST


def stack_files(folder: Path) -> set[str]:
    """Names in ``folder`` that belong to the stack its manifest describes (the manifest and its frames): what
    writing a new stack there replaces (other entries are kept)."""
    names = {MANIFEST}
    try:
        entries = json.loads((folder / MANIFEST).read_text()).get("frames", [])
    except (OSError, ValueError, AttributeError):
        return names
    for entry in entries if isinstance(entries, list) else []:
        name = entry.get("file") if isinstance(entry, dict) else entry
        if isinstance(name, str) and name and os.path.basename(name) == name:
            names.add(name)
    return names
