"""Learned levels: a distribution over the rollover count per 2 x 2 block of pixels, and region moves that use it.

The spanning tree of ``method="learned"`` (:func:`~torch_modulo.singleshot.learned.decode_jumps`) often puts whole
regions one or two periods off (``research/learned_regions.py`` measures how much): a region ringed by steps the
network is unsure of hangs on the one pair the tree crossed it by. Neighbour steps cannot settle such a region; the
idea is that its own content can: texture under multiplicative shading is larger in counts where the radiance is
higher, and lamps, skies and windows look like what they are. :class:`LevelNet` (a small head of four convolutions
on the edge network's half-resolution features) predicts, for every 2 x 2 block of pixels and every channel, a
distribution over ``k`` in ``0 .. LEVELS - 1`` (:func:`predict_levels`).

:func:`region_moves` decodes exactly, in integers: the whole plane first moves by the level the head prefers; then
the plane is cut into the regions joined by pairs the edge network is sure of, and each region may move by
``-2 .. 2`` periods where the head's costs (``-log p(k)``) plus the costs of the region's moved border pairs drop.
Every round moves the regions whose drop is larger than all their neighbours', until none drops. Every output is
``I_m + k 2^N`` with integer ``k``.

The shipped weights (``weights/levels.pt``, record in ``weights/MODEL_CARD.md``) load offline (:func:`load_levels`);
the recipe that made them is ``research/level_shared.py``.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from torch_modulo._checks import check_int
from torch_modulo.singleshot.grid import grid_components
from torch_modulo.singleshot.learned import (
    _DIRECTIONS,
    _MAX_COST,
    SLOTS,
    TILE,
    EdgeJumpNet,
    _cpu_layout,
    edge_features,
    tile_margin,
    weights_path,
    window_grid,
)

__all__ = [
    "LEVELS",
    "LEVEL_WEIGHTS",
    "LevelHead",
    "LevelNet",
    "level_margin",
    "load_levels",
    "predict_levels",
    "region_moves",
    "window_costs",
]

#: The file name of the shipped level weights inside ``torch_modulo/singleshot/weights``.
LEVEL_WEIGHTS = "levels.pt"

#: The levels the head tells apart: ``k = 0 .. LEVELS - 1`` (its training labels were clipped at the last).
LEVELS = 16

#: Half-resolution pixels of context the head's convolutions (dilations 1, 2, 4) see on every side.
_HALO = 7

#: The moves a region may make in one round, in periods.
_SHIFTS = (-2, -1, 1, 2)

#: How far a region may end up from where the global move put it, in periods (farther moves are not tried).
_REACH = 8

#: :func:`region_moves` weighs the border pairs of this many at a time (a bound on its memory).
_CHUNK = 2**18


class LevelHead(nn.Module):
    """Four convolutions (3 x 3 with dilations 1, 2, 4; then 1 x 1) from features to level logits.

    Shape:
        - Input: (B, cin, H, W) features (:class:`LevelNet`: the edge network's half-resolution ones and its input
          pooled 2 x 2, ``cin = 2 width + 15``).
        - Output: (B, 3, levels, H, W) logits per channel slot.

    Example:
        >>> LevelHead(cin=8, width=4, levels=5)(torch.zeros(1, 8, 6, 6)).shape
        torch.Size([1, 3, 5, 6, 6])
    """

    def __init__(self, cin: int = 32 + 15, width: int = 32, levels: int = LEVELS) -> None:
        super().__init__()
        self.levels = int(levels)
        self.net = nn.Sequential(
            nn.Conv2d(cin, width, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(width, width, 3, padding=2, dilation=2),
            nn.ReLU(inplace=True),
            nn.Conv2d(width, width, 3, padding=4, dilation=4),
            nn.ReLU(inplace=True),
            nn.Conv2d(width, SLOTS * self.levels, 1),
        )

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        b, _, h, w = features.shape
        hidden = self.net[:-1](features).contiguous()  # channels first for the 1 x 1 convolution (learned._cpu_layout)
        return self.net[-1](hidden).view(b, SLOTS, self.levels, h, w)


class LevelNet(nn.Module):
    """A :class:`LevelHead` at half resolution on an :class:`~torch_modulo.singleshot.learned.EdgeJumpNet`'s encoder.

    The head sees the encoder's half-resolution features (``d2`` of
    :meth:`~torch_modulo.singleshot.learned.EdgeJumpNet.encode`) and the input pooled 2 x 2; no full-resolution
    decoder stage runs, so the levels cost a fraction of the edge network. The trunk is a copy of the edge network it
    was trained on (its jump head is not used).

    Args:
        config: the trunk's :class:`~torch_modulo.singleshot.learned.EdgeJumpNet` arguments.
        width: the head's channels.
        levels: the levels told apart (``k = 0 .. levels - 1``).

    Shape:
        - Input: (B, 15, H, W) :func:`~torch_modulo.singleshot.learned.edge_features`, ``H`` and ``W`` multiples of
          :attr:`stride`.
        - Output: (B, 3, levels, H / 2, W / 2) logits, one per 2 x 2 block of pixels.

    Example:
        >>> net = LevelNet({"width": 4, "max_jump": 2}, width=4, levels=5)
        >>> net(torch.zeros(1, 15, 8, 8)).shape
        torch.Size([1, 3, 5, 4, 4])
    """

    def __init__(self, config: dict, width: int = 32, levels: int = LEVELS) -> None:
        super().__init__()
        self.trunk = EdgeJumpNet(**config)
        self.head = LevelHead(2 * self.trunk.config["width"] + 5 * SLOTS, width, levels)
        self.stride = self.trunk.stride

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head_logits(x, self.trunk.encode(x)[1])

    def head_logits(self, x: torch.Tensor, d2: torch.Tensor) -> torch.Tensor:
        """The head's logits from the features ``x`` and the trunk's ``d2`` (its encoder's half-resolution output)."""
        return self.head(torch.cat([d2, F.avg_pool2d(x, 2)], dim=1))


@functools.lru_cache(maxsize=4)
def _load_cached(path: str, device: str) -> LevelNet:
    try:
        record = torch.load(path, map_location="cpu", weights_only=True)
        levels = int(record["head"]["net.6.bias"].numel()) // SLOTS
        net = LevelNet(record["config"], width=int(record["head"]["net.0.bias"].numel()), levels=levels)
        net.trunk.load_state_dict({k: v.float() for k, v in record["state"].items()})
        net.head.load_state_dict({k: v.float() for k, v in record["head"].items()})
    except Exception as error:  # another kind of file, another network, a truncated copy: name the file
        raise ValueError(
            f"{path!r} is not a level weights file ({{'config': ..., 'state': ..., 'head': ...}} as "
            f"research/level_shared.py exports it): {type(error).__name__}: {error}"
        ) from error
    return _cpu_layout(net.eval().to(device))  # one cached copy per device


def load_levels(path: str | Path | None = None, device: torch.device | str = "cpu") -> LevelNet:
    """The trained :class:`LevelNet` (eval mode), loaded offline.

    Args:
        path: a level weights file (as ``research/level_shared.py export`` writes it); ``None`` loads the shipped one.
        device: where to put the network.

    Raises:
        FileNotFoundError: there is no file at ``path``.
        ValueError: the file is not a level weights file (the message names it).

    Example:
        >>> load_levels().head.levels
        16
    """
    return _load_cached(weights_path(path, LEVEL_WEIGHTS), str(torch.device(device)))


def level_margin(net: LevelNet) -> int:
    """The context a tile of :func:`predict_levels` needs on every side: the trunk's (:func:`tile_margin`) plus the
    head's at half resolution, rounded up to a multiple of the stride."""
    margin = tile_margin(net.trunk) + 2 * _HALO + 2
    return margin + (-margin % net.stride)


def window_costs(
    net: LevelNet, features: torch.Tensor, d2: torch.Tensor, channels: int, rows: slice, cols: slice
) -> torch.Tensor:
    """The (channels, levels, ceil(rows / 2), ceil(cols / 2)) costs of the 2 x 2 blocks of the core ``rows, cols`` of
    one window (starting at even offsets) from its (1, 15, h, w) features and its trunk's ``d2``."""
    logits = net.head_logits(features, d2)[(0, slice(channels), slice(None), *_block_slices(rows, cols))]
    return -torch.log_softmax(logits.float(), dim=1)


def _block_slices(rows: slice, cols: slice) -> tuple[slice, slice]:
    """The 2 x 2 blocks of the pixels ``rows, cols``, which start at even offsets (the windows' cores do: they start
    at multiples of the trunk's stride)."""
    return slice(rows.start // 2, (rows.stop + 1) // 2), slice(cols.start // 2, (cols.stop + 1) // 2)


@torch.no_grad()
def _level_pieces(
    net: LevelNet, moduli: torch.Tensor, bits: int, tile: int
) -> Iterator[tuple[tuple[slice, slice], torch.Tensor]]:
    """Per tile of (C, H, W) moduli (C = 1 or 3): the slices of the tile's 2 x 2 blocks and their (C, levels, h, w)
    costs."""
    # windows and cores start at multiples of the stride, so on the half-resolution grid too
    for window, core, at in window_grid(moduli, tile, level_margin(net), net.stride):
        features = edge_features(window, bits)
        yield _block_slices(*at), window_costs(net, features, net.trunk.encode(features)[1], moduli.shape[0], *core)


def predict_levels(net: LevelNet, moduli: torch.Tensor, bits: int, tile: int = TILE) -> np.ndarray:
    """Every 2 x 2 block's cost ``-log p(k)`` of each level ``k``: float16 (C, levels, ceil(H / 2), ceil(W / 2)) on
    the CPU.

    The blocks start at the top left; the pixels of a block share its costs (the head predicts at half resolution).
    The network runs on the moduli's device, in tiles of ``tile`` pixels (0: the whole image) with
    :func:`level_margin` of context; the result is the same up to float rounding.

    Args:
        net: the network.
        moduli: (C, H, W) moduli, C = 1 (seen as grey) or 3 (seen together); other channel counts are predicted
            one channel at a time.
        bits: the sensor bit depth ``N`` (the shipped network was trained at 8).
        tile: the side of the tiles.

    Example:
        >>> costs = predict_levels(load_levels(), torch.zeros(1, 8, 7), 8)
        >>> costs.shape, costs.dtype
        ((1, 16, 4, 4), dtype('float16'))
    """
    c, h, w = moduli.shape
    out = np.empty((c, net.head.levels, (h + 1) // 2, (w + 1) // 2), dtype=np.float16)
    if c not in (1, SLOTS):
        for i in range(c):
            out[i : i + 1] = predict_levels(net, moduli[i : i + 1], bits, tile)
        return out
    for (ys, xs), cost in _level_pieces(net, moduli, bits, tile):
        out[:, :, ys, xs] = cost.cpu().numpy()
    return out


def region_moves(
    modulus: np.ndarray,
    k: np.ndarray,
    table: np.ndarray,
    first: np.ndarray,
    u: np.ndarray,
    bits: int,
    *,
    weight: float = 1.0,
    sure: float = 0.01,
    rounds: int = 60,
    block: int = 2,
) -> np.ndarray:
    """``k`` of one plane moved by the level costs: the global level, then whole regions (see the module docstring).

    Args:
        modulus: (H, W) integer moduli.
        k: (H, W) integer rollover counts (e.g. the spanning tree's).
        table: (2, K, H, W) costs ``-log p`` of K consecutive jumps per pair (direction 0: to the right, 1: down):
            ``table[d, i]`` is the cost of the jump ``first[d] + i``; jumps outside cost 30, and costs are clipped to
            it. The regions are joined by the pairs whose least cost in the table is at most ``sure``.
        first: (2, H, W) integers: the jump of ``table``'s first entry per pair.
        u: (L, ceil(H / block), ceil(W / block)) every block's cost of each level (:func:`predict_levels`: 2 x 2
            blocks from the top left), shared by the block's pixels.
        bits: the sensor bit depth ``N``.
        weight: the weight of the level costs against the pairs'.
        sure: pairs at most this costly join a region.
        rounds: the most rounds of moves.
        block: the side of the blocks of ``u`` (1: a cost per pixel).

    Returns:
        int64 (H, W): ``k`` plus an integer per region (so ``modulus + k 2^N`` stays consistent with the modulus).

    Example:
        >>> m = np.array([[10, 10, 10, 10]])
        >>> table = np.full((2, 3, 1, 4), 30.0); table[:, 1] = 0.0  # jumps -1, 0, 1: sure of 0 ...
        >>> table[0, :, 0, 1] = [30.0, 1.0, 2.0]  # ... but for the middle pair, which may well be 1
        >>> u = np.full((16, 1, 2), 9.0); u[0, 0, 0] = 0.0; u[1, 0, 1] = 0.0  # the right block is a period up
        >>> region_moves(m, np.zeros((1, 4), int), table, np.full((2, 1, 4), -1), u, 8).tolist()
        [[0, 0, 1, 1]]
    """
    m = np.asarray(modulus, dtype=np.int64)
    k = np.asarray(k, dtype=np.int64)
    u = np.asarray(u)
    period = 1 << bits
    h, w = m.shape
    block = check_int(block, "block", 1)
    if u.ndim != 3 or u.shape[1:] != (-(-h // block), -(-w // block)):
        raise ValueError(f"level costs of shape {u.shape} for a {h} x {w} plane in blocks of {block}")
    if k.size == 0:
        return k.copy()
    levels = u.shape[0]
    first = np.asarray(first, dtype=np.int64)
    joined = (np.asarray(table[d]).min(axis=0)[a] <= sure for d, (a, _) in enumerate(_DIRECTIONS))
    count, flat = grid_components(*joined)
    labels = flat.reshape(h, w)

    flat_u = np.ascontiguousarray(u).reshape(levels, -1)
    of_block = ((np.arange(h) // block)[:, None] * u.shape[2] + np.arange(w) // block).ravel()  # each pixel's block

    def level_cost(kk: np.ndarray, at: np.ndarray | slice = slice(None)) -> np.ndarray:
        """The cost of the pixels ``at`` at the levels ``kk`` (clipped to the head's), raveled."""
        return flat_u.ravel().take(np.clip(kk, 0, levels - 1).ravel() * flat_u.shape[1] + of_block[at])

    # The global move: the offset the level costs prefer (ties: the smallest move), over -LEVELS .. LEVELS. The
    # costs per level of the pixels at each k give every offset's total at once; below -LEVELS and from 2 LEVELS - 1
    # on, every such offset clips k alike.
    by_k = (np.clip(k, -levels, 2 * levels - 1) + levels).ravel()
    sums = np.stack([np.bincount(by_k, flat_u[i].take(of_block), 3 * levels) for i in range(levels)])
    at = np.arange(3 * levels)

    def total(g: int) -> float:
        return float(sums[np.clip(at - levels + g, 0, levels - 1), at].sum())

    offset = min(range(-levels, levels + 1), key=lambda g: (total(g), abs(g)))
    k = k + offset
    # Each region's level cost at a total move t in -_REACH .. _REACH from there, less that at t = 0, computed the
    # first time the region may move to t (most regions never move; those that do, rarely far). Summed pixel by
    # pixel in raster order, as a bincount over the whole plane would.
    base = np.bincount(flat, level_cost(k), count)
    level = np.zeros((2 * _REACH + 1, count), dtype=np.float32)
    ready = np.zeros((2 * _REACH + 1, count), dtype=bool)
    ready[_REACH] = True  # t = 0: no change
    pixels = np.argsort(flat, kind="stable")  # region by region, each in raster order
    starts = np.concatenate([[0], np.cumsum(np.bincount(flat, minlength=count))])
    flat_k = k.ravel()

    def fill(to: np.ndarray, regions: np.ndarray, whole_rows: bool) -> None:
        """Make ``level[to + _REACH, regions]`` ready where ``|to| <= _REACH`` ((S, n) totals of n regions); with
        ``whole_rows`` (the first round: every region, none moved yet), the rows of ``to`` for every region at once."""
        if whole_rows:
            for t in np.unique(to[np.abs(to) <= _REACH]).tolist():
                if not ready[t + _REACH].all():
                    level[t + _REACH] = weight * (np.bincount(flat, level_cost(k + t), count) - base)
                    ready[t + _REACH] = True
            return
        where = (np.abs(to) <= _REACH) & ~ready[np.clip(to, -_REACH, _REACH) + _REACH, regions]
        if not where.any():
            return
        t, r = to[where], np.broadcast_to(regions, to.shape)[where]
        lengths = starts[r + 1] - starts[r]
        local = np.repeat(np.arange(r.size), lengths)
        pixel = pixels[np.arange(local.size) + np.repeat(starts[r] - np.cumsum(lengths) + lengths, lengths)]
        value = level_cost(flat_k[pixel] + t[local], pixel)
        level[t + _REACH, r] = weight * (np.bincount(local, value, r.size) - base[r])
        ready[t + _REACH, r] = True

    # The pairs between regions (both directions): their regions, their jump now (as an index into their table)
    # and their tables.
    ends_a, ends_b, jumps, tables = [], [], [], []
    for d, (a, b) in enumerate(_DIRECTIONS):
        cross = labels[a] != labels[b]
        wd = np.mod(m[b] - m[a] + period // 2, period) - period // 2
        n = (m[b] + period * k[b] - m[a] - period * k[a] - wd)[cross] // period - first[d][a][cross]
        ends_a.append(labels[a][cross])
        ends_b.append(labels[b][cross])
        jumps.append(n)
        tables.append(np.clip(np.asarray(table[d])[(slice(None), *a)][:, cross], 0.0, _MAX_COST).astype(np.float32))
    ra, rb, n0, lp = (np.concatenate(x, axis=-1) for x in (ends_a, ends_b, jumps, tables))
    del ends_a, ends_b, jumps, tables
    size = lp.shape[0]
    shifts = np.asarray(_SHIFTS)
    reach = int(np.abs(shifts).max())
    steps = np.arange(-reach, reach + 1)[:, None]
    # Every region's border pairs, region by region: the pair, and whether the region is its second end.
    owner = np.concatenate([ra, rb])
    order = np.argsort(owner, kind="stable")
    incident, second = order % max(ra.size, 1), order >= ra.size
    other = np.where(second, ra[incident], rb[incident])  # the region across each of those pairs
    bounds = np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=count))])
    del owner, order

    def entries(regions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For ``regions``' border pairs: the position of the region in ``regions`` and the pair's entry."""
        lengths = bounds[regions + 1] - bounds[regions]
        local = np.repeat(np.arange(regions.size), lengths)
        return local, np.arange(local.size) - np.repeat(np.cumsum(lengths) - lengths - bounds[regions], lengths)

    def costs(index: np.ndarray, pair: np.ndarray | slice) -> np.ndarray:
        """(2 reach + 1, n): the costs of pairs ``pair`` at their jumps (``index``, into their tables) moved by
        ``-reach .. reach``."""
        index = index + steps
        inside = (index >= 0) & (index < size)
        return np.where(inside, np.take_along_axis(lp[:, pair], np.clip(index, 0, size - 1), 0), _MAX_COST)

    def drops(regions: np.ndarray, local: np.ndarray | None, entry: np.ndarray | None, first: bool) -> np.ndarray:
        """(len(shifts), len(regions)): how much the cost changes if each region moves by each shift now, from
        ``entries(regions)`` (every region when ``regions`` is all of them: then pair by pair; ``first``: the first
        round)."""
        to = moved[regions] + shifts[:, None]
        fill(to, regions, whole_rows=first)
        delta = np.where(np.abs(to) <= _REACH, level[np.clip(to, -_REACH, _REACH) + _REACH, regions], np.inf)
        delta -= level[moved[regions] + _REACH, regions]
        slots = np.arange(shifts.size)[:, None] * regions.size
        # Moving the first region of a pair by s changes its jump by -s, moving the second by +s. In pieces of
        # _CHUNK pairs (or entries), so the first rounds, with every region active, stay small in memory.
        if regions.size == count:
            for c0 in range(0, ra.size, _CHUNK):
                part = slice(c0, c0 + _CHUNK)
                cost = costs(n0[part] + moved[rb[part]] - moved[ra[part]], part)
                for ends, sign in ((ra[part], -1), (rb[part], 1)):
                    change = (cost[reach + sign * shifts[:, None]] - cost[reach]).ravel()
                    delta += np.bincount((slots + ends).ravel(), change, delta.size).reshape(delta.shape)
            return delta
        assert local is not None and entry is not None
        for c0 in range(0, entry.size, _CHUNK):
            pair, flip, at = incident[entry[c0 : c0 + _CHUNK]], second[entry[c0 : c0 + _CHUNK]], local[c0 : c0 + _CHUNK]
            cost = costs(n0[pair] + moved[rb[pair]] - moved[ra[pair]], pair)
            change = np.where(flip, cost[reach + shifts[:, None]], cost[reach - shifts[:, None]]) - cost[reach]
            delta += np.bincount((slots + at).ravel(), change.ravel(), delta.size).reshape(delta.shape)
        return delta

    def neighbours_best(regions: np.ndarray) -> np.ndarray:
        """The largest drop (least ``best``) among each of ``regions``' neighbours (``inf``: none)."""
        lengths = bounds[regions + 1] - bounds[regions]
        out = np.full(regions.size, np.inf)
        some = lengths > 0
        if some.any():
            values = best[other] if regions.size == count else best[other[entries(regions)[1]]]
            out[some] = np.minimum.reduceat(values, (np.cumsum(lengths) - lengths)[some])
        return out

    mark = np.zeros(count, dtype=bool)

    def union(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The sorted regions in ``a`` or ``b``."""
        mark[a] = True
        mark[b] = True
        out = np.flatnonzero(mark)
        mark[out] = False
        return out

    moved = np.zeros(count, dtype=np.int64)  # each region's total move
    best = np.zeros(count)  # the largest drop of the cost a move of each region gives now (negative: a drop) ...
    choice = np.zeros(count, dtype=np.int64)  # ... and that move (an index into shifts)
    active = np.arange(count)  # the regions whose drop must be computed again: the movers and their neighbours
    for round_ in range(rounds):
        every = active.size == count  # the first round: pair by pair, no entries needed
        local, entry = (None, None) if every else entries(active)
        delta = drops(active, local, entry, first=round_ == 0)
        best[active], choice[active] = delta.min(axis=0), delta.argmin(axis=0)
        # A region moves when its drop is larger than all its neighbours' (no two neighbours move in one round);
        # only the active regions and their neighbours can decide differently from the last round.
        candidates = active if every else union(active, other[entry])
        move = (best[candidates] < -1e-6) & (best[candidates] < neighbours_best(candidates))
        if not move.any():
            break
        movers = candidates[move]
        moved[movers] += shifts[choice[movers]]
        active = union(movers, other[entries(movers)[1]])
    return k + moved[labels]
