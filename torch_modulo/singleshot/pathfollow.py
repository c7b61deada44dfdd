"""Path following: the rollover counts ``k`` of a modulus image integrated along its most reliable pairs.

This is the default single-shot method (``method="guided"``) and the starting point of ``"fast"`` on smooth
images. :func:`quality_guided_k` is reliability-guided path following in the spirit of Herraez et al. (Applied
Optics 2002, the algorithm behind scikit-image's ``unwrap_phase``): every pixel gets a reliability from the
second differences of the wrapped image, neighbour pairs are joined from the most reliable down (Kruskal's
algorithm, i.e. a minimum spanning tree), and ``k`` is integrated along the tree with the wrapped
differences. It runs in whole-array numpy/scipy calls: the tree is scipy's ``minimum_spanning_tree`` and the
integration is pointer jumping (``log2`` of the tree depth passes over the pixels).

:func:`quality_guided_colour_k` does the same for the channels of one colour image together: the channels share
their edges, so the second differences of all channels are summed into one reliability and every channel is
integrated along the same tree (a step that is steep in one channel is avoided in all of them).

Memory: the pair graph is built directly as scipy's CSR arrays with int32 indices, the tree's parents are int32,
the second differences and the integration steps are computed in chunks of rows or pixels, and pointer jumping
runs on int32. An image of more than ``tile_pixels`` pixels builds its tree in blocks of rows: each block's own
minimum spanning forest, plus the pairs across the seams between blocks, hold a minimum spanning tree of the
whole image (a pair a block's forest leaves out is the heaviest on a cycle inside the block), so Kruskal then
runs on about one pair per pixel instead of two, and only one block's full pair graph exists at a time.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from torch_modulo.singleshot.grid import path_to_root, wrapped_difference

if TYPE_CHECKING:
    from collections.abc import Callable

    from scipy.sparse import csr_matrix

__all__ = [
    "quality_guided_colour_k",
    "quality_guided_k",
    "residue_density",
    "smooth_wrapped",
]


#: Pixels per chunk of the whole-image passes (second differences, integration steps): bounds their temporaries.
_CHUNK = 1 << 20


def residue_density(modulus: np.ndarray, bits: int) -> float:
    """Share of 2 x 2 loops whose wrapped differences do not sum to zero (phase-unwrapping *residues*).

    Without residues the wrapped differences integrate to the same image along every path, so path following
    recovers a smooth image exactly; natural scenes with edges steeper than half a period have many.
    """
    m = np.asarray(modulus, dtype=np.int64)
    if m.shape[0] < 2 or m.shape[1] < 2:
        return 0.0
    period = 1 << bits
    loop = (
        wrapped_difference(m[:-1, 1:] - m[:-1, :-1], period)
        + wrapped_difference(m[1:, 1:] - m[:-1, 1:], period)
        + wrapped_difference(m[1:, :-1] - m[1:, 1:], period)
        + wrapped_difference(m[:-1, :-1] - m[1:, :-1], period)
    )
    return float(np.count_nonzero(loop) / loop.size)


def _second_difference_quality(modulus: np.ndarray, period: int) -> np.ndarray:
    """Herraez's ``D``: root sum of squared wrapped second differences (lower is more reliable).

    Border pixels use the second differences that fit inside the image; a pixel with none gets 0.
    """
    h, w = modulus.shape
    m = modulus if np.issubdtype(modulus.dtype, np.floating) else np.asarray(modulus, dtype=np.int64)
    acc = np.zeros((h, w))
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        # Second difference along (dy, dx) at the centre pixel: wrap(I[-1] - I[0]) - wrap(I[0] - I[+1]).
        y0, y1 = dy, h - dy
        x0, x1 = max(dx, -dx), w - max(dx, -dx)
        if y1 <= y0 or x1 <= x0:
            continue
        centre = m[y0:y1, x0:x1]
        before = m[y0 - dy : y1 - dy, x0 - dx : x1 - dx]
        after = m[y0 + dy : y1 + dy, x0 + dx : x1 + dx]
        sd = wrapped_difference(before - centre, period) - wrapped_difference(centre - after, period)
        acc[y0:y1, x0:x1] += sd.astype(np.float64) ** 2
    return np.sqrt(acc)


def _difficulty(planes: list[np.ndarray], period: int) -> np.ndarray:
    """The sum over ``planes`` of :func:`_second_difference_quality`, in blocks of rows (the same values).

    Each block is computed with one row of context on either side, so its temporaries stay small.
    """
    h, w = planes[0].shape
    out = np.empty((h, w))
    rows = max(1, _CHUNK // max(1, w))
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        a, b = max(0, r0 - 1), min(h, r1 + 1)
        acc = _second_difference_quality(planes[0][a:b], period)
        for m in planes[1:]:
            acc += _second_difference_quality(m[a:b], period)
        out[r0:r1] = acc[r0 - a : r1 - a]
    return out


def _pair_weights(difficulty: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weights ``1 / (R_i + R_j)``, ``R = 1 / (D + 1e-3)``, of the right (H, W - 1) and down (H - 1, W) pairs.

    Kruskal joins the most reliable pair first; every weight is > 0 (zero means "no edge" to scipy).
    """
    inv_d = 1.0 / (difficulty + 1e-3)
    right = inv_d[:, :-1] + inv_d[:, 1:]
    np.reciprocal(right, out=right)
    down = inv_d[:-1, :] + inv_d[1:, :]
    np.reciprocal(down, out=down)
    return right, down


