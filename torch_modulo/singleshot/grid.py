"""Pixel-grid helpers shared by the single-shot modules: neighbour pairs, wrapped steps, trees and components.

Everything here works on numpy arrays of one (H, W) plane, with flat pixel indices ``y * W + x``:

- neighbour pairs: :func:`pair_offsets` enumerates each unordered pair of a neighbourhood once,
  :func:`pair_slices` and :func:`pair_indices` give both ends of every pair at one offset, :func:`dilate` grows a
  pixel mask by one neighbourhood step;
- wrapped steps: :func:`wrapped_difference` is the difference a smooth image most likely had;
- graphs of pixels: :func:`components` (connected components), :func:`spanning_tree` (minimum spanning tree as a
  parent array), :func:`path_to_root` (folding values up a tree by pointer jumping) and
  :func:`integrate_wrapped` (rollover counts along a tree).
"""

from __future__ import annotations

import numpy as np

from torch_modulo._checks import check_choice

__all__ = [
    "components",
    "dilate",
    "grid_components",
    "integrate_wrapped",
    "pair_indices",
    "pair_offsets",
    "pair_slices",
    "path_to_root",
    "spanning_tree",
    "wrapped_difference",
]

#: Neighbour offsets (dy, dx) covering every unordered pair of a neighbourhood exactly once.
_OFFSETS: dict[int, tuple[tuple[int, int], ...]] = {
    4: ((0, 1), (1, 0)),
    8: ((0, 1), (1, 0), (1, 1), (1, -1)),
}


def pair_offsets(neighborhood: int = 8) -> tuple[tuple[int, int], ...]:
    """The offsets ``(dy, dx)`` that enumerate each unordered neighbour pair once.

    Args:
        neighborhood: 8 (the paper, Fig. 4b) or 4.

    Returns:
        ``((0, 1), (1, 0))`` for 4; the same plus the diagonals ``(1, 1), (1, -1)`` for 8.

    Raises:
        ValueError: ``neighborhood`` is not 4 or 8 (a list, a bool or a string included).

    Example:
        >>> pair_offsets(4)
        ((0, 1), (1, 0))
    """
    return _OFFSETS[int(check_choice(neighborhood, "neighborhood", tuple(_OFFSETS)))]


def pair_slices(height: int, width: int, offset: tuple[int, int]) -> tuple[tuple[slice, slice], tuple[slice, slice]]:
    """Slices ``(first, second)`` so that ``x[first]`` and ``x[second]`` are the two ends of every pair.

    Pixel ``(y, x)`` of ``first`` pairs with ``(y + dy, x + dx)`` of ``second``; pairs leaving the image are
    dropped (no wrap-around).

    Example:
        >>> first, second = pair_slices(2, 3, (0, 1))
        >>> image = np.arange(6).reshape(2, 3)
        >>> image[first].tolist(), image[second].tolist()
        ([[0, 1], [3, 4]], [[1, 2], [4, 5]])
    """
    dy, dx = offset
    first = (slice(0, height - dy), slice(max(0, -dx), width - max(0, dx)))
    second = (slice(dy, height), slice(max(0, dx), width + min(0, dx)))
    return first, second


