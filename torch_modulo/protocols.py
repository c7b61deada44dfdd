"""The measurement protocols of BENCHMARKS.md, shared by the benchmarks, the research harness and the examples.

- :func:`load_scene`: read an HDR file, zero NaN/Inf and negatives, and downsample it by whole-pixel area averaging
  until its longer side is at most ``max_side`` (:func:`downsample_area`).
- :func:`protocol_a`: the paper's single-shot setting: luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` scaled so
  that its 99.9th percentile is ``peak`` (4095: a 12-bit scene), clipped to ``[0, peak]`` and floored.
- :func:`protocol_b`: the UnModNet setting: RGB min-max scaled to [0, 1], the exposure ``e`` chosen by bisection so
  that ``share`` (20%) of the pixels roll over (``floor(clip(x e, 0, 1) * peak) >= period``) in at least one
  channel; the counts are ``floor(clip(x e, 0, 1) * peak)`` per channel.

The modulus of either is ``counts mod period`` (256: 8 bits).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import torch

from torch_modulo._checks import check_floating, check_image_shape
from torch_modulo.io import read_image

__all__ = ["HDR_SUFFIXES", "downsample_area", "list_scenes", "load_scene", "protocol_a", "protocol_b"]

#: File endings of the radiance maps the protocols read.
HDR_SUFFIXES = (".exr", ".hdr")


def list_scenes(folder: str | os.PathLike[str]) -> list[Path]:
    """Every .exr/.hdr file below ``folder``, sorted by path."""
    return sorted(p for p in Path(folder).rglob("*") if p.suffix.lower() in HDR_SUFFIXES)


def downsample_area(image: torch.Tensor, max_side: int) -> torch.Tensor:
    """Average whole-pixel blocks by the smallest integer factor that brings the longer side to <= ``max_side``.

    Rows and columns that do not fill a block are dropped.

    Example:
        >>> downsample_area(torch.arange(16.0).view(1, 4, 4), 2)
        tensor([[[ 2.5000,  4.5000],
                 [10.5000, 12.5000]]])
    """
    check_floating(image, "image")
    check_image_shape(image, "image", min_dims=3, max_dims=3)
    if max_side < 1:
        raise ValueError(f"max_side must be >= 1; got {max_side}")
    c, h, w = image.shape
    f = max(1, math.ceil(max(h, w) / max_side))
    if f == 1:
        return image
    h2, w2 = h // f, w // f
    return image[:, : h2 * f, : w2 * f].reshape(c, h2, f, w2, f).mean(dim=(2, 4))


def load_scene(path: str | os.PathLike[str], max_side: int | None = 512) -> torch.Tensor:
    """(C, H, W) float64 radiance of an HDR file: RGB (first three channels) or one luminance channel.

    NaN, infinities and negative values (lossy compression) become 0; with ``max_side`` the image is area-averaged
    down (:func:`downsample_area`).
    """
    image = read_image(path)
    image = image[:3] if image.shape[0] >= 3 else image[:1]
    image = torch.nan_to_num(image.double(), nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0.0)
    return downsample_area(image, max_side) if max_side else image


def protocol_a(image: torch.Tensor, peak: float = 4095.0) -> torch.Tensor:
    """(1, H, W) counts: luminance scaled so its 99.9th percentile is ``peak``, clipped to [0, peak], floored.

    Example:
        >>> protocol_a(torch.full((3, 2, 2), 0.5)).flatten().tolist()
        [4095.0, 4095.0, 4095.0, 4095.0]
    """
    check_floating(image, "image")
    check_image_shape(image, "image", min_dims=3, max_dims=3)
    if image.shape[0] == 1:
        y = image[0]
    elif image.shape[0] == 3:
        y = 0.2126 * image[0] + 0.7152 * image[1] + 0.0722 * image[2]
    else:
        raise ValueError(f"image must have 1 or 3 channels; got {image.shape[0]}")
    p = float(np.percentile(y.detach().cpu().double().numpy(), 99.9))
    if p <= 0:
        p = float(y.max()) or 1.0
    return torch.floor(torch.clamp(y * (peak / p), 0.0, peak))[None]


def protocol_b(image: torch.Tensor, share: float = 0.2, peak: float = 4095.0, period: float = 256.0) -> torch.Tensor:
    """(C, H, W) counts of min-max scaled RGB at the exposure that makes ``share`` of the pixels roll over.

    Example:
        >>> counts = protocol_b(torch.linspace(0, 1, 100).view(1, 1, 100))
        >>> round(float((counts >= 256).double().mean()), 2)
        0.2
    """
    check_floating(image, "image")
    check_image_shape(image, "image", min_dims=3, max_dims=3)
    if not 0.0 < share < 1.0:
        raise ValueError(f"share must be in (0, 1); got {share}")
    lo, hi = float(image.min()), float(image.max())
    x = (image - lo) / (hi - lo) if hi > lo else torch.zeros_like(image)

    def counts(e: float) -> torch.Tensor:
        return torch.floor(torch.clamp(x * e, 0.0, 1.0) * peak)

    def rolled(e: float) -> float:
        return float((counts(e) >= period).any(dim=0).double().mean())

    e_lo, e_hi = 1e-6, 1.0
    while rolled(e_hi) < share and e_hi < 2.0**40:
        e_lo, e_hi = e_hi, e_hi * 2
    for _ in range(60):
        mid = math.sqrt(e_lo * e_hi)
        if rolled(mid) < share:
            e_lo = mid
        else:
            e_hi = mid
    return counts(e_hi)
