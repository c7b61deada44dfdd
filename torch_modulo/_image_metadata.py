"""Image metadata for :mod:`torch_modulo.io`: the JSON dict stored with an image, and native attributes.

A metadata dict (string keys, JSON-compatible values) is stored as one JSON text under :data:`METADATA_ATTRIBUTE`
(or in TIFF's ``ImageDescription``); simple values are also written as native EXR attributes that other tools
show, except names OpenImageIO or the format interpret (:data:`RESERVED`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import OpenImageIO as oiio
import torch

__all__ = [
    "BLOB_KEY",
    "COLORSPACE_ATTRIBUTE",
    "DATA_COLORSPACE",
    "METADATA_ATTRIBUTE",
    "RESERVED",
    "check_metadata",
    "decode_blob",
    "jsonable",
    "metadata_from_spec",
    "native_attribute",
    "to_python",
]

#: The JSON attribute that holds the metadata dict (EXR and PNG); TIFF keeps it in ``ImageDescription``.
METADATA_ATTRIBUTE = "torch_modulo:metadata"
BLOB_KEY = "torch_modulo_metadata"

#: The text attribute that records the colour space of a PNG written with raw integers (:data:`DATA_COLORSPACE`):
#: such a file has no colour chunks, and OpenImageIO reports every PNG without them as sRGB.
COLORSPACE_ATTRIBUTE = "torch_modulo:colorspace"
#: OpenImageIO's name for samples that are data, not colours (``oiio:ColorSpace``).
DATA_COLORSPACE = "Raw"


#: Attribute names OpenImageIO or the format interpret; metadata keys with these names (or with a ':') are kept
#: only in the JSON text, never written as native attributes that would change how the file is written.
RESERVED = {
    "compression",
    "name",
    "datetime",
    "orientation",
    "pixelaspectratio",
    "screenwindowcenter",
    "screenwindowwidth",
    "imagedescription",
    "documentname",
    "software",
    "artist",
    "copyright",
    "xresolution",
    "yresolution",
    "resolutionunit",
    "planarconfig",
    "channelnames",
    "datawindow",
    "displaywindow",
    "lineorder",
    "type",
    "version",
    "chunkcount",
    "tiles",
    "channels",
    "capdate",
    "utcoffset",
}


def to_python(value: Any) -> Any:
    if isinstance(value, tuple):
        return [to_python(v) for v in value]
    return value


def decode_blob(text: object) -> dict[str, Any] | None:
    if not isinstance(text, str) or BLOB_KEY not in text:
        return None
    try:
        data = json.loads(text)
    except ValueError:
        return None
    if isinstance(data, dict) and isinstance(data.get(BLOB_KEY), dict):
        return data[BLOB_KEY]
    return None


def metadata_from_spec(spec: oiio.ImageSpec) -> dict[str, Any]:
    """The file's attributes overlaid with the stored dict; a data tag (:data:`COLORSPACE_ATTRIBUTE`) becomes
    ``oiio:ColorSpace``."""
    native: dict[str, Any] = {}
    stored: dict[str, Any] | None = None
    colorspace: str | None = None
    for attribute in spec.extra_attribs:
        name = attribute.name
        if name == METADATA_ATTRIBUTE:
            stored = decode_blob(attribute.value)
            continue
        if name == COLORSPACE_ATTRIBUTE:
            colorspace = attribute.value if isinstance(attribute.value, str) else None
            continue
        if name == "ImageDescription":
            blob = decode_blob(attribute.value)
            if blob is not None:
                stored = stored if stored is not None else blob
                continue
        native[name] = to_python(attribute.value)
    if colorspace is not None:
        native["oiio:ColorSpace"] = colorspace
    if stored is not None:
        native.update(stored)
    return native


def _check_text(text: str, where: str) -> None:
    """Refuse text that has no UTF-8 form (a lone surrogate such as ``"\\ud83d"``): no file format stores it."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as error:
        raise ValueError(f"metadata text {where} cannot be stored: {error.reason} in {text!r}") from None


def jsonable(value: Any, where: str) -> Any:
    """A JSON-ready copy of a metadata value; tensors and numpy values become lists and numbers."""
    if isinstance(value, torch.Tensor):
        return jsonable(value.detach().cpu().tolist(), where)
    if isinstance(value, np.ndarray | np.generic):
        return jsonable(value.tolist(), where)
    if isinstance(value, str):
        _check_text(value, where)
        return value
    if value is None or isinstance(value, bool | int | float):
        return value
    if isinstance(value, list | tuple):
        return [jsonable(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, Mapping):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise TypeError(f"metadata keys must be strings; got {k!r} in {where}")
            _check_text(k, f"a key of {where}")
            out[k] = jsonable(v, f"{where}[{k!r}]")
        return out
    raise TypeError(
        f"metadata value {where} has type {type(value).__name__}, which cannot be stored; use numbers, strings, "
        "booleans, None, lists or dicts"
    )


def check_metadata(metadata: Mapping[str, Any] | None) -> dict[str, Any]:
    if metadata is None:
        return {}
    if not isinstance(metadata, Mapping):
        raise TypeError(f"metadata must be a dict; got {type(metadata).__name__}")
    return jsonable(metadata, "metadata")


def native_attribute(spec: oiio.ImageSpec, key: str, value: Any) -> None:
    """Write a simple metadata value as a native attribute (EXR); anything else stays in the JSON text only."""
    if ":" in key or key.lower() in RESERVED or key.startswith("oiio") or not key:
        return
    if isinstance(value, bool):
        spec.attribute(key, int(value))
    elif isinstance(value, int):
        if -(2**31) <= value < 2**31:
            spec.attribute(key, value)
    elif isinstance(value, float):
        if math.isfinite(value):
            spec.attribute(key, value)
    elif isinstance(value, str):
        spec.attribute(key, value)
    elif (
        isinstance(value, list)
        and value
        and all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    ):
        spec.attribute(key, oiio.TypeDesc(f"float[{len(value)}]"), tuple(float(v) for v in value))
