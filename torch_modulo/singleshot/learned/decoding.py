"""The learned method's exact integer decoders: from every pair's jump costs to rollover counts ``k``.

:func:`decode_jumps` joins the most confident pairs first (a maximum-likelihood spanning tree, Kruskal over
``-log p``) and integrates ``k`` along the tree, so the output is always ``I_m + k 2^N`` with integer ``k``; the
probability of the least likely pair on a pixel's path to the reference region is its confidence.
:func:`refine_band` then lowers the total cost of every pair's jump, :func:`pair_costs`, by binary min-cut moves
(option ``max_cuts``).
"""

from __future__ import annotations

import maxflow
import numpy as np
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

from torch_modulo.singleshot.grid import grid_components, path_to_root
from torch_modulo.singleshot.pathfollow import kruskal_graph

__all__ = [
    "DIRECTIONS",
    "MAX_COST",
    "TREE_PIXELS",
    "decode_edges",
    "decode_jumps",
    "pair_costs",
    "refine_band",
    "refine_cut",
    "table_indices",
]

#: The two pair directions as ``(first end, second end)`` slices of a plane: to the right, and down.
DIRECTIONS = ((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :]))

#: Cost of a jump outside ``-J .. J`` (and the most any jump costs): ``-log`` of a negligible probability.
MAX_COST = 30.0

#: A pair this likely (``p >= 0.99``) joins the reference region of :func:`decode_jumps`' confidence.
_CONFIDENT = 0.99

#: :func:`decode_jumps` builds the spanning tree of a plane of more pixels than this from blocks of rows of at most
#: this many (as ``"guided"``'s ``tile_pixels``): a minimum spanning tree of the same pairs in less memory, which
#: may differ from the whole-image tree where pairs cost the same.
TREE_PIXELS = 2**22


