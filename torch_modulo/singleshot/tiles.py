"""Large images in bounded memory: overlapping tiles, solved one at a time and stitched (``tile_pixels``).

A graph-cut solver's memory grows with the pixels of its graph (``"fast"``: a few hundred bytes per pixel). An
image with more than ``tile_pixels`` pixels is therefore cut into a grid of near-square tiles whose *cores*
partition it; each tile is solved on its core plus :data:`TILE_OVERLAP` pixels on every side that has a neighbour
(at most ``tile_pixels`` pixels in all), by the same solver, independently. A tile's ``k`` is fixed only up to
one constant per plane, so the tiles are stitched:

1. for every pair of side-by-side tiles, the difference of their ``k`` on the pixels both were solved on: its
   most common value is the offset that makes them agree, and the number of pixels that take it is the
   pair's *agreement*;
2. per plane, a maximum spanning tree over the tiles by agreement (Kruskal), so that every tile is placed
   through the neighbours it agrees with best, and the offsets are summed along the tree from the first tile;
3. every tile's core is written with its offset.

The caller anchors the stitched image once (:func:`~torch_modulo.singleshot.anchor.anchor_k`). Where the image
has no residues, every tile is exact up to its constant and agrees with its neighbours on the whole overlap, so
the stitched result is the untiled one; elsewhere a tile sees less of the image than the whole does, and where it
has to guess the relative level of two regions it can guess differently. Only the overlaps of tiles whose
neighbours are still to come are kept besides the output, so the solver's own memory is that of one tile.

``"guided"`` does not use these tiles: it builds its spanning tree in blocks of ``tile_pixels`` pixels instead,
which gives a minimum spanning tree of the whole image
(:func:`~torch_modulo.singleshot.pathfollow.quality_guided_colour_k`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from torch_modulo._checks import check_int
from torch_modulo.singleshot.graphcut import plane_energy
from torch_modulo.singleshot.grid import pair_offsets
from torch_modulo.singleshot.spec import GroupSolver, MoveStats, SolverSpec

__all__ = [
    "MIN_TILE_PIXELS",
    "TILE_OVERLAP",
    "TILE_PIXELS",
    "Tile",
    "check_tile_pixels",
    "solve_tiled",
    "stitch_offsets",
    "tile_grid",
    "tiled",
]

#: Default ``tile_pixels`` of ``"fast"`` and ``"guided"``: images with more pixels than this (per channel) are solved
#: in tiles (``"fast"``) or build their tree in blocks (``"guided"``).
TILE_PIXELS = 1 << 22

#: Pixels a tile is solved on beyond its core, on every side that has a neighbour.
TILE_OVERLAP = 32

#: The smallest ``tile_pixels`` accepted (besides 0): a tile of ``4 * TILE_OVERLAP`` pixels square.
MIN_TILE_PIXELS = (4 * TILE_OVERLAP) ** 2


def check_tile_pixels(value: object, name: str) -> int:
    """``tile_pixels``: 0 (never tile) or an integer >= :data:`MIN_TILE_PIXELS`; raises naming the value otherwise.

    Example:
        >>> check_tile_pixels(1 << 20, "tile_pixels")
        1048576
    """
    tile_pixels = check_int(value, name, 0)
    if 0 < tile_pixels < MIN_TILE_PIXELS:
        raise ValueError(f"{name} must be 0 (never tile) or >= {MIN_TILE_PIXELS}; got {tile_pixels}")
    return tile_pixels


@dataclass(frozen=True)
class Tile:
    """One tile: the rows and columns it decides (``core``) and the ones it is solved on (``ext``).

    Attributes:
        core: ``(rows, cols)`` slices of the image; the cores of a grid partition it.
        ext: the core grown by the overlap on every side inside the image.
    """

    core: tuple[slice, slice]
    ext: tuple[slice, slice]


def _splits(n: int, parts: int, overlap: int) -> list[tuple[slice, slice]]:
    """``parts`` core ranges of near-equal length covering ``range(n)``, each with its range grown by ``overlap``."""
    edges = [round(i * n / parts) for i in range(parts + 1)]
    return [
        (slice(a, b), slice(max(0, a - overlap), min(n, b + overlap)))
        for a, b in zip(edges[:-1], edges[1:], strict=True)
    ]


def _grid_shape(height: int, width: int, tile_pixels: int, overlap: int) -> tuple[int, int]:
    """``(rows, cols)`` of near-square tiles whose solved area (core and overlap) stays within ``tile_pixels``.

    Square tiles (of side ``isqrt(tile_pixels)``, overlap included) keep the most pixels away from a tile's border;
    an image narrower than that in one direction gets one row (or column) of tiles as long as the budget allows.
    """

    def count(n: int, ext_other: int) -> int:  # tiles along a side of ``n`` pixels, the other side being ``ext_other``
        if n * ext_other <= tile_pixels:
            return 1
        return -(-n // max(1, tile_pixels // ext_other - 2 * overlap))

    side = math.isqrt(tile_pixels)
    rows = 1 if height <= side else -(-height // (side - 2 * overlap))
    ext_h = height if rows == 1 else -(-height // rows) + 2 * overlap
    by_rows = (rows, count(width, ext_h))
    cols = 1 if width <= side else -(-width // (side - 2 * overlap))
    ext_w = width if cols == 1 else -(-width // cols) + 2 * overlap
    by_cols = (count(height, ext_w), cols)
    return min(by_rows, by_cols, key=lambda rc: (rc[0] * rc[1], rc))


def tile_grid(height: int, width: int, tile_pixels: int, overlap: int = TILE_OVERLAP) -> list[list[Tile]]:
    """The tiles of an image, as rows of :class:`Tile`: one tile when the image has at most ``tile_pixels`` pixels.

    Args:
        height: image height.
        width: image width.
        tile_pixels: the most pixels a tile is solved on (0: never tile); at least :data:`MIN_TILE_PIXELS`.
        overlap: pixels a tile is solved on beyond its core, on every side that has a neighbour.

    Returns:
        ``rows x cols`` tiles (the fewest that fit, squarest first); their cores partition the image and each
        ``ext`` holds at most ``tile_pixels`` pixels.

    Example:
        >>> grid = tile_grid(1000, 1000, 1 << 18)
        >>> len(grid), len(grid[0]), grid[0][0].core, grid[0][0].ext
        (2, 3, (slice(0, 500, None), slice(0, 333, None)), (slice(0, 532, None), slice(0, 365, None)))
    """
    if tile_pixels == 0 or height * width <= tile_pixels:
        whole = (slice(0, height), slice(0, width))
        return [[Tile(whole, whole)]]
    rows, cols = _grid_shape(height, width, tile_pixels, overlap)
    return [
        [Tile((ry, rx), (ey, ex)) for rx, ex in _splits(width, cols, overlap)]
        for ry, ey in _splits(height, rows, overlap)
    ]


def _within(outer: tuple[slice, slice], inner: tuple[slice, slice]) -> tuple[slice, slice]:
    """``inner`` (image coordinates) relative to the origin of ``outer``."""
    return tuple(slice(i.start - o.start, i.stop - o.start) for o, i in zip(outer, inner, strict=True))  # type: ignore[return-value]


def _intersection(a: tuple[slice, slice], b: tuple[slice, slice]) -> tuple[slice, slice]:
    return tuple(slice(max(x.start, y.start), min(x.stop, y.stop)) for x, y in zip(a, b, strict=True))  # type: ignore[return-value]


def _agreement(diff: np.ndarray) -> tuple[list[int], list[int]]:
    """Per plane of ``diff`` (G, h, w), its most common value (the smallest on ties) and how many pixels take it."""
    modes, counts = [], []
    for plane in diff.reshape(diff.shape[0], -1):
        values, n = np.unique(plane, return_counts=True)
        best = int(n.argmax())
        modes.append(int(values[best]))
        counts.append(int(n[best]))
    return modes, counts


def stitch_offsets(n_tiles: int, pairs: list[tuple[int, int, int, int]]) -> np.ndarray:
    """The offset of every tile from its pairs, along a maximum spanning tree by agreement (Kruskal).

    Args:
        n_tiles: the number of tiles.
        pairs: ``(a, b, mode, agreement)``: ``k_a - k_b`` takes the value ``mode`` on ``agreement`` pixels of
            their overlap.

    Returns:
        int64 (n_tiles,) offsets, tile 0 at 0 (and every tile that no pair reaches at 0), so that
        ``k_a + offset_a - k_b - offset_b`` is 0 on the agreeing pixels of every tree pair.

    Example:
        >>> stitch_offsets(3, [(0, 1, 2, 90), (1, 2, -1, 80), (0, 2, 5, 10)]).tolist()  # (0, 2) disagrees most
        [0, 2, 1]
    """
    root = list(range(n_tiles))

    def find(i: int) -> int:
        while root[i] != i:
            root[i] = root[root[i]]
            i = root[i]
        return i

    adjacent: list[list[tuple[int, int]]] = [[] for _ in range(n_tiles)]
    for a, b, mode, _ in sorted(pairs, key=lambda p: -p[3]):
        ra, rb = find(a), find(b)
        if ra != rb:
            root[ra] = rb
            adjacent[a].append((b, mode))  # offset_b = offset_a + mode
            adjacent[b].append((a, -mode))
    offsets = np.zeros(n_tiles, dtype=np.int64)
    seen = [False] * n_tiles
    for start in range(n_tiles):
        if seen[start]:
            continue
        seen[start] = True
        stack = [start]
        while stack:
            a = stack.pop()
            for b, mode in adjacent[a]:
                if not seen[b]:
                    seen[b] = True
                    offsets[b] = offsets[a] + mode
                    stack.append(b)
    return offsets


def _merge_stats(total: MoveStats, part: MoveStats) -> None:
    """Add one tile's solver statistics to the plane's (the energies are set after stitching)."""
    total.steps.extend(part.steps)
    total.cuts += part.cuts
    total.nodes.extend(part.nodes)
    for stage, seconds in part.seconds.items():
        total.seconds[stage] = total.seconds.get(stage, 0.0) + seconds
    total.stop = part.stop or total.stop


def solve_tiled(
    solve: GroupSolver, moduli: np.ndarray, spec: SolverSpec, stats: list[MoveStats], tile_pixels: int
) -> np.ndarray:
    """``solve(moduli, spec, stats)``, in tiles of at most ``tile_pixels`` pixels when the image has more.

    Args:
        solve: a method's group solver (see :mod:`torch_modulo.singleshot.methods`).
        moduli: (G, H, W) int64 moduli in ``[0, 2**bits)``: one plane, or the channels of one image.
        spec: the solver's settings.
        stats: one :class:`~torch_modulo.singleshot.graphcut.MoveStats` per plane; with tiles, each gathers
            its tiles' steps, cuts and times, and its ``energies`` holds the stitched plane's energy alone.
        tile_pixels: the most pixels a tile is solved on; 0 or at least the image's ``H * W``: no tiles.

    Returns:
        int64 (G, H, W) restored counts ``moduli + k 2**bits``, ``k`` up to one constant per plane (the caller
        anchors it).

    Example:
        >>> from torch_modulo.singleshot.methods import REGISTRY, make_spec
        >>> ramp = np.add.outer(np.arange(300), np.arange(300)) * 20  # 0 .. 11960 counts, 46 rollovers
        >>> spec = make_spec(8, "guided", 8, 0.1, 1e-5, None, 2, 10, {})
        >>> out = solve_tiled(REGISTRY["guided"].solve, ramp[None] % 256, spec, [MoveStats()], 128 * 128)
        >>> bool(np.array_equal(out[0] - out[0, 0, 0], ramp))
        True
    """
    g, h, w = moduli.shape
    grid = tile_grid(h, w, tile_pixels)
    if len(grid) * len(grid[0]) == 1:
        return solve(moduli, spec, stats)
    period = spec.params.period
    cols = len(grid[0])
    tiles = [t for row in grid for t in row]
    k = np.empty((g, h, w), dtype=np.int64)
    pending: dict[tuple[int, int], np.ndarray] = {}  # k of tile a on its overlap with a later tile b
    pairs: list[list[tuple[int, int, int, int]]] = [[] for _ in range(g)]
    for index, tile in enumerate(tiles):
        part = np.ascontiguousarray(moduli[(slice(None), *tile.ext)])
        part_stats = [MoveStats() for _ in range(g)]
        k_tile = solve(part, spec, part_stats)
        if np.may_share_memory(k_tile, part):
            k_tile = k_tile.copy()
        k_tile -= part
        k_tile //= period
        del part
        for total, st in zip(stats, part_stats, strict=True):
            _merge_stats(total, st)
        k[(slice(None), *tile.core)] = k_tile[(slice(None), *_within(tile.ext, tile.core))]
        row, col = divmod(index, cols)
        earlier = [index - 1] if col > 0 else []
        earlier += [index - cols] if row > 0 else []
        for other in earlier:
            overlap = _within(tile.ext, _intersection(tiles[other].ext, tile.ext))
            modes, counts = _agreement(pending.pop((other, index)) - k_tile[(slice(None), *overlap)])
            for plane, (mode, count) in enumerate(zip(modes, counts, strict=True)):
                pairs[plane].append((other, index, mode, count))
        later = [index + 1] if col + 1 < cols else []
        later += [index + cols] if index + cols < len(tiles) else []
        for other in later:
            overlap = _within(tile.ext, _intersection(tiles[other].ext, tile.ext))
            pending[(index, other)] = k_tile[(slice(None), *overlap)].copy()
        del k_tile
    start = time.perf_counter()
    offsets = np.stack([stitch_offsets(len(tiles), plane_pairs) for plane_pairs in pairs])  # (G, tiles)
    for index, tile in enumerate(tiles):
        k[(slice(None), *tile.core)] += offsets[:, index, None, None]
    restored: np.ndarray = k
    restored *= period
    restored += moduli
    offsets_nb = pair_offsets(spec.neighborhood)
    for plane, st in zip(restored, stats, strict=True):
        st.energies[:] = [plane_energy(plane, spec.params, offsets_nb)]
        st.tick("stitch", start)
    return restored


def tiled(solve: GroupSolver) -> GroupSolver:
    """A group solver that runs ``solve`` in tiles (:func:`solve_tiled`) of the spec's ``tile_pixels`` option."""

    def solve_in_tiles(moduli: np.ndarray, spec: SolverSpec, stats: list[MoveStats]) -> np.ndarray:
        return solve_tiled(solve, moduli, spec, stats, int(spec.option("tile_pixels")))

    solve_in_tiles.__doc__ = solve.__doc__
    return solve_in_tiles
