"""Image files through OpenImageIO: EXR, Radiance HDR, PFM, 8/16-bit PNG and TIFF, with metadata.

Images are float tensors (C, H, W); (H, W) is accepted for writing and stored as one channel, and so is a batch of
one image, (1, C, H, W).

How values are stored
    ======================  ==========================  =========================================================
    format (extension)      sample types (``dtype=``)   values
    ======================  ==========================  =========================================================
    OpenEXR (.exr)          ``"float"`` (default),      as they are (NaN/Inf kept); ``"half"`` rounds to 11
                            ``"half"``                  significant bits and refuses magnitudes above 65504
    Radiance (.hdr)         ``"float"`` (RGBE)          3 channels only, finite and >= 0; shared-exponent
                                                        encoding keeps about 2-3 significant digits (relative
                                                        error up to 2^-8 of the pixel's largest channel)
    PFM (.pfm)              ``"float"``                 1 or 3 channels, float32, exact
    PNG (.png)              ``"uint8"``, ``"uint16"``   raw integers (see below); 1 to 4 channels
    TIFF (.tif, .tiff)      ``"uint8"``, ``"uint16"``,  raw integers, or float32 with ``dtype="float"``
                            ``"float"``
    ======================  ==========================  =========================================================

Integer formats store *raw integer values*, not values normalised to [0, 1]: a 12-bit modulus image holding the
integers 0..4095 written to a 16-bit PNG or TIFF reads back as exactly those integers. Files whose samples are
narrower than their container (a 12-bit TIFF, a 1/2/4-bit PNG) also read as the integers stored (OpenImageIO
stretches them to the container's range; :func:`read_image` shifts them back). Writing refuses NaN,
non-integers and values outside ``[0, 2**8 - 1]`` or ``[0, 2**16 - 1]`` rather than rounding or clipping them.
Display images in [0, 1] (tone-mapped results) are stored normalised, ``round(x * 255)`` (or ``* 65535``);
``read_image(..., normalized=True)`` divides by the same maximum. Reading an integer file returns its raw values
unless ``normalized=True`` is given, whatever wrote it. Without ``dtype``, PNG and TIFF are written as 8-bit unless
``metadata["bits"]`` is between 9 and 16, in which case 16-bit.

Raw or normalised (``normalized=None``, the default, decides from the image)
    ==========================================================  ===============================================
    image                                                       stored as
    ==========================================================  ===============================================
    ``metadata`` has ``"bits"`` (a sensor's frame)              raw integers, always
    integer dtype (``torch.uint8``, ``torch.int64``, ...)       raw integers
    floating, every value an integer                            raw integers (a float tensor of counts)
    floating, some value not an integer, all in [0, 1]          normalised (``round(x * 255)``), as torchvision
                                                                and scikit-image store float images
    floating, some value not an integer, some outside [0, 1]    refused (``ValueError``)
    ==========================================================  ===============================================

    Why integers win: every count the capture models, the sensors and :func:`~torch_modulo.sensors.write_frames`
    produce is a float tensor of integers, and a dark frame can hold nothing but 0 and 1. A rule that took every
    float image in [0, 1] as a display image would silently store such a frame as 0 and 255, and the frame would
    decode to a radiance 255 times too bright. Stored raw, an image of integers reads back exactly with
    :func:`read_image`'s default. The one image both rules fit, a float image holding only 0 and 1 with no
    ``"bits"`` in its metadata (a black-and-white mask, or a dark frame written by hand), is stored raw with a
    warning that names ``normalized=True``. Pass ``normalized=True`` or ``normalized=False`` to decide yourself and
    silence the rule.

Colour
    A PNG written with raw integers is tagged as data: it holds none of the chunks (``sRGB``, ``gAMA``, ``cHRM``)
    that tell a viewer to treat its samples as sRGB colours, and :func:`read_metadata` reports
    ``oiio:ColorSpace`` as ``"Raw"`` (OpenImageIO's name for data; without the tag it reports sRGB for every PNG).
    A normalised PNG keeps OpenImageIO's sRGB chunks: it is an image for display.

Metadata
    A metadata dict (string keys; values that JSON can hold: numbers, strings, booleans, None, lists and dicts of
    these; tensors and numpy arrays are stored as lists) round-trips exactly in EXR, PNG and TIFF: it is stored as
    one JSON text (the ``torch_modulo:metadata`` attribute in EXR and PNG, the ``ImageDescription`` tag in TIFF).
    EXR also gets each simple value (number, string, list of numbers) as a native attribute that other tools
    (``exrheader``, ``oiiotool --info -v``) show, floats in single precision. Radiance HDR and PFM files cannot
    hold metadata: writing metadata to them warns and drops it (keep a JSON sidecar, as
    :func:`torch_modulo.sensors.write_frames` does). :func:`read_metadata` returns the file's own attributes as
    OpenImageIO reports them (for example ``compression``), overlaid with the stored dict.

Orientation
    Row 0 is the top of the image in every format. PFM files store rows bottom to top; OpenImageIO 3.x flips them
    back only when a file is opened with a configuration, which this module always passes (``pnm:pfmflip=1``),
    so PFM files from other tools read the right way up.

Writes are atomic: the image goes to a hidden temporary file with the same extension in the destination folder,
which is checked, flushed to the disk (``fsync``) and only then renamed into place over the destination, so a
reader never sees a half-written file. PNG files are read back and compared with the image before the rename,
because the PNG writer does not report a short write (a full disk); every other format reports it itself. A
failed write raises ``OSError`` and leaves nothing under the destination's name.

Errors: a missing file raises ``FileNotFoundError``; a file OpenImageIO cannot read (unknown format, not an image,
truncated, corrupted) raises ``OSError``; a bad image or value to write raises ``TypeError``/``ValueError``. Every
message names the file.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np
import OpenImageIO as oiio
import torch

from torch_modulo._atomic import atomic_file
from torch_modulo._checks import check_flag
from torch_modulo._image_metadata import (
    BLOB_KEY,
    COLORSPACE_ATTRIBUTE,
    DATA_COLORSPACE,
    METADATA_ATTRIBUTE,
    check_metadata,
    metadata_from_spec,
    native_attribute,
)

__all__ = [
    "WRITABLE_EXTENSIONS",
    "integer_sample_bits",
    "read_image",
    "read_metadata",
    "write_image",
]


@dataclass(frozen=True)
class _Format:
    name: str
    dtypes: tuple[str, ...]
    channels: tuple[int, ...] | None  # None: any number
    metadata: str | None  # "attribute", "description" or None
    nonnegative: bool = False


_FORMATS: dict[str, _Format] = {
    ".exr": _Format("OpenEXR", ("float", "half"), None, "attribute"),
    ".hdr": _Format("Radiance HDR", ("float",), (3,), None, nonnegative=True),
    ".pfm": _Format("PFM", ("float",), (1, 3), None),
    ".png": _Format("PNG", ("uint8", "uint16"), (1, 2, 3, 4), "attribute"),
    ".tif": _Format("TIFF", ("uint8", "uint16", "float"), None, "description"),
    ".tiff": _Format("TIFF", ("uint8", "uint16", "float"), None, "description"),
}

#: Extensions :func:`write_image` writes (any format OpenImageIO reads can be read).
WRITABLE_EXTENSIONS: tuple[str, ...] = tuple(_FORMATS)

_DTYPE_ALIASES: dict[object, str] = {
    "uint8": "uint8",
    "uint16": "uint16",
    "half": "half",
    "float16": "half",
    "float": "float",
    "float32": "float",
    torch.uint8: "uint8",
    torch.uint16: "uint16",
    torch.float16: "half",
    torch.float32: "float",
}
_INT_MAX = {"uint8": 255, "uint16": 65535}
_NUMPY = {"uint8": np.uint8, "uint16": np.uint16, "half": np.float32, "float": np.float32}
_HALF_MAX = 65504.0


# --------------------------------------------------------------------------------------------------- helpers


def _path(path: object, what: str = "path") -> Path:
    if isinstance(path, str | os.PathLike):
        return Path(path)
    raise TypeError(f"{what} must be a str or os.PathLike; got {type(path).__name__}")


def _format_for_writing(path: Path) -> _Format:
    fmt = _FORMATS.get(path.suffix.lower())
    if fmt is None:
        raise ValueError(
            f"cannot write {path}: unsupported extension {path.suffix!r}; write one of {', '.join(WRITABLE_EXTENSIONS)}"
        )
    return fmt


def _config() -> oiio.ImageSpec:
    """Reader configuration: PFM rows the right way up, PNG alpha kept as stored (no premultiplication)."""
    config = oiio.ImageSpec()
    config.attribute("pnm:pfmflip", 1)
    config.attribute("oiio:UnassociatedAlpha", 1)
    return config


def _open(path: Path) -> oiio.ImageInput:
    if not path.exists():
        raise FileNotFoundError(errno.ENOENT, "image file not found", str(path))
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "expected an image file, got a directory", str(path))
    inp = oiio.ImageInput.open(str(path), _config())
    if inp is None:
        raise OSError(f"cannot read image {path}: {_errors()}")
    return inp


def _errors(obj: oiio.ImageInput | oiio.ImageOutput | None = None) -> str:
    """Collect (and so clear) the pending OpenImageIO error messages of ``obj`` and of the library."""
    messages = [obj.geterror() if obj is not None else "", oiio.geterror()]
    text = "; ".join(m.strip() for m in messages if m and m.strip())
    return text or "unknown OpenImageIO error"


def _channel_names(channels: int, exr: bool) -> list[str] | None:
    if channels <= 4:
        return None  # OpenImageIO's defaults: Y, (R, G), RGB, RGBA
    if not exr:
        return None
    # EXR stores channels sorted by name: zero-padded names keep their order.
    width = max(2, len(str(channels - 1)))
    return [f"ch{i:0{width}d}" for i in range(channels)]


def _resolve_dtype(dtype: object, fmt: _Format, path: Path, metadata: dict[str, Any]) -> str:
    if dtype is None:
        if fmt.dtypes[0] != "uint8":
            return fmt.dtypes[0]
        bits = metadata.get("bits")
        if isinstance(bits, int) and not isinstance(bits, bool) and 8 < bits <= 16:
            return "uint16"
        return "uint8"
    try:
        name = _DTYPE_ALIASES.get(dtype)
    except TypeError:
        name = None
    if name is None or name not in fmt.dtypes:
        raise ValueError(
            f"cannot write {path}: {fmt.name} ({path.suffix}) stores dtype {' or '.join(repr(d) for d in fmt.dtypes)}; "
            f"got {dtype!r}"
        )
    return name


def _pixels(image: torch.Tensor, path: Path) -> torch.Tensor:
    """Validate the image to write and return it as a CPU float64 (H, W, C) tensor."""
    if not isinstance(image, torch.Tensor):
        raise TypeError(f"image to write to {path} must be a torch.Tensor; got {type(image).__name__}")
    if image.dtype == torch.bool or image.is_complex():
        raise TypeError(f"image to write to {path} must hold real numbers; got dtype {image.dtype}")
    if image.dim() == 2:
        image = image.unsqueeze(0)
    if image.dim() == 4 and image.shape[0] == 1:
        image = image[0]
    if image.dim() == 4:
        raise ValueError(
            f"image to write to {path} must be one image: (C, H, W), (H, W) or a batch of one (1, C, H, W); got a "
            f"batch of {image.shape[0]}, shape {tuple(image.shape)} (write one file per image)"
        )
    if image.dim() != 3:
        raise ValueError(
            f"image to write to {path} must have shape (C, H, W), (H, W) or (1, C, H, W); got {tuple(image.shape)}"
        )
    c, h, w = image.shape
    if c < 1 or h < 1 or w < 1:
        raise ValueError(f"image to write to {path} must be non-empty; got shape {tuple(image.shape)}")
    return image.detach().to(device="cpu", dtype=torch.float64).permute(1, 2, 0).contiguous()


def _is_normalized(
    pixels: torch.Tensor, floating: bool, metadata: Mapping[str, Any], normalized: bool | None, path: Path
) -> bool:
    """Whether to store ``round(x * maximum)``: the rule of ``normalized=None`` (module docstring), or the caller's."""
    if normalized is not None:
        return normalized
    if "bits" in metadata or not floating:
        return False
    if not bool(torch.isfinite(pixels).all()):
        return False  # integer formats refuse NaN and Inf either way
    integers = bool((pixels == torch.floor(pixels)).all())
    lo, hi = float(pixels.min()), float(pixels.max())
    if not integers:
        return lo >= 0 and hi <= 1
    if lo >= 0 and hi == 1:
        warnings.warn(
            f"writing {path}: a float image holding only 0 and 1 is stored as the raw integers 0 and 1 (a dark "
            "frame of counts); pass normalized=True for a display image in [0, 1] (stored as 0 and the maximum), "
            "or normalized=False to say it holds counts",
            UserWarning,
            stacklevel=3,
        )
    return False


