"""Region moves: whole regions of a decoded plane moved by whole periods where the level head's costs say so.

The spanning tree (:func:`~torch_modulo.singleshot.learned.decode_jumps`) often puts whole regions one or two
periods off: a region ringed by steps the network is unsure of hangs on the one pair the tree crossed it by.
Neighbour steps cannot settle such a region; its own content can: texture under multiplicative shading is larger
in counts where the radiance is higher, and lamps, skies and windows look like what they are. The level head
(:class:`~torch_modulo.singleshot.learned.LevelNet`) gives every 2 x 2 block a cost ``-log p(k)`` of each level.

:class:`RegionMoves` decodes exactly, in integers: the whole plane first moves by the level the head prefers
(:meth:`RegionMoves.global_offset`); then the plane is cut into the regions joined by pairs the edge network is sure
of, and each region may move by ``-2 .. 2`` periods where the head's costs plus the costs of the region's moved
border pairs drop. Every round moves the regions whose drop is larger than all their neighbours', until none drops.
Every output is ``I_m + k 2^N`` with integer ``k``.
"""

from __future__ import annotations

import numpy as np

from torch_modulo._checks import check_int
from torch_modulo.singleshot.grid import grid_components
from torch_modulo.singleshot.learned.decoding import DIRECTIONS, MAX_COST, table_indices

__all__ = ["RegionMoves", "region_moves"]

#: The moves a region may make in one round, in periods.
_SHIFTS = (-2, -1, 1, 2)

#: How far a region may end up from where the global move put it, in periods (farther moves are not tried).
_REACH = 8

#: The moves weigh the border pairs of this many at a time (a bound on their memory).
_CHUNK = 2**18


