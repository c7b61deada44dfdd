"""Binary-move graph cuts for the single-shot energy (paper Sec. 4.2), on numpy planes.

Everything here works on one (H, W) plane of integer-valued float64 or int64 counts; the torch front end
(:func:`torch_modulo.singleshot.unwrap_single`) splits batches and channels into such planes.

A move ``k <- k + s * delta`` with binary ``delta`` turns each pair term ``V(d)``, ``d = I_i - I_j``, into
``E00 = E11 = V(d)``, ``E10 = V(d + s P)``, ``E01 = V(d - s P)`` (``P = 2**bits``). With ``A = E10 - E00`` and
``B = E01 - E00`` the term is ``A [x_i = 1, x_j = 0] + B [x_i = 0, x_j = 1]`` up to a constant, and it is built as

- ``A >= 0`` and ``B >= 0`` (every smooth pair, ``|d| <= x0``): two directed edges, ``j -> i`` with capacity
  ``A`` and ``i -> j`` with capacity ``B``, and no terminal link. This represents the term exactly and keeps
  the terminal links to the fringes, which makes the max-flow much faster than the textbook construction;
- otherwise the negative one of ``A``, ``B`` becomes a pair of terminal links and ``A + B`` the one remaining
  edge. Where ``A + B < 0`` the term is not graph-representable (Eq. 4) and that edge gets weight 0, as in the
  paper and PUMA (Bioucas-Dias and Valadao 2007). The dropped edge only raises the graph's energy of the
  labelling where the pair separates the "wrong" way, so the cut is a majoriser of the true move energy that is
  exact at ``delta = 0``: a minimum cut never raises the true energy. The term kept exact is the larger
  decrease, so the construction does not depend on the order in which pairs are enumerated.

A move is kept only if the true energy, computed exactly from ``A`` and ``B``, drops. Capacities come from
lookup tables indexed by the integer difference ``d`` (or are computed directly when the range of ``d`` is
too wide for a table), and every graph is built with whole-array calls (``Graph.add_edges``,
``Graph.add_grid_tedges``), never per-pixel Python loops.

Three solvers share this machinery:

- :func:`solve_pixels`: the paper's algorithm (``method="paper"``), one node per pixel (``rel_tol`` can end it
  early).
- :func:`solve_windows`: the same moves cut inside small windows with the rest of the image fixed, up and down, only
  where something can still improve. The max-flow's cost grows much faster than the graph on these images,
  so many small cuts are far cheaper than one global cut; they find local moves only.
- :func:`solve_fast`: the schedule of ``method="fast"``: global pixel moves until one gains less than
  ``rel_tol`` of the energy, then windows.

:func:`pixel_move` (one global move), :class:`PairTerms` (the pair terms of a move and their graph
decomposition) and :func:`add_terminals` are the building blocks, public for solvers built on them.
"""

from __future__ import annotations

import time
import warnings
from typing import Any

import maxflow
import numpy as np

from torch_modulo.singleshot.energy import EnergyParams, energy_np, potential_np
from torch_modulo.singleshot.grid import dilate, pair_slices
from torch_modulo.singleshot.spec import MoveStats

__all__ = [
    "MoveStats",
    "PairTerms",
    "add_terminals",
    "move_delta_e",
    "pixel_move",
    "plane_energy",
    "solve_fast",
    "solve_pixels",
    "solve_windows",
]

#: A lookup table of pair terms is used when the range of differences is at most this many entries
#: (or at most 4 entries per pixel pair, whichever is larger); beyond it the terms are computed directly.
_TABLE_LIMIT = 1 << 20


