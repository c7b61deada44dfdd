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
    # Every level at once (labelling each level's mask separately costs levels x pixels): the regions of all
    # levels, their sizes and levels, and for every level its largest region, the first in raster order on a tie
    # (the one ``ndimage.label(k == level)`` numbers first).
    labels, count = _level_regions(k)
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    region_level = np.empty(count + 1, dtype=np.int64)
    region_level[labels.ravel()] = k.ravel()
    order = np.lexsort((-sizes[1:], region_level[1:])) + 1  # by level, then largest first; stable: label order
    sorted_level = region_level[order]
    largest = order[np.r_[True, sorted_level[1:] != sorted_level[:-1]]]  # every level's largest, levels ascending
    levels, level_size = region_level[largest], sizes[largest]
    best_level = int(levels[level_size.argmax()])  # the lowest level with the largest region of all
    candidates = np.flatnonzero(level_size >= need)
    if not candidates.size:
        return np.maximum(k - best_level, 0)
    if restored is None:
        return np.maximum(k - levels[candidates[0]], 0)
    big = candidates[level_size[candidates] >= large]
    if big.size:  # levels above the first large one are never tried
        candidates = candidates[candidates <= big[0]]
    small = candidates[level_size[candidates] < large]
    if small.size:  # the border test, only where a level needs it (``1 << (bits - 1)`` only then)
        assert bits is not None  # checked with the modulus above
        smooth = _smooth_borders(labels, count, restored, 1 << (bits - 1))
        passing = small[smooth[largest[small]]]
        if passing.size:
            return np.maximum(k - levels[passing[0]], 0)
    if big.size:
        return np.maximum(k - levels[big[0]], 0)
    return np.maximum(k - levels[candidates[0]], 0)  # no level passes: the lowest with a region of ``need``


def _level_regions(k: np.ndarray) -> tuple[np.ndarray, int]:
    """Label the 4-connected regions of equal ``k``, all levels in one pass: (H, W) int32 labels 1..count, count.

    ``ndimage.label`` joins any two foreground neighbours, whatever their values, so ``k`` is spread onto a grid
    of twice the size: pixel ``(y, x)`` at ``(2y, 2x)``, and between two neighbours a link that is foreground
    only where their ``k`` is equal (the odd-odd cells stay background). Each label's first cell in raster order
    is a pixel (a link follows the pixel on its left or above), so the labels keep the raster order of the
    regions' first pixels, as ``ndimage.label(k == level)`` numbers one level's regions. The grid costs 4 bytes
    (bool) and its labels 16 bytes (int32) per pixel, well under a sparse graph of the pairs.
    """
    from scipy import ndimage

    height, width = k.shape
    grid = np.zeros((2 * height - 1, 2 * width - 1), dtype=bool)
    grid[::2, ::2] = True
    grid[::2, 1::2] = k[:, 1:] == k[:, :-1]
    grid[1::2, ::2] = k[1:] == k[:-1]
    labels, count = ndimage.label(grid)
    del grid
    return np.ascontiguousarray(labels[::2, ::2]), int(count)


def _smooth_borders(labels: np.ndarray, count: int, restored: np.ndarray, half: int) -> np.ndarray:
    """Per region (by label), whether more than 80% of the 4-neighbour pairs leaving it step by less than ``half``.

    Neighbours with different labels differ in ``k`` (equal ones share a region), so every such pair leaves both
    of its regions and counts for each: one pass over the pairs gives the borders of all regions.
    """
    smooth = np.zeros(count + 1, dtype=np.int64)
    border = np.zeros(count + 1, dtype=np.int64)
    for off in ((0, 1), (1, 0)):
        first, second = pair_slices(labels.shape[0], labels.shape[1], off)
        leaving = labels[first] != labels[second]
        ends = (labels[first][leaving], labels[second][leaving])
        small = np.abs(restored[first][leaving] - restored[second][leaving]) < half
        for end in ends:
            border += np.bincount(end, minlength=count + 1)
            smooth += np.bincount(end[small], minlength=count + 1)
    return smooth > 4 * (border - smooth)