def _encode(pixels: torch.Tensor, kind: str, fmt: _Format, normalized: bool, path: Path) -> np.ndarray:
    """Check the values for the sample type and return the numpy array OpenImageIO will write as they are."""
    n_nan = int(torch.isnan(pixels).sum())
    n_inf = int(torch.isinf(pixels).sum())
    if kind in _INT_MAX:
        top = _INT_MAX[kind]
        if n_nan or n_inf:
            raise ValueError(
                f"cannot write {path} as {kind}: the image holds {n_nan} NaN and {n_inf} Inf values, which integer "
                "formats cannot store"
            )
        lo, hi = float(pixels.min()), float(pixels.max())
        if normalized:
            if lo < 0 or hi > 1:
                raise ValueError(
                    f"cannot write {path} with normalized=True: values must lie in [0, 1]; got min {lo}, max {hi}"
                )
            values = torch.round(pixels * top)
        else:
            if lo < 0 or hi > top:
                hint = " (use dtype='uint16')" if kind == "uint8" and hi <= 65535 and lo >= 0 else ""
                raise ValueError(
                    f"cannot write {path} as {kind}: raw integer values must lie in [0, {top}]; got min {lo}, "
                    f"max {hi}{hint} (or pass normalized=True for an image in [0, 1])"
                )
            frac = pixels - torch.floor(pixels)
            if bool((frac != 0).any()):
                bad = float(pixels.flatten()[int(frac.flatten().argmax())])
                raise ValueError(
                    f"cannot write {path} as {kind}: integer formats store raw integers; got non-integer value {bad} "
                    "(pass normalized=True for an image in [0, 1], or write a float format such as .exr)"
                )
            values = pixels
        return values.numpy().astype(_NUMPY[kind])
    if fmt.nonnegative:
        if n_nan or n_inf:
            raise ValueError(
                f"cannot write {path}: {fmt.name} stores finite values only; got {n_nan} NaN and {n_inf} Inf values"
            )
        lo = float(pixels.min())
        if lo < 0:
            raise ValueError(f"cannot write {path}: {fmt.name} stores values >= 0 only; got min {lo}")
    if kind == "half":
        finite = pixels[torch.isfinite(pixels)]
        if finite.numel() and float(finite.abs().max()) > _HALF_MAX:
            raise ValueError(
                f"cannot write {path} as half: values beyond +-{_HALF_MAX:g} would become Inf; got max |value| "
                f"{float(finite.abs().max())} (use dtype='float')"
            )
    return pixels.numpy().astype(np.float32)