def decode_edges(
    modulus: np.ndarray, logp: np.ndarray, bits: int, max_jump: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Integer ``k`` of one plane from its jump log-probabilities: :func:`decode_jumps` of the most likely jumps.

    Args:
        modulus: (H, W) integer-valued moduli.
        logp: (2, 2J + 1, H, W) jump log-probabilities (:func:`predict_edges`; direction 0: to the right, 1: down).
        bits: the sensor bit depth ``N``.
        max_jump: ``J`` (default: from ``logp``).

    Example:
        >>> m = np.array([[200, 10, 60]])
        >>> logp = np.full((2, 3, 1, 3), -30.0); logp[:, 1] = 0.0  # sure that every wrapped step is right
        >>> decode_edges(m, logp, 8)[0].tolist()
        [[0, 1, 1]]
    """
    j = (logp.shape[1] - 1) // 2 if max_jump is None else int(max_jump)
    best = logp.argmax(axis=1)
    cost = np.maximum(-np.take_along_axis(logp, best[:, None], 1)[:, 0], 0.0)
    return decode_jumps(modulus, best.astype(np.int64) - j, cost, bits)


def decode_jumps(modulus: np.ndarray, jump: np.ndarray, cost: np.ndarray, bits: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer ``k`` of one plane from every pair's most likely jump: a maximum-likelihood spanning tree.

    Kruskal's algorithm joins the pairs from the most confident (``cost = -log p`` smallest) and ``k`` is integrated
    along the tree with each pair's jump, so ``I_m + k 2^N`` is exact for integer ``k``.

    The confidence of a pixel is the probability of the least likely pair on its tree path to the reference region
    (the largest region joined by pairs with ``p >= 0.99``). The tree maximises that bottleneck over all paths, so
    it is the pixel's best chain of evidence; it is at least 0.99 inside the reference region.

    Args:
        modulus: (H, W) integer-valued moduli.
        jump: (2, H, W) integer jumps ``n`` of every pair (direction 0: to the right neighbour, 1: to the one below;
            the last column's and last row's entries are ignored).
        cost: (2, H, W) their costs ``-log p >= 0``.
        bits: the sensor bit depth ``N``.

    Returns:
        ``(k, confidence)``: int64 (H, W) rollover counts with ``k = 0`` at a pixel of the reference region (the
        caller anchors them) and float64 (H, W) confidences in ``(0, 1]``.

    Example:
        >>> m = np.array([[200, 10, 60]])
        >>> k, confidence = decode_jumps(m, np.zeros((2, 1, 3), int), np.full((2, 1, 3), 0.5), 8)
        >>> k.tolist(), confidence.round(2).tolist()
        ([[0, 1, 1]], [[1.0, 0.61, 0.61]])
    """
    m = np.asarray(modulus, dtype=np.int64)
    h, w = m.shape
    n = h * w
    if n <= 1:
        return np.zeros((h, w), dtype=np.int64), np.ones((h, w))
    cost = np.asarray(cost)

    def pair_weights(r0: int, r1: int) -> tuple[np.ndarray, np.ndarray]:
        # scipy reads a stored 0 as "no edge": every cost is shifted a little (the tree is the same).
        right = np.add(cost[0, r0:r1, :-1], 1e-9, dtype=np.float64)
        return right, np.add(cost[1, r0 : r1 - 1, :], 1e-9, dtype=np.float64)

    tree = minimum_spanning_tree(kruskal_graph(pair_weights, h, w, TREE_PIXELS), overwrite=True)
    # The reference region, the largest one joined by sure pairs, is joined by the tree's own sure pairs: a minimum
    # spanning tree's path between two pixels has the smallest largest cost of all paths.
    sure = tree.copy()
    sure.data = (sure.data <= -np.log(_CONFIDENT) + 1e-9).astype(np.int8)
    sure.eliminate_zeros()
    _, labels = connected_components(sure, directed=False)
    del sure
    root = int(np.argmax(labels == np.bincount(labels).argmax()))
    del labels
    _, parent = breadth_first_order(tree, root, directed=False, return_predecessors=True)  # int32
    del tree
    orphans = np.flatnonzero(parent < 0)  # the root, and pixels no pair reaches
    parent[orphans] = orphans
    # Every pixel's step to its parent, k_child - k_parent, and the cost of the pair between them, by chunks. A
    # step is at most J + 1 periods, so int32 holds every sum along a path unless the image is huge.
    flat_m, flat_jump, flat_cost = m.ravel(), np.asarray(jump).reshape(2, n), cost.reshape(2, n)
    period, half = 1 << bits, 1 << (bits - 1)
    bound = (int(np.abs(flat_jump).max(initial=0)) + 1) * n
    k_step = np.zeros(n, dtype=np.int32 if bound < 2**31 else np.int64)
    c_step = np.zeros(n, dtype=np.float32)
    for s in range(0, n, 1 << 20):
        child = np.arange(s, min(n, s + (1 << 20)), dtype=np.int64)
        par = parent[child]
        first = np.minimum(child, par)  # the pair is stored at its first pixel (left or upper end)
        direction = (np.abs(par - child) == w).astype(np.int64)
        jump_c = flat_jump[direction, first].astype(np.int64)
        d = flat_m[np.maximum(child, par)] - flat_m[first]
        step = (np.mod(d + half, period) - half + period * jump_c - d) // period  # k_second - k_first
        k_step[child] = np.where(child == first, -step, step)
        c_step[child] = flat_cost[direction, first]
    k_step[orphans] = 0
    c_step[orphans] = 0.0
    del orphans
    k = path_to_root(parent, k_step).astype(np.int64)
    del k_step
    confidence = np.exp(-path_to_root(parent, c_step, np.maximum).astype(np.float64))
    return k.reshape(h, w), confidence.reshape(h, w)


def table_indices(
    m: np.ndarray, k: np.ndarray, first: np.ndarray, period: int, shift_a: int = 0, shift_b: int = 0
) -> list[np.ndarray]:
    """Per direction, the jump ``n`` every pair takes under ``k`` (moved by ``shift_a`` at each pair's first end and
    ``shift_b`` at its second), as an index ``n - first[d]`` into its table of jump costs (see :func:`pair_costs`).

    Returns:
        ``[right, down]``: (H, W - 1) and (H - 1, W) int64 indices (outside ``0 .. K - 1`` for jumps off the table).

    Example:
        >>> m, k = np.array([[10, 20]]), np.array([[0, 1]])  # the pair steps by 10 + 256 counts: jump 1
        >>> [n.tolist() for n in table_indices(m, k, np.full((2, 1, 2), -1), 256)]
        [[[2]], []]
    """
    out = []
    for direction, (a, b) in enumerate(DIRECTIONS):
        restored_a, restored_b = m[a] + period * (k[a] + shift_a), m[b] + period * (k[b] + shift_b)
        wd = np.mod(m[b] - m[a] + period // 2, period) - period // 2
        out.append((restored_b - restored_a - wd) // period - first[direction][a])
    return out


def pair_costs(
    m: np.ndarray,
    k: np.ndarray,
    table: np.ndarray,
    first: np.ndarray,
    period: int,
    shift_a: int = 0,
    shift_b: int = 0,
) -> list[np.ndarray]:
    """Per direction, the cost of the jump every pair takes under ``k`` moved by ``shift_a`` at each pair's first end
    and ``shift_b`` at its second: what the cuts and the level moves weigh.

    Args:
        m: (H, W) int64 moduli.
        k: (H, W) int64 rollover counts.
        table: (2, K, H, W) costs ``-log p`` of K consecutive jumps per pair (direction 0: to the right, 1: down):
            ``table[d, i]`` is the cost of the jump ``first[d] + i``.
        first: (2, H, W) integers: the jump of ``table``'s first entry per pair.
        period: ``2^N``.
        shift_a: periods added to ``k`` at every pair's first end (left or upper pixel).
        shift_b: periods added at its second end.

    Returns:
        ``[right, down]``: the (H, W - 1) and (H - 1, W) costs ``table[d, n - first[d]]`` of every pair's jump ``n``,
        :data:`MAX_COST` for a jump outside the table.

    Example:
        >>> m, k = np.array([[10, 20]]), np.array([[0, 1]])  # the pair steps by 10 + 256 counts: jump 1
        >>> table = np.zeros((2, 3, 1, 2)); table[0, :, 0, 0] = [5.0, 1.0, 2.0]  # jumps -1, 0, 1
        >>> [c.tolist() for c in pair_costs(m, k, table, np.full((2, 1, 2), -1), 256)]
        [[[2.0]], []]
    """
    size = table.shape[1]
    out = []
    for direction, n in enumerate(table_indices(m, k, first, period, shift_a, shift_b)):
        a = DIRECTIONS[direction][0]
        inside = (n >= 0) & (n < size)
        c = np.take_along_axis(table[direction][(slice(None), *a)], np.clip(n, 0, size - 1)[None], 0)[0]
        out.append(np.where(inside, c, MAX_COST))
    return out


def refine_cut(modulus: np.ndarray, k: np.ndarray, logp: np.ndarray, bits: int, max_cuts: int = 6) -> np.ndarray:
    """:func:`refine_band` with every jump's cost: from (2, 2J + 1, H, W) jump log-probabilities.

    Example:
        >>> m = np.array([[200, 10, 60]])
        >>> logp = np.full((2, 3, 1, 3), -30.0); logp[:, 1] = 0.0  # sure that every wrapped step is right
        >>> refine_cut(m, np.array([[0, 0, 1]]), logp, 8, max_cuts=2).tolist()
        [[0, 1, 1]]
    """
    j = (logp.shape[1] - 1) // 2
    first = np.full((2, *np.shape(modulus)), -j, dtype=np.int64)
    return refine_band(modulus, k, -np.asarray(logp, dtype=np.float64), first, bits, max_cuts)


#: :func:`refine_band` moves superpixels: pixels joined by pairs this sure (``-log p < 0.01``) inside blocks of
#: ``_BLOCK x _BLOCK`` pixels move together.
_SURE, _BLOCK = 0.01, 4


def refine_band(
    modulus: np.ndarray,
    k: np.ndarray,
    table: np.ndarray,
    first: np.ndarray,
    bits: int,
    max_cuts: int = 6,
    block: int = _BLOCK,
) -> np.ndarray:
    """Lower ``sum over pairs of -log p(jump)`` over integer ``k`` by binary moves ``k <- k + delta x`` (min cuts).

    Where :func:`decode_jumps` trusts one tree, this weighs every pair, so a confident but wrong tree pair that
    shifts a whole region is outvoted by the region's other borders (loop consistency). Moves alternate
    ``delta = +1, -1``; a pair term that is not graph-representable for a move is dropped from its graph (as
    in PUMA) and a move is kept only if the exact cost drops. Stops after ``max_cuts`` cuts or two moves in a row
    that do not help. The graph's nodes are superpixels, not pixels: the pixels of a ``block x block`` square
    joined by pairs the network is sure of at the starting ``k`` (``-log p < 0.01``) move as one. A superpixel
    still ends wherever the network is unsure, and the graph is tens of times smaller (``block=1``: pixels).

    Args:
        modulus: (H, W) integer-valued moduli.
        k: int64 (H, W) starting rollover counts (e.g. from :func:`decode_jumps`).
        table: (2, K, H, W) costs ``-log p`` of K consecutive jumps per pair (direction 0: to the right, 1: down):
            ``table[d, i]`` is the cost of the jump ``first[d] + i``; jumps outside cost :data:`MAX_COST`, and
            costs are clipped to it.
        first: (2, H, W) integers: the jump of ``table``'s first entry per pair.
        bits: the sensor bit depth ``N``.
        max_cuts: the most minimum cuts.
        block: the side of the squares superpixels stay inside.

    Returns:
        int64 (H, W) rollover counts.
    """
    m = np.asarray(modulus, dtype=np.int64)
    k = np.asarray(k, dtype=np.int64).copy()
    first = np.asarray(first, dtype=np.int64)
    h, w = m.shape
    period = 1 << bits
    table = np.clip(np.asarray(table, dtype=np.float32), 0.0, MAX_COST)

    def costs(kk: np.ndarray, shift_a: int = 0, shift_b: int = 0) -> list:
        return pair_costs(m, kk, table, first, period, shift_a, shift_b)

    same = costs(k)
    rows, cols = np.arange(h)[:, None] // block, np.arange(w)[None, :] // block
    square = rows * (-(-w // block)) + cols
    joined = [(c < _SURE) & (square[a] == square[b]) for (a, b), c in zip(DIRECTIONS, same, strict=True)]
    n, labels = grid_components(*joined)
    labels = labels.reshape(h, w)
    # Pairs inside a superpixel keep their jump under every move: only the pairs between superpixels enter a graph.
    ends = [(labels[a][x], labels[b][x], x) for (a, b) in DIRECTIONS for x in [labels[a] != labels[b]]]
    nodes = np.arange(n)
    energy = sum(float(c.sum(dtype=np.float64)) for c in same)
    failures = 0
    for cut in range(max_cuts):
        delta = 1 if cut % 2 == 0 else -1
        second_moves, first_moves = costs(k, 0, delta), costs(k, delta, 0)
        graph = maxflow.Graph[float](n, sum(int(x.sum()) for _, _, x in ends))
        graph.add_nodes(n)
        unary = np.zeros(n)
        for (ra, rb, x), c_a, c_b, c_f in zip(ends, same, second_moves, first_moves, strict=True):
            c_a, c_b, c_f = c_a[x].astype(np.float64), c_b[x].astype(np.float64), c_f[x].astype(np.float64)
            unary += np.bincount(ra, c_f - c_a, n) + np.bincount(rb, c_a - c_f, n)
            pair = np.maximum(c_b + c_f - 2 * c_a, 0.0)
            graph.add_edges(ra, rb, pair, np.zeros(pair.size))
        graph.add_grid_tedges(nodes, np.maximum(unary, 0.0), np.maximum(-unary, 0.0))
        graph.maxflow()
        trial = k + delta * graph.get_grid_segments(nodes)[labels]
        trial_costs = costs(trial)
        new = sum(float(c.sum(dtype=np.float64)) for c in trial_costs)
        if new < energy - 1e-9 * max(1.0, energy):
            k, same, energy, failures = trial, trial_costs, new, 0
        else:
            failures += 1
            if failures >= 2:
                break
    return k