def pair_indices(height: int, width: int, offset: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices (int64) of both ends of every pair at ``offset``, in the order of :func:`pair_slices`.

    Example:
        >>> [a.tolist() for a in pair_indices(2, 2, (1, 0))]
        [[0, 1], [2, 3]]
    """
    ids = np.arange(height * width, dtype=np.int64).reshape(height, width)
    first, second = pair_slices(height, width, offset)
    return ids[first].ravel(), ids[second].ravel()


def dilate(mask: np.ndarray, offsets: tuple[tuple[int, int], ...]) -> np.ndarray:
    """Grow a boolean (H, W) pixel mask by one neighbourhood step (the pairs of ``offsets``); a new array.

    Example:
        >>> dilate(np.array([[False, True, False]]), pair_offsets(4)).tolist()
        [[True, True, True]]
    """
    h, w = mask.shape
    grown = mask.copy()
    for off in offsets:
        first, second = pair_slices(h, w, off)
        grown[first] |= mask[second]
        grown[second] |= mask[first]
    return grown


def wrapped_difference(d: np.ndarray, period: int) -> np.ndarray:
    """Wrap differences into ``[-period / 2, period / 2)``: the difference a smooth image most likely had.

    Example:
        >>> wrapped_difference(np.array([-200, 100, 128, 300]), 256).tolist()
        [56, 100, -128, 44]
    """
    half = period // 2
    return np.mod(d + half, period) - half


def components(n: int, rows: np.ndarray, cols: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected components of an undirected graph on ``n`` nodes given by its edge lists ``(rows, cols)``.

    Returns:
        ``(count, labels)``: the number of components and the component of every node, as scipy returns them.

    Example:
        >>> count, labels = components(4, np.array([0, 2]), np.array([1, 3]))
        >>> count, labels.tolist()
        (2, [0, 0, 1, 1])
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    graph = coo_matrix((np.ones(rows.size, dtype=np.int8), (rows, cols)), shape=(n, n)).tocsr()
    return connected_components(graph, directed=False)


def grid_components(right: np.ndarray, down: np.ndarray) -> tuple[int, np.ndarray]:
    """Connected components of an (H, W) pixel grid whose pairs are joined where ``right`` ((H, W - 1): a pixel and
    its right neighbour) and ``down`` ((H - 1, W): a pixel and the one below) are true.

    The same as :func:`components` on those pairs, labels included (numbered by their first pixel in raster order),
    several times faster: the grid and its joined pairs become one binary image of (2H - 1, 2W - 1) cells, labelled
    by ``scipy.ndimage.label``.

    Returns:
        ``(count, labels)``: the number of components and the (H W,) int32 component of every pixel.

    Raises:
        ValueError: the shapes of ``right`` and ``down`` are not those of one grid's pairs.

    Example:
        >>> count, labels = grid_components(np.array([[True, False]]), np.zeros((0, 3), bool))
        >>> count, labels.tolist()
        (2, [0, 0, 1])
    """
    from scipy import ndimage

    right, down = np.asarray(right, dtype=bool), np.asarray(down, dtype=bool)
    if right.ndim != 2 or down.ndim != 2:
        raise ValueError(f"right {right.shape} and down {down.shape} are not the pairs of one pixel grid")
    h, w = right.shape[0], down.shape[1]
    if right.shape != (h, max(w - 1, 0)) or down.shape != (max(h - 1, 0), w):
        raise ValueError(f"right {right.shape} and down {down.shape} are not the pairs of one pixel grid")
    if h * w == 0:
        return 0, np.zeros(0, dtype=np.int32)
    cells = np.zeros((2 * h - 1, 2 * w - 1), dtype=bool)
    cells[::2, ::2] = True
    cells[::2, 1::2] = right
    cells[1::2, ::2] = down
    labels, count = ndimage.label(cells)  # 4-connected; each component's first cell is a pixel
    return int(count), labels[::2, ::2].ravel() - 1


def path_to_root(parent: np.ndarray, values: np.ndarray, combine: np.ufunc = np.add) -> np.ndarray:
    """Fold ``values`` from every node up to its root by pointer jumping (``log2`` of the tree depth passes).

    ``combine`` is an associative ufunc: ``np.add`` sums the values on the path (integration), ``np.maximum`` takes
    their largest (a bottleneck). Roots have ``parent[i] == i`` and must hold the neutral value (0).

    Example:
        >>> path_to_root(np.array([0, 0, 1]), np.array([0, 2, 5])).tolist()  # a chain 2 -> 1 -> 0
        [0, 2, 7]
    """
    parent = parent.copy()
    total = values.copy()
    while True:
        grand = parent[parent]
        if np.array_equal(grand, parent):
            return total
        total = combine(total, total[parent])
        parent = grand


def spanning_tree(n: int, first: np.ndarray, second: np.ndarray, weights: np.ndarray, root: int = 0) -> np.ndarray:
    """Parent of every node in the minimum spanning tree of the pairs ``(first, second)``, rooted at ``root``.

    ``weights`` must be > 0 (scipy reads 0 as "no edge"). A node the pairs do not reach is its own parent.

    Example:
        >>> spanning_tree(3, np.array([0, 1, 0]), np.array([1, 2, 2]), np.array([1.0, 1.0, 5.0])).tolist()
        [0, 0, 1]
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, minimum_spanning_tree

    tree = minimum_spanning_tree(coo_matrix((weights, (first, second)), shape=(n, n)).tocsr())
    _, pred = breadth_first_order(tree, root, directed=False, return_predecessors=True)
    return np.where(pred < 0, np.arange(n), pred)


def integrate_wrapped(modulus: np.ndarray, parent: np.ndarray, period: int) -> np.ndarray:
    """``k`` along the tree: ``I_i - I_parent`` equals the wrapped difference of the modulus (integer or real).

    Args:
        modulus: (H, W) wrapped values in ``[0, period)``.
        parent: flat parent index of every pixel (e.g. from :func:`spanning_tree`); roots get ``k = 0``.
        period: ``2**bits``.

    Returns:
        int64 (H, W) rollover counts relative to the roots.

    Example:
        >>> integrate_wrapped(np.array([[200, 10, 60]]), np.array([0, 0, 1]), 256).tolist()
        [[0, 1, 1]]
    """
    flat = modulus.ravel()
    d = flat - flat[parent]
    step = np.rint((wrapped_difference(d, period) - d) / period).astype(np.int64)
    return path_to_root(parent, step).reshape(modulus.shape)