def _pair_graph(weight_right: np.ndarray, weight_down: np.ndarray) -> csr_matrix:
    """The 4-neighbour pairs of an (H, W) grid as a CSR matrix: row ``p`` holds ``(p, p + 1)``, then ``(p, p + W)``.

    ``weight_right`` is (H, W - 1) and ``weight_down`` (H - 1, W), both > 0. The arrays are the ones scipy builds
    from the pair lists of :func:`~torch_modulo.singleshot.grid.pair_indices` (``coo_matrix(...).tocsr()``, int32
    indices, the same entries in the same order, so Kruskal breaks ties in the same way), without the int64 pair
    lists and the COO copy.
    """
    from scipy.sparse import csr_matrix

    h = weight_down.shape[0] + 1
    w = weight_right.shape[1] + 1
    n = h * w
    right = np.zeros((h, w), dtype=bool)
    right[:, :-1] = True
    down = np.zeros((h, w), dtype=bool)
    down[:-1, :] = True
    indptr = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(right.ravel(), out=indptr[1:], dtype=np.int32)
    indptr[1:] += np.cumsum(down.ravel(), dtype=np.int32)
    slots = np.stack([right, down], axis=-1)  # (H, W, 2): the right pair, then the down pair, of every pixel
    data = np.empty((h, w, 2))
    data[:, :-1, 0] = weight_right
    data[:-1, :, 1] = weight_down
    data = data[slots]
    ids = np.arange(n, dtype=np.int32).reshape(h, w)
    indices = np.empty((h, w, 2), dtype=np.int32)
    indices[..., 0] = ids + 1
    indices[..., 1] = ids + w
    del ids
    indices = indices[slots]
    return csr_matrix((data, indices, indptr), shape=(n, n))