# ------------------------------------------------------------------------------------------------ public API


def read_metadata(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read an image file's metadata without decoding its pixels.

    Args:
        path: an image file OpenImageIO reads.

    Returns:
        The file's attributes as OpenImageIO reports them (tuples as lists), overlaid with the metadata dict that
        :func:`write_image` stored, which comes back exactly as written.

    Raises:
        FileNotFoundError: the file does not exist.
        OSError: OpenImageIO cannot read it.

    Example:
        >>> import os, tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = write_image(os.path.join(folder, "m.exr"), torch.zeros(1, 2, 2), {"bits": 8, "taus": [1.0, 4.0]})
        ...     meta = read_metadata(path)
        >>> meta["bits"], meta["taus"]
        (8, [1.0, 4.0])
    """
    path = _path(path)
    inp = _open(path)
    try:
        return metadata_from_spec(inp.spec())
    finally:
        inp.close()


def integer_sample_bits(path: str | os.PathLike[str]) -> int | None:
    """The bits of an image file's integer samples (the widest channel's), or None for a float file (EXR, HDR, PFM,
    float TIFF). Only the header is read.

    Raises:
        FileNotFoundError: the file does not exist.
        OSError: OpenImageIO cannot read it.

    Example:
        >>> import os, tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     png = write_image(os.path.join(folder, "x.png"), torch.zeros(1, 2, 2), dtype="uint16")
        ...     exr = write_image(os.path.join(folder, "x.exr"), torch.zeros(1, 2, 2))
        ...     integer_sample_bits(png), integer_sample_bits(exr)
        (16, None)
    """
    inp = _open(_path(path))
    try:
        spec = inp.spec()
        formats = list(spec.channelformats) or [spec.format]
    finally:
        inp.close()
    bits = [8 * f.size() for f in formats if f.basetype in _INTEGER_BASETYPES]
    return max(bits) if bits else None


@overload
def read_image(
    path: str | os.PathLike[str],
    *,
    with_metadata: Literal[False] = False,
    normalized: bool = False,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor: ...


@overload
def read_image(
    path: str | os.PathLike[str],
    *,
    with_metadata: Literal[True],
    normalized: bool = False,
    dtype: torch.dtype = torch.float32,
) -> tuple[torch.Tensor, dict[str, Any]]: ...


@overload
def read_image(
    path: str | os.PathLike[str],
    *,
    with_metadata: bool,
    normalized: bool = False,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor | tuple[torch.Tensor, dict[str, Any]]: ...


def read_image(
    path: str | os.PathLike[str],
    *,
    with_metadata: bool = False,
    normalized: bool = False,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor | tuple[torch.Tensor, dict[str, Any]]:
    """Read an image file into a (C, H, W) float tensor; row 0 is the top of the image.

    Integer files (8/16-bit PNG and TIFF, ...) give their raw integer values, or values divided by the type's
    maximum (255, 65535) with ``normalized=True``; float files (EXR, HDR, PFM, float TIFF) give their values
    unchanged either way. Only the first subimage of multi-part files is read.

    Args:
        path: any file OpenImageIO reads.
        with_metadata: also return the metadata dict (see :func:`read_metadata`).
        normalized: scale integer samples into [0, 1].
        dtype: ``torch.float32`` (default) or ``torch.float64``. Integers above ``2**24`` (32-bit files) need
            float64 to stay exact.

    Returns:
        The image (C, H, W), or ``(image, metadata)`` with ``with_metadata=True``.

    Raises:
        FileNotFoundError: the file does not exist.
        OSError: OpenImageIO cannot read the file (unknown format, not an image, truncated or corrupted).
        TypeError: ``dtype`` is not float32 or float64.

    Example:
        >>> import os, tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = write_image(os.path.join(folder, "m.png"), torch.tensor([[[0.0, 7.0, 255.0]]]))
        ...     read_image(path)
        tensor([[[  0.,   7., 255.]]])
    """
    with_metadata = check_flag(with_metadata, "with_metadata")
    normalized = check_flag(normalized, "normalized")
    if dtype not in (torch.float32, torch.float64):
        raise TypeError(f"dtype must be torch.float32 or torch.float64; got {dtype}")
    path = _path(path)
    inp = _open(path)
    try:
        spec = inp.spec()
        if spec.deep:
            raise OSError(f"cannot read image {path}: deep images are not supported")
        base = spec.format.basetype
        integer = base in _INTEGER_BASETYPES and not spec.channelformats
        fmt = spec.format if integer else oiio.TypeDesc("float")
        pixels = inp.read_image(0, 0, 0, spec.nchannels, fmt)
        if pixels is None:
            raise OSError(f"cannot read image {path}: {_errors(inp)}")
        metadata = metadata_from_spec(spec) if with_metadata else {}
        # Files with fewer bits than their container (12-bit TIFF, 1/2/4-bit PNG) are expanded by OpenImageIO to
        # the container's full range; shift back to the stored integers.
        stored_bits = spec.get_int_attribute("oiio:BitsPerSample", 0)
        container_bits = 8 * spec.format.size()
        narrow = integer and base in _UNSIGNED and 0 < stored_bits < container_bits
        shift = container_bits - stored_bits if narrow else 0
    finally:
        inp.close()
    array = np.asarray(pixels)
    if array.ndim == 4:  # volume images: (z, y, x, c); keep the first slice
        array = array[0]
    if array.ndim == 2:
        array = array[:, :, None]
    if shift:
        array = np.right_shift(array, shift)
    tensor = torch.from_numpy(np.ascontiguousarray(array.astype(np.float64 if integer else np.float32)))
    if integer and normalized:
        top = 2 ** (container_bits - shift) - 1 if shift else _INTEGER_BASETYPES[base]
        tensor = tensor / float(top)
    image = tensor.permute(2, 0, 1).contiguous().to(dtype)
    if with_metadata:
        return image, metadata
    return image


_UNSIGNED = {oiio.UINT8, oiio.UINT16, oiio.UINT32}
_INTEGER_BASETYPES = {
    oiio.UINT8: 2**8 - 1,
    oiio.INT8: 2**7 - 1,
    oiio.UINT16: 2**16 - 1,
    oiio.INT16: 2**15 - 1,
    oiio.UINT32: 2**32 - 1,
    oiio.INT32: 2**31 - 1,
}


def write_image(
    path: str | os.PathLike[str],
    image: torch.Tensor,
    metadata: Mapping[str, Any] | None = None,
    *,
    dtype: str | torch.dtype | None = None,
    normalized: bool | None = None,
) -> Path:
    """Write a (C, H, W), (H, W) or (1, C, H, W) image atomically; the format follows the extension.

    See the module docstring for the formats, how values are stored (raw integers or normalised, and how
    ``normalized=None`` chooses) and which formats keep metadata.

    Args:
        path: destination; its extension picks the format (.exr, .hdr, .pfm, .png, .tif, .tiff). The folder must
            exist. An existing file is replaced.
        image: real-valued tensor on any device (floating or integer dtype).
        metadata: dict of JSON-compatible values stored with the image (EXR, PNG, TIFF).
        dtype: sample type: ``"float"``/``"half"`` (EXR), ``"uint8"``/``"uint16"`` (PNG, TIFF), ``"float"``
            (TIFF, HDR, PFM), or the matching torch dtype. Default: float for EXR/HDR/PFM; for PNG/TIFF 8-bit,
            or 16-bit when ``metadata["bits"]`` is 9 to 16.
        normalized: for integer formats, ``True`` stores ``round(image * maximum)`` of an image in [0, 1],
            ``False`` stores raw integers, and ``None`` (default) chooses: raw integers for a sensor's frame
            (``"bits"`` in ``metadata``), an integer tensor or a float tensor of integers; normalised for a float
            image in [0, 1] that holds other values. Ignored by float formats.

    Returns:
        The path written.

    Raises:
        TypeError: ``image`` is not a real tensor, or metadata holds a value that cannot be stored.
        ValueError: unsupported extension or dtype, wrong shape (a batch of more than one image) or channel count
            for the format, NaN/Inf or non-integers or values out of range for an integer format, negative values
            for HDR, magnitudes beyond the half-float range.
        FileNotFoundError: the destination folder does not exist.
        OSError: OpenImageIO failed to write.

    Warns:
        UserWarning: with ``normalized=None``, a float image that holds only 0 and 1 (and no ``"bits"`` in its
            metadata) for an integer format: it is stored as the raw integers 0 and 1.

    Example:
        >>> import os, tempfile
        >>> modulus = torch.tensor([[[0.0, 4095.0], [17.0, 256.0]]])
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = write_image(os.path.join(folder, "m.tif"), modulus, {"bits": 12})   # 16-bit, raw integers
        ...     torch.equal(read_image(path), modulus)
        True
    """
    path = _path(path)
    if normalized is not None:
        normalized = check_flag(normalized, "normalized")
    fmt = _format_for_writing(path)
    meta = check_metadata(metadata)
    kind = _resolve_dtype(dtype, fmt, path, meta)
    pixels = _pixels(image, path)
    scaled = kind in _INT_MAX and _is_normalized(pixels, image.is_floating_point(), meta, normalized, path)
    h, w, c = pixels.shape
    if fmt.channels is not None and c not in fmt.channels:
        allowed = " or ".join(str(n) for n in fmt.channels)
        raise ValueError(f"cannot write {path}: {fmt.name} stores {allowed} channels; got {c} (shape (C, H, W))")
    array = _encode(pixels, kind, fmt, scaled, path)
    folder = path.parent
    if not folder.is_dir():
        raise FileNotFoundError(errno.ENOENT, "destination folder does not exist", str(folder))

    spec = oiio.ImageSpec(w, h, c, oiio.TypeDesc(kind))
    names = _channel_names(c, fmt.name == "OpenEXR")
    if names is not None:
        spec.channelnames = tuple(names)
    spec.attribute("oiio:UnassociatedAlpha", 1)
    if fmt.name == "PNG" and not scaled:
        # Raw integers are data, not sRGB colours: "Raw" keeps OpenImageIO from writing the sRGB/gAMA/cHRM chunks,
        # and the text attribute lets read_metadata say so (OpenImageIO reports sRGB for any untagged PNG).
        spec.attribute("oiio:ColorSpace", DATA_COLORSPACE)
        spec.attribute(COLORSPACE_ATTRIBUTE, DATA_COLORSPACE)
    if meta:
        blob = json.dumps({BLOB_KEY: meta}, allow_nan=True)
        if fmt.metadata == "attribute":
            if fmt.name == "OpenEXR":
                for key, value in meta.items():
                    native_attribute(spec, key, value)
            spec.attribute(METADATA_ATTRIBUTE, blob)
        elif fmt.metadata == "description":
            spec.attribute("ImageDescription", blob)
        else:
            warnings.warn(
                f"{fmt.name} ({path.suffix}) cannot store metadata; dropped keys {sorted(meta)} when writing {path} "
                "(use .exr, .png or .tif, or a JSON sidecar)",
                UserWarning,
                stacklevel=2,
            )

    with atomic_file(path, keep_suffix=True) as tmp:
        _write_checked(tmp, spec, np.ascontiguousarray(array), fmt, path)
    return path


def _write_checked(tmp: Path, spec: oiio.ImageSpec, array: np.ndarray, fmt: _Format, path: Path) -> None:
    """Write ``array`` to ``tmp``, check what landed on the disk, and flush it there; ``OSError`` on any failure."""
    out = oiio.ImageOutput.create(str(tmp))
    if out is None:
        raise OSError(f"cannot write {path}: {_errors()}")
    if not out.open(str(tmp), spec):
        raise OSError(f"cannot write {path}: {_errors(out)}")
    ok = out.write_image(array)
    closed = out.close()
    if not ok or not closed:
        raise OSError(f"cannot write {path}: {_errors(out)}")
    if fmt.name == "PNG":
        _verify(tmp, array, path)
    fd = os.open(tmp, os.O_RDONLY)
    try:
        if os.fstat(fd).st_size == 0:
            raise _short_write(path, "the file is empty")
        os.fsync(fd)
    finally:
        os.close(fd)


def _verify(tmp: Path, array: np.ndarray, path: Path) -> None:
    """Read ``tmp`` back and compare it with ``array``: the PNG writer does not report a short write."""
    try:
        inp = _open(tmp)
    except OSError as exc:
        raise _short_write(path, str(exc)) from None
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, spec.format)
        problem = None if pixels is not None else _errors(inp)
    finally:
        inp.close()
    if problem is None and not np.array_equal(np.asarray(pixels).reshape(array.shape), array):
        problem = "the file read back differs from the image"
    if problem is not None:
        raise _short_write(path, problem)


def _short_write(path: Path, problem: str) -> OSError:
    """The error for a file that did not reach the disk whole; a full file system is named as such."""
    try:
        full = shutil.disk_usage(path.parent).free == 0
    except OSError:
        full = False
    if full:
        return OSError(errno.ENOSPC, f"cannot write {path}: {os.strerror(errno.ENOSPC)} ({problem})")
    return OSError(errno.EIO, f"cannot write {path}: {problem}")
