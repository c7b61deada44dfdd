"""Anchoring: fix the one free constant of the rollover counts ``k`` that single-shot unwrapping leaves.

Every single-shot method recovers ``k`` up to one constant per image and channel (the wrapped differences do not
change when all of ``k`` moves by one). :func:`anchor_k` chooses it: the darkest large connected region gets
``k = 0`` and nothing is left below it (``k >= 0``, since a sensor cannot read negative counts).
"""

from __future__ import annotations

import numpy as np

from torch_modulo.singleshot.grid import pair_slices

__all__ = ["anchor_k"]


def anchor_k(
    k: np.ndarray,
    min_fraction: float = 1e-3,
    *,
    modulus: np.ndarray | None = None,
    bits: int | None = None,
    large_fraction: float = 0.03,
) -> np.ndarray:
    """Shift ``k`` so that the darkest large connected region has ``k = 0``, and clip what falls below to 0.

    Levels are tried from the lowest up; a level anchors the image when its largest 4-connected region holds at
    least ``min_fraction`` of the pixels (and at least one pixel) and, if ``modulus`` is given, either holds at
    least ``large_fraction`` of them or meets the rest of the image smoothly: more than 80% of its border pairs
    step by less than half a period in the restored image ``modulus + k 2**bits``. Anchoring on the minimum
    instead would let a handful of noisy pixels one level low shift the whole image. The size and border tests
    keep bright regions that a solver put too low from anchoring the image, while the true darkest region, a
    few percent of a smooth ramp say, still does. If no level passes, the lowest level with a region of
    ``min_fraction`` anchors (the rule without ``modulus``); if none has one, the level of the largest region
    does. Pixels left below 0 would mean negative counts, which a sensor cannot read, so they are set to 0.

    Args:
        k: integer (H, W) rollover counts, determined up to a global constant.
        min_fraction: the smallest region, as a share of the pixels, that may anchor the image.
        modulus: the (H, W) modulus ``k`` belongs to; enables the border test.
        bits: the bit depth of ``modulus`` (required with it).
        large_fraction: with ``modulus``, regions at least this large anchor without the border test.

    Returns:
        int64 (H, W) counts ``>= 0``.

    Example:
        >>> anchor_k(np.array([[3, 3, 4, 5], [3, 3, 4, 2]]), 0.25).tolist()  # the lone 2 is too small to anchor
        [[0, 0, 1, 2], [0, 0, 1, 0]]
    """
    from scipy import ndimage

    k = np.asarray(k, dtype=np.int64)
    if k.size == 0:
        return k.copy()
    restored = None
    if modulus is not None:
        if bits is None:
            raise ValueError("anchor_k needs bits with modulus")
        restored = np.asarray(modulus, dtype=np.int64) + (k << bits)
    need = max(1, int(np.ceil(min_fraction * k.size)))
    large = max(need, int(np.ceil(large_fraction * k.size)))
    best_size, best_level = -1, int(k.min())
    first_large = None  # the lowest level with a region of ``need`` pixels: the fallback when no level passes
    for level in np.unique(k):
        lab, n = ndimage.label(k == level)
        if not n:
            continue
        sizes = np.bincount(lab.ravel())
        sizes[0] = 0
        region = int(sizes.argmax())
        size = int(sizes[region])
        if size > best_size:
            best_size, best_level = size, int(level)
        if size < need:
            continue
        if first_large is None:
            first_large = int(level)
        if restored is None or size >= large or _smooth_border(lab == region, restored, 1 << (bits - 1)):
            return np.maximum(k - level, 0)
    return np.maximum(k - (first_large if first_large is not None else best_level), 0)


def _smooth_border(region: np.ndarray, restored: np.ndarray, half: int) -> bool:
    """Whether more than 80% of the 4-neighbour pairs leaving ``region`` step by less than ``half``."""
    smooth = steep = 0
    for off in ((0, 1), (1, 0)):
        first, second = pair_slices(*region.shape, off)
        leaving = region[first] != region[second]
        small = np.abs(restored[first] - restored[second])[leaving] < half
        smooth += int(small.sum())
        steep += int(small.size - small.sum())
    return smooth > 4 * steep
