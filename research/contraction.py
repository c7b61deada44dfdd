"""Region contraction: the paper's binary moves on graphs whose nodes are regions of the restored image.

Research code, not part of the package (README.md, "Region contraction"): it did not pay. Pixels joined by small
differences of the current restored image (``|I_i - I_j| <= link``) form regions that move together; pixels on a
region's border (the band) stay single nodes, so fringes can still move by a pixel. The pair terms of each pair
of nodes are summed exactly, so the energy change of a contracted move is the true one.

:func:`solve_fast_contracted` is what ``unwrap_single(method="fast", contract=True)`` did before the option was
removed: the contracted moves run between ``"fast"``'s starting point and its pixel moves.
"""

from __future__ import annotations

import time

import maxflow
import numpy as np

from torch_modulo.singleshot.anchor import anchor_k
from torch_modulo.singleshot.energy import EnergyParams
from torch_modulo.singleshot.graphcut import MoveStats, PairTerms, add_terminals, plane_energy, solve_fast
from torch_modulo.singleshot.grid import components, dilate, pair_offsets, pair_slices
from torch_modulo.singleshot.methods import fast_start

__all__ = ["contract_regions", "solve_contracted", "solve_fast_contracted"]


def _span(restored: np.ndarray) -> int:
    return int(restored.max() - restored.min()) if restored.size else 0


def _accept(delta_e: float, energy: float) -> bool:
    """A move is kept only if it lowers the energy by more than rounding noise (as in the package's solvers)."""
    return delta_e < -1e-9 * max(1.0, abs(energy))