def _forest_graph(
    pair_weights: Callable[[int, int], tuple[np.ndarray, np.ndarray]], h: int, w: int, tile_pixels: int
) -> csr_matrix:
    """The pairs that can be in a minimum spanning tree, found in blocks of rows of at most ``tile_pixels`` pixels.

    ``pair_weights(r0, r1)`` gives the weights (> 0) of the right (r1 - r0, W - 1) and down (r1 - r0 - 1, W) pairs
    among rows ``r0 .. r1 - 1`` of the (H, W) grid. Each block keeps the pairs of its own minimum spanning forest
    (a pair left out of it is the heaviest on a cycle inside the block, so some minimum spanning tree of the whole
    image does without it), plus every pair across the seam to the next block: about one pair per pixel instead
    of two, and only one block's pair graph at a time. Returned as a CSR matrix like :func:`_pair_graph`'s (rows
    in order, columns sorted in a row).
    """
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import minimum_spanning_tree

    n = h * w
    rows = max(1, tile_pixels // w)
    indptr = np.zeros(n + 1, dtype=np.int32)
    parts: list[tuple[np.ndarray, np.ndarray]] = []  # (columns, weights) of every block, in row order
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        right, down = pair_weights(r0, min(h, r1 + 1))  # one more row: the pairs across the seam
        forest = minimum_spanning_tree(_pair_graph(right[: r1 - r0], down[: r1 - r0 - 1]), overwrite=True)
        first = np.repeat(np.arange(r0 * w, r1 * w, dtype=np.int32), np.diff(forest.indptr))
        second = forest.indices + np.int32(r0 * w)
        weights = forest.data
        if r1 < h:
            seam = np.arange((r1 - 1) * w, r1 * w, dtype=np.int32)
            first = np.concatenate([first, seam])
            second = np.concatenate([second, seam + np.int32(w)])
            weights = np.concatenate([weights, down[r1 - r0 - 1]])
            order = np.lexsort((second, first))
            first, second, weights = first[order], second[order], weights[order]
        indptr[r0 * w + 1 : r1 * w + 1] = np.bincount(first - np.int32(r0 * w), minlength=(r1 - r0) * w)
        parts.append((second, weights))
        del right, down, forest, first
    np.cumsum(indptr, out=indptr)
    indices = np.empty(int(indptr[-1]), dtype=np.int32)
    data = np.empty(int(indptr[-1]))
    at = 0
    for i in range(len(parts)):  # copy block by block, freeing each block's arrays as it is copied
        second, weights = parts[i]
        parts[i] = (np.empty(0, dtype=np.int32), np.empty(0))
        indices[at : at + second.size] = second
        data[at : at + second.size] = weights
        at += second.size
    return csr_matrix((data, indices, indptr), shape=(n, n))


def kruskal_graph(
    pair_weights: Callable[[int, int], tuple[np.ndarray, np.ndarray]], h: int, w: int, tile_pixels: int = 0
) -> csr_matrix:
    """The pairs a minimum spanning tree of the (H, W) grid is taken from, with ``pair_weights`` as for
    :func:`_forest_graph`: every pair (:func:`_pair_graph`) up to ``tile_pixels`` pixels (or always with 0), above
    the pairs that survive the blocks' own spanning forests (:func:`_forest_graph`)."""
    if tile_pixels and h * w > tile_pixels:
        return _forest_graph(pair_weights, h, w, tile_pixels)
    return _pair_graph(*pair_weights(0, h))


def _reliability_graph(difficulty: np.ndarray, tile_pixels: int = 0) -> csr_matrix:
    """The 4-neighbour pairs of Herraez's ``D`` with their weights, as a CSR matrix for Kruskal.

    Up to ``tile_pixels`` pixels (or always with 0) every pair (:func:`_pair_graph`); above, the pairs that
    survive the blocks' own spanning forests (:func:`_forest_graph`), which hold a minimum spanning tree of the
    same graph.
    """
    h, w = difficulty.shape
    return kruskal_graph(lambda r0, r1: _pair_weights(difficulty[r0:r1]), h, w, tile_pixels)


def _tree_parents(graph: csr_matrix, root: int = 0) -> np.ndarray:
    """int32 parent of every pixel in the minimum spanning tree of ``graph`` (Kruskal), rooted at ``root``.

    The root, and pixels no pair reaches, are their own parents. ``graph`` is overwritten.
    """
    from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

    tree = minimum_spanning_tree(graph, overwrite=True)
    _, parent = breadth_first_order(tree, root, directed=False, return_predecessors=True)
    del tree
    orphans = np.flatnonzero(parent < 0)
    parent[orphans] = orphans
    return parent


def _reliability_tree(difficulty: np.ndarray, tile_pixels: int = 0) -> np.ndarray:
    """Parent of every pixel in the most reliable spanning tree (Kruskal on 4-neighbour pairs), rooted at pixel 0.

    ``difficulty`` is Herraez's ``D`` (lower is more reliable); a pair's weight is ``1 / (R_i + R_j)`` with
    ``R = 1 / (D + 1e-3)``, so the minimum spanning tree joins the most reliable pairs first. Without
    ``tile_pixels`` (or up to that many pixels) it is the tree of
    :func:`~torch_modulo.singleshot.grid.spanning_tree` on the pairs of ``pair_indices``, with int32 indices;
    above, a minimum spanning tree of the same graph built from blocks of rows (:func:`_forest_graph`), which
    differs from it only where pairs of equal weight tie.
    """
    return _tree_parents(_reliability_graph(difficulty, tile_pixels))


def _integrate(modulus: np.ndarray, parent: np.ndarray, period: int) -> np.ndarray:
    """:func:`~torch_modulo.singleshot.grid.integrate_wrapped` (the same values) with int32 steps and sums.

    The steps are found in chunks of pixels and pointer jumping runs on int32 arrays, which needs a third of the
    memory; the counts of one plane cannot exceed its pixel count, so int32 holds them.
    """
    flat = modulus.ravel()
    step = np.empty(flat.size, dtype=np.int32)
    for s in range(0, flat.size, _CHUNK):
        d = flat[s : s + _CHUNK] - flat[parent[s : s + _CHUNK]]
        step[s : s + _CHUNK] = np.rint((wrapped_difference(d, period) - d) / period)
    k = path_to_root(parent, step)
    del step
    return k.astype(np.int64).reshape(modulus.shape)


def smooth_wrapped(modulus: np.ndarray, period: int, sigma: float) -> np.ndarray:
    """Denoise a wrapped image: Gaussian-smooth its phasor ``exp(2 pi i I_m / period)`` (``sigma`` pixels).

    Returns real values in ``[0, period)``. Smoothing the phasor, not the values, keeps the rollovers intact.
    """
    from scipy.ndimage import gaussian_filter

    phase = np.asarray(modulus, dtype=np.float64) * (2 * np.pi / period)
    re = gaussian_filter(np.cos(phase), sigma, mode="nearest")
    im = gaussian_filter(np.sin(phase), sigma, mode="nearest")
    out = np.mod(np.arctan2(im, re) * (period / (2 * np.pi)), period)
    return np.where(out >= period, 0.0, out)  # np.mod of a tiny negative number rounds up to ``period``


def quality_guided_k(modulus: np.ndarray, bits: int) -> np.ndarray:
    """Rollover counts from reliability-guided path following (Herraez et al. 2002), up to a constant.

    Args:
        modulus: (H, W) integer-valued array in ``[0, 2**bits)``.
        bits: the sensor bit depth ``N``.

    Returns:
        int64 (H, W) ``k``, with ``k = 0`` at the first pixel (the caller re-anchors it).
    """
    return quality_guided_colour_k(np.asarray(modulus)[None], bits)[0]


def quality_guided_colour_k(moduli: np.ndarray, bits: int, denoise: float = 0.0, tile_pixels: int = 0) -> np.ndarray:
    """Path following for the channels of one image on one shared tree: reliabilities summed over channels.

    With one channel this is :func:`quality_guided_k`. A step that is steep in one channel is avoided in all of
    them, which helps where an edge that rolls one channel over is visible in another.

    With ``denoise > 0`` the tree and the integration use the wrapped images smoothed by :func:`smooth_wrapped`
    (Gaussian of ``denoise`` pixels), and each pixel then takes the ``k`` that puts its own count nearest to the
    smooth estimate: robust to noise in the low bits (the paper's Fig. 14) at the price of fine detail.

    Images of more than ``tile_pixels`` pixels (when it is not 0) build the tree from blocks of rows of at most
    that many pixels (:func:`_forest_graph`): a minimum spanning tree of the same pairs and weights, in less memory.

    Args:
        moduli: (C, H, W) integer-valued array in ``[0, 2**bits)``: the channels of one image.
        bits: the sensor bit depth ``N``.
        denoise: the smoothing's standard deviation in pixels (0: none).
        tile_pixels: the most pixels of one block of the tree (0: the whole image at once).

    Returns:
        int64 (C, H, W) ``k``, with ``k = 0`` at the first pixel of every channel (the caller re-anchors it).

    Example:
        >>> ramp = np.add.outer(np.arange(4), np.arange(6)) * 100  # 0 .. 800 counts
        >>> k = quality_guided_colour_k(ramp[None] % 256, 8)
        >>> bool(np.array_equal(ramp % 256 + 256 * k[0], ramp))
        True
    """
    moduli = np.asarray(moduli, dtype=np.int64)  # no copy when it is int64 already
    c, h, w = moduli.shape
    if h * w <= 1:
        return np.zeros((c, h, w), dtype=np.int64)
    period = 1 << bits
    planes = [smooth_wrapped(m, period, denoise) for m in moduli] if denoise > 0 else list(moduli)
    graph = _reliability_graph(_difficulty(planes, period), tile_pixels)
    parent = _tree_parents(graph)
    del graph
    k = np.empty((c, h, w), dtype=np.int64)
    for ci, m in enumerate(planes):
        k[ci] = _integrate(m, parent, period)
    del parent
    if denoise > 0:  # each pixel's k nearest to the smooth estimate, one channel at a time
        for ci, m in enumerate(planes):
            k[ci] = np.rint((m + period * k[ci] - moduli[ci]) / period)
    return k