class RegionMoves:
    """The region moves of one plane (see the module docstring): build it, then :meth:`run` it.

    Args:
        modulus: (H, W) integer moduli.
        k: (H, W) integer rollover counts (e.g. the spanning tree's).
        table: (2, K, H, W) costs ``-log p`` of K consecutive jumps per pair (direction 0: to the right, 1: down):
            ``table[d, i]`` is the cost of the jump ``first[d] + i``; jumps outside cost
            :data:`~torch_modulo.singleshot.learned.MAX_COST`, and costs are clipped to it. The regions are joined
            by the pairs whose least cost in the table is at most ``sure``.
        first: (2, H, W) integers: the jump of ``table``'s first entry per pair.
        u: (L, ceil(H / block), ceil(W / block)) every block's cost of each level
            (:func:`~torch_modulo.singleshot.learned.predict_levels`: 2 x 2 blocks from the top left), shared by the
            block's pixels.
        bits: the sensor bit depth ``N``.
        weight: the weight of the level costs against the pairs'.
        sure: pairs at most this costly join a region.
        block: the side of the blocks of ``u`` (1: a cost per pixel).

    Attributes:
        labels: (H, W) the region of every pixel, ``0 .. count - 1``.
        count: the number of regions.
        moved: (count,) every region's move so far, in periods, from where the global move put it.

    Example:
        >>> m = np.array([[10, 10, 10, 10]])
        >>> table = np.full((2, 3, 1, 4), 30.0); table[:, 1] = 0.0  # jumps -1, 0, 1: sure of 0 ...
        >>> table[0, :, 0, 1] = [30.0, 1.0, 2.0]  # ... but for the middle pair, which may well be 1
        >>> u = np.full((16, 1, 2), 9.0); u[0, 0, 0] = 0.0; u[1, 0, 1] = 0.0  # the right block is a period up
        >>> moves = RegionMoves(m, np.zeros((1, 4), int), table, np.full((2, 1, 4), -1), u, 8)
        >>> moves.count, moves.global_offset()
        (2, 0)
        >>> moves.run().tolist()
        [[0, 0, 1, 1]]
    """

    def __init__(
        self,
        modulus: np.ndarray,
        k: np.ndarray,
        table: np.ndarray,
        first: np.ndarray,
        u: np.ndarray,
        bits: int,
        *,
        weight: float = 1.0,
        sure: float = 0.01,
        block: int = 2,
    ) -> None:
        m = np.asarray(modulus, dtype=np.int64)
        self.k = np.asarray(k, dtype=np.int64)
        u = np.asarray(u)
        h, w = m.shape
        block = check_int(block, "block", 1)
        if u.ndim != 3 or u.shape[1:] != (-(-h // block), -(-w // block)):
            raise ValueError(f"level costs of shape {u.shape} for a {h} x {w} plane in blocks of {block}")
        self.weight = float(weight)
        self.levels = u.shape[0]
        if self.k.size == 0:  # nothing to move
            self.count, self.labels, self.moved = 0, self.k, np.zeros(0, dtype=np.int64)
            return
        first = np.asarray(first, dtype=np.int64)
        joined = (np.asarray(table[d]).min(axis=0)[a] <= sure for d, (a, _) in enumerate(DIRECTIONS))
        self.count, self.flat = grid_components(*joined)
        self.labels = self.flat.reshape(h, w)
        self.flat_u = np.ascontiguousarray(u).reshape(self.levels, -1)
        self.of_block = ((np.arange(h) // block)[:, None] * u.shape[2] + np.arange(w) // block).ravel()
        self._border_pairs(m, np.asarray(table), first, 1 << bits)
        self.moved = np.zeros(self.count, dtype=np.int64)
        self._mark = np.zeros(self.count, dtype=bool)

    def _union(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The sorted regions in ``a`` or ``b``."""
        self._mark[a] = True
        self._mark[b] = True
        out = np.flatnonzero(self._mark)
        self._mark[out] = False
        return out

    def _border_pairs(self, m: np.ndarray, table: np.ndarray, first: np.ndarray, period: int) -> None:
        """The pairs between regions (both directions): their regions ``ra``, ``rb``, their jump under ``k`` (``n0``,
        an index into their tables ``lp``), and every region's border pairs, region by region."""
        labels = self.labels
        ends_a, ends_b, jumps, tables = [], [], [], []
        for d, ((a, b), n) in enumerate(zip(DIRECTIONS, table_indices(m, self.k, first, period), strict=True)):
            cross = labels[a] != labels[b]
            ends_a.append(labels[a][cross])
            ends_b.append(labels[b][cross])
            jumps.append(n[cross])
            tables.append(np.clip(table[d][(slice(None), *a)][:, cross], 0.0, MAX_COST).astype(np.float32))
        self.ra, self.rb, self.n0, self.lp = (np.concatenate(x, axis=-1) for x in (ends_a, ends_b, jumps, tables))
        owner = np.concatenate([self.ra, self.rb])
        order = np.argsort(owner, kind="stable")
        #: Per region, its border pairs, whether the region is their second end, and the region across.
        self.incident, self.second = order % max(self.ra.size, 1), order >= self.ra.size
        self.other = np.where(self.second, self.ra[self.incident], self.rb[self.incident])
        self.bounds = np.concatenate([[0], np.cumsum(np.bincount(owner, minlength=self.count))])

    def level_cost(self, k: np.ndarray, at: np.ndarray | slice = slice(None)) -> np.ndarray:
        """The level cost of the pixels ``at`` (raveled indices; default all) at the levels ``k`` (clipped to the
        head's), raveled."""
        index = np.clip(k, 0, self.levels - 1).ravel() * self.flat_u.shape[1] + self.of_block[at]
        return self.flat_u.ravel().take(index)

    def global_offset(self) -> int:
        """The offset of the whole plane the level costs prefer (ties: the smallest move), in ``-L .. L``.

        The costs per level of the pixels at each ``k`` give every offset's total at once; below ``-L`` and from
        ``2 L - 1`` on, every such offset clips ``k`` alike.
        """
        levels = self.levels
        by_k = (np.clip(self.k, -levels, 2 * levels - 1) + levels).ravel()
        sums = np.stack([np.bincount(by_k, self.flat_u[i].take(self.of_block), 3 * levels) for i in range(levels)])
        at = np.arange(3 * levels)

        def total(g: int) -> float:
            return float(sums[np.clip(at - levels + g, 0, levels - 1), at].sum())

        return min(range(-levels, levels + 1), key=lambda g: (total(g), abs(g)))

    def _start(self, offset: int) -> None:
        """Apply the global ``offset`` and set up the regions' level-cost changes, filled as moves are tried.

        ``level[t + _REACH, r]`` is region ``r``'s level cost at a total move ``t`` in ``-_REACH .. _REACH``, less
        that at ``t = 0``, computed the first time the region may move to ``t`` (most regions never move; those that
        do, rarely far); summed pixel by pixel in raster order, as a bincount over the whole plane would.
        """
        self.k = self.k + offset
        self.base = np.bincount(self.flat, self.level_cost(self.k), self.count)
        self.level = np.zeros((2 * _REACH + 1, self.count), dtype=np.float32)
        self.ready = np.zeros((2 * _REACH + 1, self.count), dtype=bool)
        self.ready[_REACH] = True  # t = 0: no change
        self.pixels = np.argsort(self.flat, kind="stable")  # region by region, each in raster order
        self.starts = np.concatenate([[0], np.cumsum(np.bincount(self.flat, minlength=self.count))])

    def _fill(self, to: np.ndarray, regions: np.ndarray, whole_rows: bool) -> None:
        """Make ``level[to + _REACH, regions]`` ready where ``|to| <= _REACH`` ((S, n) totals of n regions); with
        ``whole_rows`` (the first round: every region, none moved yet), the rows of ``to`` for every region at once."""
        level, ready = self.level, self.ready
        if whole_rows:
            for t in np.unique(to[np.abs(to) <= _REACH]).tolist():
                if not ready[t + _REACH].all():
                    level[t + _REACH] = self.weight * (
                        np.bincount(self.flat, self.level_cost(self.k + t), self.count) - self.base
                    )
                    ready[t + _REACH] = True
            return
        where = (np.abs(to) <= _REACH) & ~ready[np.clip(to, -_REACH, _REACH) + _REACH, regions]
        if not where.any():
            return
        t, r = to[where], np.broadcast_to(regions, to.shape)[where]
        lengths = self.starts[r + 1] - self.starts[r]
        local = np.repeat(np.arange(r.size), lengths)
        pixel = self.pixels[np.arange(local.size) + np.repeat(self.starts[r] - np.cumsum(lengths) + lengths, lengths)]
        value = self.level_cost(self.k.ravel()[pixel] + t[local], pixel)
        level[t + _REACH, r] = self.weight * (np.bincount(local, value, r.size) - self.base[r])
        ready[t + _REACH, r] = True

    def _entries(self, regions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For ``regions``' border pairs: the position of the region in ``regions`` and the pair's entry."""
        lengths = self.bounds[regions + 1] - self.bounds[regions]
        local = np.repeat(np.arange(regions.size), lengths)
        return local, np.arange(local.size) - np.repeat(np.cumsum(lengths) - lengths - self.bounds[regions], lengths)

    def _costs(self, pair: np.ndarray | slice, reach: int) -> np.ndarray:
        """(2 reach + 1, n): the costs of the pairs ``pair`` at their jumps now moved by ``-reach .. reach``."""
        index = (
            self.n0[pair]
            + self.moved[self.rb[pair]]
            - self.moved[self.ra[pair]]
            + np.arange(-reach, reach + 1)[:, None]
        )
        size = self.lp.shape[0]
        inside = (index >= 0) & (index < size)
        return np.where(inside, np.take_along_axis(self.lp[:, pair], np.clip(index, 0, size - 1), 0), MAX_COST)

    def drops(self, regions: np.ndarray, first: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        """How much the cost changes if each of ``regions`` (sorted) moves by each shift now: (len(shifts),
        len(regions)), and the entries of their border pairs (``None`` when ``regions`` is every region: then the
        pairs are read pair by pair). ``first``: the first round."""
        shifts = np.asarray(_SHIFTS)[:, None]
        reach = int(np.abs(shifts).max())
        to = self.moved[regions] + shifts
        self._fill(to, regions, whole_rows=first)
        level = self.level
        delta = np.where(np.abs(to) <= _REACH, level[np.clip(to, -_REACH, _REACH) + _REACH, regions], np.inf)
        delta -= level[self.moved[regions] + _REACH, regions]
        slots = np.arange(shifts.size)[:, None] * regions.size
        # Moving the first region of a pair by s changes its jump by -s, moving the second by +s. In pieces of
        # _CHUNK pairs (or entries), so the first rounds, with every region active, stay small in memory.
        if regions.size == self.count:
            for c0 in range(0, self.ra.size, _CHUNK):
                part = slice(c0, c0 + _CHUNK)
                cost = self._costs(part, reach)
                for ends, sign in ((self.ra[part], -1), (self.rb[part], 1)):
                    change = (cost[reach + sign * shifts] - cost[reach]).ravel()
                    delta += np.bincount((slots + ends).ravel(), change, delta.size).reshape(delta.shape)
            return delta, None
        local, entry = self._entries(regions)
        for c0 in range(0, entry.size, _CHUNK):
            pair, flip, at = (
                self.incident[entry[c0 : c0 + _CHUNK]],
                self.second[entry[c0 : c0 + _CHUNK]],
                local[c0 : c0 + _CHUNK],
            )
            cost = self._costs(pair, reach)
            change = np.where(flip, cost[reach + shifts], cost[reach - shifts]) - cost[reach]
            delta += np.bincount((slots + at).ravel(), change.ravel(), delta.size).reshape(delta.shape)
        return delta, entry

    def _neighbours_best(self, regions: np.ndarray, best: np.ndarray) -> np.ndarray:
        """The largest drop (least ``best``) among each of ``regions``' neighbours (``inf``: none)."""
        lengths = self.bounds[regions + 1] - self.bounds[regions]
        out = np.full(regions.size, np.inf)
        some = lengths > 0
        if some.any():
            values = best[self.other] if regions.size == self.count else best[self.other[self._entries(regions)[1]]]
            out[some] = np.minimum.reduceat(values, (np.cumsum(lengths) - lengths)[some])
        return out

    def run(self, rounds: int = 60) -> np.ndarray:
        """The global move, then at most ``rounds`` rounds of region moves: int64 (H, W), ``k`` plus an integer per
        region (so ``modulus + k 2^N`` stays consistent with the modulus)."""
        if self.k.size == 0:
            return self.k.copy()
        self._start(self.global_offset())
        shifts = np.asarray(_SHIFTS)
        best = np.zeros(self.count)  # the largest drop of the cost a move of each region gives now (negative) ...
        choice = np.zeros(self.count, dtype=np.int64)  # ... and that move (an index into the shifts)
        active = np.arange(self.count)  # the regions whose drop must be computed again: the movers and neighbours
        for round_ in range(rounds):
            delta, entry = self.drops(active, first=round_ == 0)
            best[active], choice[active] = delta.min(axis=0), delta.argmin(axis=0)
            # A region moves when its drop is larger than all its neighbours' (no two neighbours move in one round);
            # only the active regions and their neighbours can decide differently from the last round.
            candidates = active if entry is None else self._union(active, self.other[entry])
            move = (best[candidates] < -1e-6) & (best[candidates] < self._neighbours_best(candidates, best))
            if not move.any():
                break
            movers = candidates[move]
            self.moved[movers] += shifts[choice[movers]]
            active = self._union(movers, self.other[self._entries(movers)[1]])
        return self.k + self.moved[self.labels]


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
    """``k`` of one plane moved by the level costs: the global level, then whole regions (:class:`RegionMoves`).

    Args:
        modulus: (H, W) integer moduli.
        k: (H, W) integer rollover counts (e.g. the spanning tree's).
        table: (2, K, H, W) costs ``-log p`` of K consecutive jumps per pair (see :class:`RegionMoves`).
        first: (2, H, W) integers: the jump of ``table``'s first entry per pair.
        u: (L, ceil(H / block), ceil(W / block)) every block's cost of each level.
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
    moves = RegionMoves(modulus, k, table, first, u, bits, weight=weight, sure=sure, block=block)
    return moves.run(rounds)