def contract_regions(
    restored: np.ndarray, link: float, offsets: tuple[tuple[int, int], ...], band: int = 1, block: int = 0
) -> tuple[int, np.ndarray]:
    """Label the nodes of a contracted graph: regions of the restored image plus single band pixels.

    Pixels joined (4-neighbourhood) by ``|I_i - I_j| <= link`` form regions; every pixel that takes part in a
    pair (over ``offsets``) whose ends lie in different regions, dilated ``band - 1`` more times, becomes a node
    of its own. With ``band=0`` the regions are the nodes. With ``block > 0`` regions are further cut into
    ``block`` x ``block`` squares, so that no node gets a huge degree.

    Args:
        restored: (H, W) integer plane.
        link: the largest difference that joins two pixels.
        offsets: the neighbourhood whose pairs define the band.
        band: border width in pixels.
        block: side of the squares regions are cut into (0: not cut).

    Returns:
        ``(n_nodes, labels)``: labels is an (H, W) intp array of node indices in ``[0, n_nodes)``.
    """
    h, w = restored.shape
    n = h * w
    ids = np.arange(n, dtype=np.intp).reshape(h, w)
    rows, cols = [], []
    for off in ((0, 1), (1, 0)):
        first, second = pair_slices(h, w, off)
        joined = np.abs(restored[first] - restored[second]) <= link
        rows.append(ids[first][joined])
        cols.append(ids[second][joined])
    _, labels = components(n, np.concatenate(rows), np.concatenate(cols))
    labels = labels.reshape(h, w).astype(np.int64)
    border = np.zeros((h, w), dtype=bool)
    if band > 0:
        for off in offsets:
            first, second = pair_slices(h, w, off)
            cross = labels[first] != labels[second]
            border[first] |= cross
            border[second] |= cross
        for _ in range(band - 1):
            border = dilate(border, offsets)
    if block > 0:
        # Split regions into blocks so that no node has a huge degree (the max-flow slows down on such hubs).
        bw = (w + block - 1) // block
        tiles = (np.arange(h) // block)[:, None] * bw + (np.arange(w) // block)[None, :]
        labels = labels * ((h + block - 1) // block * bw) + tiles
    if border.any():
        # Band pixels get fresh labels after the regions.
        labels[border] = int(labels.max()) + 1 + np.arange(int(border.sum()))
    # Compact the labels to 0..n_nodes-1.
    uniq, labels = np.unique(labels.ravel(), return_inverse=True)
    return int(uniq.size), labels.reshape(h, w).astype(np.intp)


class _ContractedGraph:
    """The pairs of a contracted graph: pixel pairs whose ends lie in different nodes, summed per node pair."""

    def __init__(self, labels: np.ndarray, n_nodes: int, offsets: tuple[tuple[int, int], ...]) -> None:
        h, w = labels.shape
        ids = np.arange(h * w, dtype=np.intp).reshape(h, w)
        pi, pj = [], []
        for off in offsets:
            first, second = pair_slices(h, w, off)
            cross = labels[first] != labels[second]
            pi.append(ids[first][cross])
            pj.append(ids[second][cross])
        self.pi = np.concatenate(pi)
        self.pj = np.concatenate(pj)
        flat = labels.ravel()
        a, b = flat[self.pi], flat[self.pj]
        self.flip = a > b
        lo = np.where(self.flip, b, a).astype(np.int64)
        hi = np.where(self.flip, a, b).astype(np.int64)
        keys, self.inverse = np.unique(lo * n_nodes + hi, return_inverse=True)
        self.na = (keys // n_nodes).astype(np.intp)
        self.nb = (keys % n_nodes).astype(np.intp)
        self.n_nodes = n_nodes
        self.labels = flat

    def move(self, restored: np.ndarray, terms: PairTerms) -> tuple[np.ndarray, float]:
        """One binary move over the nodes: returns per-pixel ``delta`` (bool, flat) and the exact energy change."""
        flat = restored.ravel()
        idx = terms.index(flat[self.pi] - flat[self.pj])
        a, b = terms.ab(idx)
        a_node = np.where(self.flip, b, a)
        b_node = np.where(self.flip, a, b)
        npairs = self.na.size
        aa = np.bincount(self.inverse, weights=a_node, minlength=npairs)
        bb = np.bincount(self.inverse, weights=b_node, minlength=npairs)
        cij, cji, m = PairTerms.decompose(aa, bb)
        graph = maxflow.Graph[float](self.n_nodes, npairs)
        nodes = graph.add_nodes(self.n_nodes)
        graph.add_edges(self.na, self.nb, cij, cji)
        unary = np.bincount(self.na, weights=m, minlength=self.n_nodes) - np.bincount(
            self.nb, weights=m, minlength=self.n_nodes
        )
        add_terminals(graph, unary)
        graph.maxflow()
        delta_node = graph.get_grid_segments(nodes)
        da, db = delta_node[self.na], delta_node[self.nb]
        delta_e = float(aa[da & ~db].sum()) + float(bb[~da & db].sum())
        return delta_node[self.labels], delta_e


def solve_contracted(
    restored: np.ndarray,
    p: EnergyParams,
    offsets: tuple[tuple[int, int], ...],
    *,
    link: float,
    band: int = 1,
    block: int = 0,
    sigma: int = 2,
    max_iter: int = 1000,
    max_rounds: int = 20,
    stats: MoveStats | None = None,
) -> np.ndarray:
    """The paper's moves on contracted graphs, re-contracting after every round that changed something.

    Each round labels regions of the current restored image (:func:`contract_regions`), then runs step-1 and
    step-``sigma`` moves over those nodes until neither lowers the energy. Every move's energy change is exact,
    so the energy never rises. Rounds repeat (regions grow as fringes are removed) until a round accepts no
    move, ``max_rounds`` rounds ran, or ``max_iter`` cuts were solved in all.

    Returns:
        The restored plane (int64) after the last accepted move.
    """
    stats = stats if stats is not None else MoveStats()
    restored = np.array(restored, dtype=np.int64, copy=True)
    start = time.perf_counter()
    energy = plane_energy(restored, p, offsets)
    if not stats.energies:
        stats.energies.append(energy)
    cuts = 0
    for _ in range(max_rounds):
        n_nodes, labels = contract_regions(restored, link, offsets, band, block)
        if n_nodes < 2:
            break
        graph = _ContractedGraph(labels, n_nodes, offsets)
        changed = False
        step = 1
        span = _span(restored)
        while cuts < max_iter:
            terms = PairTerms(p, step, span, graph.pi.size)
            delta, delta_e = graph.move(restored, terms)
            cuts += 1
            stats.cuts += 1
            stats.nodes.append(n_nodes)
            if _accept(delta_e, energy):
                restored.ravel()[delta] += step * p.period
                energy += delta_e
                stats.energies.append(energy)
                stats.steps.append(step)
                span = _span(restored)
                changed = True
                step = 1
            elif step == 1 and sigma > 1:
                step = sigma
            else:
                break
        if not changed or cuts >= max_iter:
            break
    stats.tick("contract", start)
    return restored


def solve_fast_contracted(
    modulus: np.ndarray,
    bits: int = 8,
    *,
    neighborhood: int = 8,
    init: str = "auto",
    rel_tol: float = 3e-4,
    tile: int = 64,
    sigma: int = 2,
    max_iter: int = 1000,
    stats: MoveStats | None = None,
) -> np.ndarray:
    """``"fast"`` with region moves first (the former ``contract=True``), anchored like ``unwrap_single``.

    Start from ``fast_start`` (``init``), run :func:`solve_contracted` (link half a period, band 1, blocks of
    32), then ``"fast"``'s pixel moves and tiles; anchor ``k`` as the package does.

    Args:
        modulus: (H, W) integer-valued array in ``[0, 2**bits)``.
        bits: the sensor bit depth ``N``.
        neighborhood: 8 or 4.
        init: ``"auto"``, ``"zeros"`` or ``"quality"`` (see ``torch_modulo.singleshot.methods.fast_start``).
        rel_tol: see ``torch_modulo.singleshot.graphcut.solve_fast``.
        tile: see ``torch_modulo.singleshot.graphcut.solve_fast``.
        sigma: the larger step.
        max_iter: the most global cuts.
        stats: filled with energies, steps, cut counts and timings when given.

    Returns:
        int64 (H, W) restored counts, ``k >= 0``.

    Example:
        >>> ramp = np.arange(0, 1200, 40).reshape(1, -1).repeat(3, axis=0)
        >>> bool(np.array_equal(solve_fast_contracted(ramp % 256), ramp))
        True
    """
    stats = stats if stats is not None else MoveStats()
    modulus = np.asarray(modulus, dtype=np.int64)
    p = EnergyParams.make(bits)
    offsets = pair_offsets(neighborhood)
    restored = fast_start(modulus, bits, init)
    restored = solve_contracted(restored, p, offsets, link=p.period // 2, band=1, block=32, sigma=sigma, stats=stats)
    restored = solve_fast(restored, p, offsets, sigma=sigma, max_iter=max_iter, rel_tol=rel_tol, tile=tile, stats=stats)
    k = anchor_k((restored - modulus) // p.period, modulus=modulus, bits=bits)
    return modulus + p.period * k