class PairTerms:
    """``A(d)``, ``B(d)`` and their graph decomposition for a move of ``step`` periods.

    Differences ``d`` are integers in ``[-span, span]``; when the span is small enough the five quantities are
    tabulated once and looked up, otherwise they are computed directly.

    Args:
        p: the potential's parameters.
        step: the move's step in periods.
        span: the largest ``|d|`` that will be looked up.
        pairs: the number of pairs of the graph (a table of up to 4 entries per pair is always allowed).

    Example:
        >>> terms = PairTerms(EnergyParams.make(8), 1, 300, 10)
        >>> [float(v) for v in terms.ab(terms.index(np.array([0])))[0]]  # A(0) = V(256) - V(0)
        [13.29152]
    """

    def __init__(self, p: EnergyParams, step: int, span: int, pairs: int) -> None:
        self.p = p
        self.shift = float(step * p.period)
        self.span = int(span)
        self.table = 2 * self.span + 1 <= max(_TABLE_LIMIT, 4 * pairs)
        if self.table:
            d = np.arange(-self.span, self.span + 1, dtype=np.float64)
            self.a, self.b = self._ab(d)
            self.cij, self.cji, self.m = self.decompose(self.a, self.b)

    def _ab(self, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = potential_np(d, self.p)
        return potential_np(d + self.shift, self.p) - v, potential_np(d - self.shift, self.p) - v

    @staticmethod
    def decompose(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Capacities ``i -> j``, ``j -> i`` and the unary coefficient ``m`` (``+m`` on i, ``-m`` on j)."""
        neg = np.minimum(a, b) < 0
        a_low = a < b
        w = np.maximum(a + b, 0.0)
        cij = np.where(neg, np.where(a_low, w, 0.0), b)
        cji = np.where(neg, np.where(a_low, 0.0, w), a)
        m = np.where(neg, np.where(a_low, a, -b), 0.0)
        return cij, cji, m

    def index(self, d: np.ndarray) -> np.ndarray:
        """Turn integer differences into table indices (in place when possible)."""
        if self.table:
            d = d.astype(np.intp, copy=False)
            d += self.span
        return d

    def ab(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``A`` and ``B`` at the indices from :meth:`index`."""
        if self.table:
            return self.a[idx], self.b[idx]
        return self._ab(idx.astype(np.float64))

    def graph_terms(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`decompose` of the terms at the indices from :meth:`index`."""
        if self.table:
            return self.cij[idx], self.cji[idx], self.m[idx]
        return self.decompose(*self._ab(idx.astype(np.float64)))


def _span(restored: np.ndarray) -> int:
    if restored.size == 0:
        return 0
    return int(restored.max() - restored.min())


def plane_energy(restored: np.ndarray, p: EnergyParams, offsets: tuple[tuple[int, int], ...]) -> float:
    """Eq. 3 of one integer-valued (H, W) plane, via a table of ``V`` when the range allows it."""
    h, w = restored.shape
    span = _span(restored)
    if 2 * span + 1 > max(_TABLE_LIMIT, 4 * restored.size):
        return energy_np(restored, p, offsets)
    table = potential_np(np.arange(-span, span + 1, dtype=np.float64), p)
    total = 0.0
    for off in offsets:
        first, second = pair_slices(h, w, off)
        d = restored[first] - restored[second]
        d += span
        total += float(table[d].sum())
    return total


def _accept(delta_e: float, energy: float) -> bool:
    """A move is kept only if it lowers the energy by more than rounding noise."""
    return delta_e < -1e-9 * max(1.0, abs(energy))


def add_terminals(graph: maxflow.GraphFloat, unary: np.ndarray) -> None:
    """``unary[n] * x_n``: a source link of ``u`` where ``u > 0``, a sink link of ``-u`` where ``u < 0``."""
    nz = np.flatnonzero(unary)
    if nz.size:
        u = unary[nz]
        graph.add_grid_tedges(nz, np.maximum(u, 0.0), np.maximum(-u, 0.0))


#: Pixels per chunk when a pixel graph's edges are assembled (bounds the temporary arrays).
_CHUNK = 1 << 16


def pixel_move(
    restored: np.ndarray, p: EnergyParams, offsets: tuple[tuple[int, int], ...], step: int, span: int | None = None
) -> tuple[np.ndarray, float]:
    """One binary move ``k <- k + step * delta`` on the pixel grid: ``delta`` (bool, (H, W)) and the exact energy
    change.

    Edges are added node by node (all pairs of a pixel together) rather than offset by offset: the max-flow
    walks each node's arcs, and keeping them close in memory makes it faster. They are assembled in chunks of
    rows so that the temporaries stay small next to the graph itself.

    Args:
        restored: int64 (H, W) plane ``I_m + k 2**bits``.
        p: the potential's parameters.
        offsets: neighbour offsets from :func:`~torch_modulo.singleshot.grid.pair_offsets`.
        step: the move's step in periods.
        span: ``restored.max() - restored.min()`` when the caller knows it (computed otherwise).
    """
    if span is None:
        span = _span(restored)
    h, w = restored.shape
    n = h * w
    k = len(offsets)
    n_pairs = sum((h - dy) * (w - abs(dx)) for dy, dx in offsets)
    terms = PairTerms(p, step, span, n_pairs)
    ids = np.arange(n, dtype=np.int64).reshape(h, w)
    unary = np.zeros((h, w))
    graph = maxflow.Graph[float](n, n_pairs)
    graph.add_nodes(n)
    rows = max(1, _CHUNK // max(w, 1))
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        cap_ij = np.zeros((r1 - r0, w, k))
        cap_ji = np.zeros((r1 - r0, w, k))
        partner = np.full((r1 - r0, w, k), -1, dtype=np.int64)
        for slot, (dy, dx) in enumerate(offsets):
            end = min(r1, h - dy)
            if end <= r0:
                continue
            c0, c1 = max(0, -dx), w - max(0, dx)
            first = (slice(r0, end), slice(c0, c1))
            second = (slice(r0 + dy, end + dy), slice(c0 + dx, c1 + dx))
            cij, cji, m = terms.graph_terms(terms.index(restored[first] - restored[second]))
            unary[first] += m
            unary[second] -= m
            cap_ij[: end - r0, c0:c1, slot] = cij
            cap_ji[: end - r0, c0:c1, slot] = cji
            partner[: end - r0, c0:c1, slot] = ids[second]
        valid = partner >= 0
        source = np.broadcast_to(ids[r0:r1, :, None], valid.shape)[valid]
        graph.add_edges(source, partner[valid], cap_ij[valid], cap_ji[valid])
    add_terminals(graph, unary.ravel())
    del unary
    graph.maxflow()
    delta = graph.get_grid_segments(ids)
    del graph
    return delta, move_delta_e(restored, delta, step * p.period, p, offsets)


def solve_pixels(
    restored: np.ndarray,
    p: EnergyParams,
    offsets: tuple[tuple[int, int], ...],
    *,
    sigma: int = 2,
    max_iter: int = 1000,
    rel_tol: float = 0.0,
    stats: MoveStats | None = None,
) -> np.ndarray:
    """The paper's minimisation (Sec. 4.2) on the pixel grid, from ``restored`` (int64, modified copy returned).

    Moves ``k <- k + delta`` are cut and kept while the energy drops; when a step-1 move no longer lowers it, a
    step-``sigma`` move is tried, and after an accepted step-``sigma`` move the step returns to 1. Stops when
    neither lowers the energy or after ``max_iter`` cuts.

    Args:
        restored: int64 (H, W) plane ``I_m + k 2**bits`` to start from.
        p: the potential's parameters.
        offsets: neighbour offsets from :func:`~torch_modulo.singleshot.energy.pair_offsets`.
        sigma: the larger step (paper: 2); 1 disables it.
        max_iter: the most cuts to solve.
        rel_tol: stop after an accepted move that lowered the energy by less than this share of it (0: run to
            the paper's stopping rule).
        stats: filled with energies, steps, cut counts and timings when given.

    Returns:
        The restored plane after the last accepted move (int64).
    """
    stats = stats if stats is not None else MoveStats()
    restored = np.array(restored, dtype=np.int64, copy=True)
    start = time.perf_counter()
    energy = plane_energy(restored, p, offsets)
    if not stats.energies:
        stats.energies.append(energy)
    step = 1
    span = _span(restored)
    cuts = 0
    stats.stop = "converged"
    while restored.size > 1:
        if cuts >= max_iter:
            stats.stop = "max_iter"
            break
        delta, delta_e = pixel_move(restored, p, offsets, step, span)
        cuts += 1
        stats.cuts += 1
        stats.nodes.append(restored.size)
        if _accept(delta_e, energy):
            restored += (step * p.period) * delta
            energy += delta_e
            stats.energies.append(energy)
            stats.steps.append(step)
            span = _span(restored)
            step = 1
            if -delta_e < rel_tol * energy:
                stats.stop = "rel_tol"
                break
        elif step == 1 and sigma > 1:
            step = sigma
        else:
            break
    stats.tick("pixels", start)
    return restored


# --------------------------------------------------------------------------------------------------- windows


def _pair_index(width: int, offset: tuple[int, int], mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices ``(i, j)`` of the pairs at ``offset`` picked by ``mask`` (shaped like the pair slices)."""
    dy, dx = offset
    rows, cols = np.nonzero(mask)
    first = rows * width + (cols + max(0, -dx))
    return first, first + (dy * width + dx)


def move_delta_e(
    restored: np.ndarray, moved: np.ndarray, shift: int, p: EnergyParams, offsets: tuple[tuple[int, int], ...]
) -> float:
    """Exact change of Eq. 3 when the pixels of ``moved`` (bool mask) get ``shift`` more counts."""
    h, w = restored.shape
    flat = restored.ravel()
    total = 0.0
    for off in offsets:
        first, second = pair_slices(h, w, off)
        change = moved[first] != moved[second]
        if not change.any():
            continue
        fi, fj = _pair_index(w, off, change)
        d = (flat[fi] - flat[fj]).astype(np.float64)
        moved_i = moved.ravel()[fi]
        new = d + np.where(moved_i, shift, -shift)
        total += float(potential_np(new, p).sum() - potential_np(d, p).sum())
    return total


class _WindowGrid:
    """Square windows of side ``window`` shifted by ``shift`` pixels, coloured 2 x 2 (windows of one colour never
    touch, not even diagonally)."""

    def __init__(self, h: int, w: int, window: int, shift: int) -> None:
        ty = (np.arange(h) + shift) // window
        tx = (np.arange(w) + shift) // window
        self.nty, self.ntx = int(ty[-1]) + 1, int(tx[-1]) + 1
        self.index = (ty[:, None] * self.ntx + tx[None, :]).ravel()
        self.pixel_colour = ((ty % 2)[:, None] * 2 + (tx % 2)[None, :]).ravel()
        self.count = self.nty * self.ntx

    def windows_of(self, mask: np.ndarray) -> np.ndarray:
        """Boolean per window: whether the window holds a pixel of ``mask``."""
        hit = np.zeros(self.count, dtype=bool)
        hit[self.index[mask.ravel()]] = True
        return hit


def _window_move(
    restored: np.ndarray,
    p: EnergyParams,
    offsets: tuple[tuple[int, int], ...],
    step: int,
    grid: _WindowGrid,
    windows: np.ndarray,
    tol: float,
) -> tuple[np.ndarray, int]:
    """Cut the move ``k <- k + step * delta`` inside every selected window, each with the rest of the image fixed.

    All selected windows go into one graph; a pair that leaves its window becomes a unary term of its free end (the
    other end held fixed). Returns the pixels of the windows whose own energy change (neighbours fixed) is
    negative, and the number of graph nodes.
    """
    h, w = restored.shape
    flat = restored.ravel()
    free = windows[grid.index]
    nodes = np.flatnonzero(free)
    n = nodes.size
    node_of = np.full(h * w, -1, dtype=np.int64)
    node_of[nodes] = np.arange(n)
    free = free.reshape(h, w)
    sign = 1 if step > 0 else -1
    terms = PairTerms(p, abs(step), _span(restored), n * len(offsets))
    graph = maxflow.Graph[float](n, len(offsets) * n)
    graph.add_nodes(n)
    unary = np.zeros(n)
    saved = []
    for off in offsets:
        first, second = pair_slices(h, w, off)
        fi, fj = _pair_index(w, off, free[first] | free[second])
        if fi.size == 0:
            continue
        idx = terms.index((flat[fi] - flat[fj]) * sign)
        a, b = terms.ab(idx)
        ni, nj = node_of[fi], node_of[fj]
        ti, tj = grid.index[fi], grid.index[fj]
        inner = (ni >= 0) & (nj >= 0) & (ti == tj)
        cij, cji, m = terms.graph_terms(idx[inner])
        graph.add_edges(ni[inner], nj[inner], cij, cji)
        unary += np.bincount(ni[inner], weights=m, minlength=n) - np.bincount(nj[inner], weights=m, minlength=n)
        end_i = (ni >= 0) & ~inner
        end_j = (nj >= 0) & ~inner
        unary += np.bincount(ni[end_i], weights=a[end_i], minlength=n)
        unary += np.bincount(nj[end_j], weights=b[end_j], minlength=n)
        saved.append((ni, nj, ti, tj, a, b, inner))
    add_terminals(graph, unary)
    graph.maxflow()
    delta = graph.get_grid_segments(np.arange(n))
    # Each window's exact energy change with its neighbours held fixed.
    gain = np.zeros(grid.count)
    for ni, nj, ti, tj, a, b, inner in saved:
        di = np.zeros(ni.size, dtype=bool)
        dj = np.zeros(nj.size, dtype=bool)
        di[ni >= 0] = delta[ni[ni >= 0]]
        dj[nj >= 0] = delta[nj[nj >= 0]]
        up = np.where(inner, di & ~dj, di)
        down = np.where(inner, ~di & dj, dj)
        gain += np.bincount(ti[up], weights=a[up], minlength=grid.count)
        gain += np.bincount(tj[down], weights=b[down], minlength=grid.count)
    keep = gain < -tol
    moved = np.zeros(h * w, dtype=bool)
    moved[nodes[delta]] = True
    moved &= keep[grid.index]
    return moved.reshape(h, w), n


def _steep_pixels(restored: np.ndarray, offsets: tuple[tuple[int, int], ...], limit: float) -> np.ndarray:
    """Pixels that take part in a pair more than ``limit`` apart."""
    h, w = restored.shape
    hot = np.zeros((h, w), dtype=bool)
    for off in offsets:
        first, second = pair_slices(h, w, off)
        big = np.abs(restored[first] - restored[second]) > limit
        hot[first] |= big
        hot[second] |= big
    return hot


def solve_windows(
    restored: np.ndarray,
    p: EnergyParams,
    offsets: tuple[tuple[int, int], ...],
    *,
    window: int = 64,
    sigma: int = 2,
    max_sweeps: int = 100,
    stats: MoveStats | None = None,
) -> np.ndarray:
    """Local moves: the paper's binary moves cut inside small windows, up and down, until none helps.

    Every window is cut with the rest of the image held fixed, all windows of a sweep in one graph, with steps
    ``+1, -1`` and then ``+sigma, -sigma`` (down moves stand in for the global "move everything else up"
    that a bounded window cannot make), on two window grids shifted by half a window. A window is cut only when it is
    *dirty* (something within a pixel changed since it was last cut for that step and grid) and *hot* (it holds
    a pair with ``|I_i - I_j| > |step| 2**bits / 2``: without one every pair term grows under the move, so no
    move can lower the energy). The windows' moves are applied together when that lowers the exact energy, else
    colour by colour (windows of one colour do not touch). Small graphs keep the max-flow fast: on these images
    its cost grows much faster than linearly with the graph.

    Returns:
        The restored plane (int64) after the last accepted move.
    """
    stats = stats if stats is not None else MoveStats()
    restored = np.array(restored, dtype=np.int64, copy=True)
    start = time.perf_counter()
    h, w = restored.shape
    energy = plane_energy(restored, p, offsets)
    if not stats.energies:
        stats.energies.append(energy)
    if restored.size < 2:
        return restored
    window = max(2, int(window))
    grids = {shift: _WindowGrid(h, w, window, shift) for shift in dict.fromkeys((0, window // 2))}
    steps = (1, -1) if sigma <= 1 else (1, -1, sigma, -sigma)
    combos = [(shift, step) for step in steps for shift in grids]
    dirty = {combo: np.ones((h, w), dtype=bool) for combo in combos}
    quiet = 0
    for _ in range(max_sweeps):
        for shift, step in combos:
            grid = grids[shift]
            mask = dirty[(shift, step)]
            changed = False
            if mask.any():
                dirty[(shift, step)] = np.zeros((h, w), dtype=bool)
                hot = _steep_pixels(restored, offsets, abs(step) * p.period / 2)
                todo = grid.windows_of(mask) & grid.windows_of(hot)
                if todo.any():
                    tol = 1e-9 * max(1.0, abs(energy))
                    moved, n = _window_move(restored, p, offsets, step, grid, todo, tol)
                    stats.cuts += 1
                    stats.nodes.append(n)
                    shift_counts = step * p.period
                    parts = [moved]
                    if moved.any():
                        delta_e = move_delta_e(restored, moved, shift_counts, p, offsets)
                        if delta_e >= -tol:
                            colour = grid.pixel_colour.reshape(h, w)
                            parts = [moved & (colour == c) for c in range(4)]
                    for part in parts:
                        if not part.any():
                            continue
                        delta_e = move_delta_e(restored, part, shift_counts, p, offsets)
                        if delta_e < -tol:
                            restored[part] += shift_counts
                            energy += delta_e
                            stats.energies.append(energy)
                            stats.steps.append(step)
                            touched = dilate(part, offsets)
                            for combo in combos:
                                dirty[combo] |= touched
                            changed = True
            quiet = 0 if changed else quiet + 1
            if quiet >= len(combos):
                break
        if quiet >= len(combos):
            break
    stats.tick("windows", start)
    return restored


def solve_fast(
    restored: np.ndarray,
    p: EnergyParams,
    offsets: tuple[tuple[int, int], ...],
    *,
    sigma: int = 2,
    max_iter: int = 1000,
    rel_tol: float = 3e-4,
    window: int = 64,
    stats: MoveStats | None = None,
) -> np.ndarray:
    """The paper's energy and moves on a cheaper schedule (``method="fast"``), from ``restored``.

    Global pixel moves as in :func:`solve_pixels` until an accepted move gains less than ``rel_tol`` of the
    energy; if that (or ``max_iter``) stopped them before the paper's rule did, local moves in ``window`` x ``window``
    windows (:func:`solve_windows`) finish the job. The long tail of global moves that each gain little is what
    costs most on textured images; the windows find the same local moves far more cheaply.

    Args:
        restored: int64 (H, W) plane ``I_m + k 2**bits`` to start from.
        p: the potential's parameters.
        offsets: neighbour offsets from :func:`~torch_modulo.singleshot.grid.pair_offsets`.
        sigma: the larger step (paper: 2); 1 disables it.
        max_iter: the most global cuts.
        rel_tol: stop the global phase after an accepted move that gains less than this share of the energy.
        window: side of the windows of the local phase; 0 skips it.
        stats: filled with energies, steps, cut counts and timings when given.

    Returns:
        The restored plane (int64) after the last accepted move.

    Example:
        >>> ramp = np.arange(0, 1200, 40).reshape(1, -1).repeat(3, axis=0)
        >>> out = solve_fast(ramp % 256, EnergyParams.make(8), ((0, 1), (1, 0)))
        >>> bool(np.array_equal(out - out.min(), ramp))
        True
    """
    stats = stats if stats is not None else MoveStats()
    restored = solve_pixels(restored, p, offsets, sigma=sigma, max_iter=max_iter, rel_tol=rel_tol, stats=stats)
    if window > 0 and stats.stop != "converged":
        restored = solve_windows(restored, p, offsets, window=window, sigma=sigma, stats=stats)
    return restored


def __getattr__(name: str) -> object:
    if name == "solve_tiles":  # the former name of solve_windows
        warnings.warn(
            "graphcut.solve_tiles is deprecated; use solve_windows (window=)", DeprecationWarning, stacklevel=2
        )
        return _solve_tiles
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _solve_tiles(*args: Any, tile: int = 64, **kwargs: Any) -> np.ndarray:
    """:func:`solve_windows` under its former name and argument (``tile``: the window's side)."""
    return solve_windows(*args, window=tile, **kwargs)
