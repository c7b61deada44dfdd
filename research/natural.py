"""Single-shot unwrapping for natural scenes: a log-domain image model, colour coupling and region moves.

Research code, not part of the package (README.md, "A natural-image model"): every model tried here found
wrong solutions of lower energy than the truth.

The paper's energy (Eqs. 3, 5) penalises linear differences of the restored image ``I = I_m + k 2^N`` (Eq. 2).
On real photographs it prefers wrong solutions: at high counts a real edge is hundreds of counts, and the
quadratic tail of Eq. 5 pulls bright objects down to their background. This module
replaces the model, keeping the move-making idea of Sec. 4.2:

- **Log-domain prior.** The image is modelled through ``u = log(I + c)``; neighbouring differences of ``u`` follow
  a heavy-tailed Student-t law (natural-image gradient statistics), so the pair cost is
  ``rho(du) = log(1 + (du / sigma)^2)``. The change of variables from ``u`` back to the counts adds the Jacobian
  ``sum_i log(I_i + c)`` (a ``1/I`` prior on intensities), which stops the model from lifting everything up.
  Inside a region the texture's log-contrast shrinks as the region is lifted, so the level of a region enclosed
  by a steep edge is set by its own texture and by the Jacobian, instead of being pulled down to its border.
- **Colour coupling.** For colour images the log-differences of the channels are tied together:
  ``rho_c(du_c - du_c')`` for every pair of channels, so an illumination edge that rolls one channel over is
  explained by the others (channel ratios stay nearly constant across such edges). Channels are solved in turn
  (block coordinate descent), each seeing the others as fixed.
- **Bounds.** ``k >= 0``, and with ``max_count`` (a sensor that saturates) ``I_m + k 2^N <= max_count``.
- **Optimiser.** Quality-guided initial ``k`` (Herraez et al. 2002, :mod:`torch_modulo.singleshot.pathfollow`), then
  binary moves ``k <- k + t delta`` (``t = +-1, +-2, ...``) solved by max-flow on contracted graphs: regions of
  the current restored image (pixels joined by ``|I_i - I_j| <= link``) move together, from coarse (large
  ``link``) to the pixel grid. Each move's pair terms are made submodular by dropping the non-representable part
  (Eq. 4, as in the paper and PUMA); a move is kept only if the exact energy drops.
- **Confidence.** Optional: per pixel, the energy increase of the cheapest alternative ``k`` of its region
  (``return_confidence=True``); low values mark where a second exposure would help.

The faithful solver of the paper stays in :mod:`torch_modulo.singleshot.graphcut`; ``potential="linear"`` here
runs the paper's Eq. 5 through this optimiser for comparison.

Status (README.md): on the dev scenes every model tried here (Student-t and Laplace log-domain potentials with
and without the Jacobian, colour coupling, the paper's Eq. 5) gives the solution the optimiser finds a LOWER
energy than the truth, and the refinement loses exact-k against its own initialisation. The default is therefore
the initialisation alone (quality-guided ``k`` with the saturation bound, ``links=()``); the refinement is opt-in
(``links=(64, 16, 0)``), and slow.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields

import maxflow
import numpy as np
import torch
from torch import nn

from torch_modulo.singleshot.anchor import anchor_k
from torch_modulo.singleshot.energy import EnergyParams, potential_np
from torch_modulo.singleshot.grid import pair_indices, pair_offsets
from torch_modulo.singleshot.pathfollow import quality_guided_k

__all__ = ["NaturalOptions", "NaturalUnwrap", "natural_energy", "unwrap_natural", "unwrap_natural_torch"]

_BIG = 1e9


def _check_bits(bits: object) -> int:
    """The bit depth as ``int`` in [1, 52]; raises naming the value."""
    if isinstance(bits, bool) or not isinstance(bits, int | np.integer):
        raise TypeError(f"bits must be an integer; got {bits!r}")
    if not 1 <= bits <= 52:
        raise ValueError(f"bits must be in [1, 52]; got {bits}")
    return int(bits)


def _check_tensor(modulus: object) -> torch.Tensor:
    """A finite floating tensor of 2 to 4 dimensions; raises naming what is wrong."""
    if not isinstance(modulus, torch.Tensor) or not modulus.is_floating_point():
        got = modulus.dtype if isinstance(modulus, torch.Tensor) else type(modulus).__name__
        raise TypeError(f"modulus must be a floating-point tensor; got {got}")
    if not 2 <= modulus.ndim <= 4:
        raise ValueError(f"modulus must be (B, C, H, W), (C, H, W) or (H, W); got shape {tuple(modulus.shape)}")
    if not bool(torch.isfinite(modulus).all()):
        raise ValueError("modulus must be finite; got NaN or infinite values")
    return modulus


@dataclass(frozen=True)
class NaturalOptions:
    """Options of :func:`unwrap_natural` (validated by :meth:`make`).

    Attributes:
        potential: ``"log"`` (a potential on log-differences, default) or ``"linear"`` (the paper's Eq. 5).
        rho: the log-domain potential: ``"student"`` (``log(1 + (du / sigma)^2)``) or ``"laplace"``
            (``|du| / sigma``).
        sigma: scale of the log-differences in ``rho`` (natural images: about 0.05-0.2).
        offset: ``c`` in ``log(I + c)``, in counts; tempers the dark, noisy and quantised low counts.
        jacobian: weight of ``sum log(I + c)`` (1 is the exact change of variables).
        smooth: weight of the per-channel log-difference term.
        colour: weight of the cross-channel term (0 disables colour coupling).
        colour_sigma: scale of the cross-channel differences ``du_c - du_c'``.
        neighborhood: 4 or 8.
        links: region links in counts, coarse to fine, for the model-based refinement; 0 means the pixel grid.
            Empty (the default) skips the refinement: on the dev scenes every refinement tried lowered the
            model energy below the truth's and lost exact-k (README.md).
        max_step: the largest move step ``t`` in periods.
        max_count: the sensor's largest count (saturation) or ``None`` for unbounded.
        rounds: colour rounds (each solves every channel once).
        max_cuts: the most cuts per channel and round.
        confidence_link: region link (counts) of the confidence map.
    """

    potential: str = "log"
    rho: str = "student"
    sigma: float = 0.1
    offset: float = 16.0
    jacobian: float = 1.0
    smooth: float = 1.0
    colour: float = 1.0
    colour_sigma: float = 0.1
    neighborhood: int = 4
    links: tuple[float, ...] = ()
    max_step: int = 3
    max_count: float | None = None
    rounds: int = 2
    max_cuts: int = 400
    confidence_link: float = 16.0

    @classmethod
    def make(cls, **options: object) -> NaturalOptions:
        """Validate keyword options; unknown names and bad values raise with the value in the message.

        Raises:
            TypeError: an unknown option, or a value of the wrong type.
            ValueError: a value out of range.
        """
        known = {f.name for f in fields(cls)}
        for name in options:
            if name not in known:
                raise TypeError(f"unknown option {name!r}; known: {sorted(known)}")
        opts = dict(options)
        if "potential" in opts and opts["potential"] not in ("log", "linear"):
            raise ValueError(f"potential must be 'log' or 'linear'; got {opts['potential']!r}")
        for name in ("sigma", "offset", "jacobian", "smooth", "colour", "colour_sigma", "confidence_link"):
            if name in opts:
                v = opts[name]
                if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
                    raise TypeError(f"{name} must be a finite real number; got {v!r}")
                opts[name] = float(v)
                if opts[name] < 0 or (name in ("sigma", "colour_sigma") and opts[name] == 0):
                    raise ValueError(f"{name} must be {'> 0' if 'sigma' in name else '>= 0'}; got {v!r}")
        if "offset" in opts and opts["offset"] <= 0:
            raise ValueError(f"offset must be > 0; got {opts['offset']!r}")
        if "rho" in opts and opts["rho"] not in ("student", "laplace"):
            raise ValueError(f"rho must be 'student' or 'laplace'; got {opts['rho']!r}")
        if "neighborhood" in opts:
            pair_offsets(opts["neighborhood"])  # raises ValueError naming the value
        for name in ("max_step", "rounds", "max_cuts"):
            if name in opts:
                v = opts[name]
                if isinstance(v, bool) or not isinstance(v, int):
                    raise TypeError(f"{name} must be an integer; got {v!r}")
                if v < 1:
                    raise ValueError(f"{name} must be >= 1; got {v!r}")
        if "links" in opts:
            links = opts["links"]
            if isinstance(links, int | float) and not isinstance(links, bool):
                links = (links,)
            try:
                links = tuple(float(x) for x in links)  # type: ignore[union-attr]
            except TypeError as err:
                raise TypeError(f"links must be a sequence of numbers; got {opts['links']!r}") from err
            if any(not math.isfinite(x) or x < 0 for x in links):
                raise ValueError(f"links must be a sequence of finite numbers >= 0; got {opts['links']!r}")
            opts["links"] = links
        if opts.get("max_count") is not None:
            v = opts["max_count"]
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
                raise TypeError(f"max_count must be a finite number or None; got {v!r}")
            if v < 0:
                raise ValueError(f"max_count must be >= 0; got {v!r}")
            opts["max_count"] = float(v)
        return cls(**opts)  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------------------- model


class _Model:
    """Pair costs of one channel given the other channels (fixed), on flat pair index arrays."""

    def __init__(self, opts: NaturalOptions, period: int) -> None:
        self.o = opts
        self.period = period
        self.paper = EnergyParams.make(int(round(math.log2(period)))) if opts.potential == "linear" else None
        self.inv_s2 = 1.0 / (opts.sigma * opts.sigma)
        self.inv_c2 = 1.0 / (opts.colour_sigma * opts.colour_sigma)

    def u(self, a: np.ndarray) -> np.ndarray:
        return np.log(np.maximum(a + self.o.offset, 1e-3))

    def pair(self, a: np.ndarray, b: np.ndarray, guides: list[np.ndarray]) -> np.ndarray:
        """Cost of pairs with restored values ``a`` and ``b``; ``guides`` are the other channels' du."""
        if self.paper is not None:
            return potential_np(a - b, self.paper)
        du = self.u(a) - self.u(b)
        if self.o.smooth <= 0:
            cost = np.zeros_like(du)
        elif self.o.rho == "laplace":
            cost = (self.o.smooth / self.o.sigma) * np.abs(du)
        else:
            cost = self.o.smooth * np.log1p(du * du * self.inv_s2)
        if self.o.colour > 0:
            for g in guides:
                x = du - g
                cost += self.o.colour * np.log1p(x * x * self.inv_c2)
        return cost

    def unary(self, a: np.ndarray) -> np.ndarray:
        if self.paper is not None or self.o.jacobian == 0:
            return np.zeros_like(a)
        return self.o.jacobian * self.u(a)


class _Pairs:
    """Flat indices of every unordered neighbour pair of an (H, W) grid."""

    def __init__(self, h: int, w: int, neighborhood: int) -> None:
        pairs = [pair_indices(h, w, off) for off in pair_offsets(neighborhood)]
        self.i = np.concatenate([p[0] for p in pairs]) if pairs else np.zeros(0, np.int64)
        self.j = np.concatenate([p[1] for p in pairs]) if pairs else np.zeros(0, np.int64)
        self.h, self.w = h, w
        # 4-neighbour pairs for region labelling.
        four = [pair_indices(h, w, off) for off in ((0, 1), (1, 0))]
        self.i4 = np.concatenate([f for f, _ in four])
        self.j4 = np.concatenate([s for _, s in four])


def _guides(restored: np.ndarray, c: int, pairs: _Pairs, model: _Model) -> list[np.ndarray]:
    if model.o.colour <= 0 or model.paper is not None:
        return []
    out = []
    for other in range(restored.shape[0]):
        if other != c:
            u = model.u(restored[other].ravel())
            out.append(u[pairs.i] - u[pairs.j])
    return out


def _channel_energy(a: np.ndarray, pairs: _Pairs, model: _Model, guides: list[np.ndarray]) -> float:
    return float(model.pair(a[pairs.i], a[pairs.j], guides).sum() + model.unary(a).sum())


def natural_energy(restored: np.ndarray, bits: int = 8, **options: object) -> float:
    """The energy of :func:`unwrap_natural` for a restored (C, H, W) image (lower is more natural).

    Self terms of every channel plus the cross-channel terms counted once per pair of channels, plus the
    Jacobian. Use it to compare the truth with a solution (is a failure the model's or the optimiser's?).

    Example:
        >>> flat = np.full((1, 4, 4), 100.0)
        >>> natural_energy(flat, 8, jacobian=0.0)
        0.0
    """
    opts = NaturalOptions.make(**options)
    restored = np.asarray(restored, dtype=np.float64)
    if restored.ndim != 3:
        raise ValueError(f"restored must be (C, H, W); got shape {restored.shape}")
    c, h, w = restored.shape
    model = _Model(opts, 1 << _check_bits(bits))
    pairs = _Pairs(h, w, opts.neighborhood)
    total = 0.0
    for ch in range(c):
        a = restored[ch].ravel()
        total += _channel_energy(a, pairs, model, [])  # self terms and Jacobian
        if opts.colour > 0 and model.paper is None:
            ua = model.u(a)
            for other in range(ch + 1, c):
                ub = model.u(restored[other].ravel())
                x = (ua[pairs.i] - ua[pairs.j]) - (ub[pairs.i] - ub[pairs.j])
                total += opts.colour * float(np.log1p(x * x * model.inv_c2).sum())
    return total


# ------------------------------------------------------------------------------------------------- regions


def _regions(a: np.ndarray, pairs: _Pairs, link: float) -> tuple[int, np.ndarray]:
    """Node label per pixel: 4-connected components of ``|a_i - a_j| <= link``; ``link = 0``: every pixel."""
    n = a.size
    if link <= 0:
        return n, np.arange(n, dtype=np.int64)
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    keep = np.abs(a[pairs.i4] - a[pairs.j4]) <= link
    r, c = pairs.i4[keep], pairs.j4[keep]
    graph = coo_matrix((np.ones(r.size, dtype=np.int8), (r, c)), shape=(n, n)).tocsr()
    count, labels = connected_components(graph, directed=False)
    return int(count), labels.astype(np.int64)


def _move(
    a: np.ndarray,
    k: np.ndarray,
    kmax: np.ndarray,
    node: np.ndarray,
    n_nodes: int,
    pairs: _Pairs,
    model: _Model,
    guides: list[np.ndarray],
    t: int,
) -> tuple[np.ndarray, float]:
    """One binary move ``k <- k + t x`` with one variable per node: returns the pixel mask and exact change."""
    shift = float(t * model.period)
    pi, pj = pairs.i, pairs.j
    ai, aj = a[pi], a[pj]
    e00 = model.pair(ai, aj, guides)
    e10 = model.pair(ai + shift, aj, guides) - e00
    e01 = model.pair(ai, aj + shift, guides) - e00
    e11 = model.pair(ai + shift, aj + shift, guides) - e00
    ni, nj = node[pi], node[pj]
    # Unary: Jacobian change, plus pairs internal to a node, plus forbidden nodes.
    un_px = model.unary(a + shift) - model.unary(a)
    unary = np.bincount(node, weights=un_px, minlength=n_nodes)
    bad = (k + t < 0) | (k + t > kmax)
    if bad.any():
        unary[np.unique(node[bad])] += _BIG
    same = ni == nj
    if same.any():
        unary += np.bincount(ni[same], weights=e11[same], minlength=n_nodes)
    cross = ~same
    u, v = ni[cross], nj[cross]
    f10, f01, f11 = e10[cross], e01[cross], e11[cross]
    # Canonical order lo < hi: swapping the ends swaps E10 and E01.
    flip = u > v
    lo = np.where(flip, v, u)
    hi = np.where(flip, u, v)
    g10 = np.where(flip, f01, f10)
    g01 = np.where(flip, f10, f01)
    if lo.size:
        keys, inv = np.unique(lo * n_nodes + hi, return_inverse=True)
        s10 = np.bincount(inv, weights=g10)
        s01 = np.bincount(inv, weights=g01)
        s11 = np.bincount(inv, weights=f11)
        klo, khi = keys // n_nodes, keys % n_nodes
        # theta = E10 x_lo + (E11 - E10) x_hi + w (1 - x_lo) x_hi, w = E01 + E10 - E11 (E00 = 0).
        w = np.maximum(s01 + s10 - s11, 0.0)
        unary += np.bincount(klo, weights=s10, minlength=n_nodes)
        unary += np.bincount(khi, weights=s11 - s10, minlength=n_nodes)
    graph = maxflow.Graph[float](n_nodes, int(lo.size and keys.size))
    graph.add_nodes(n_nodes)
    if lo.size:
        nzw = w > 0
        if nzw.any():
            graph.add_edges(klo[nzw], khi[nzw], w[nzw], np.zeros(int(nzw.sum())))
    nz = np.flatnonzero(unary)
    if nz.size:
        uu = unary[nz]
        graph.add_grid_tedges(nz, np.maximum(uu, 0.0), np.maximum(-uu, 0.0))
    graph.maxflow()
    x_node = graph.get_grid_segments(np.arange(n_nodes))
    x = x_node[node]
    if not x.any():
        return x, 0.0
    xi, xj = x[pi], x[pj]
    de = float(un_px[x].sum())
    de += float(e10[xi & ~xj].sum() + e01[~xi & xj].sum() + e11[xi & xj].sum())
    return x, de


def _solve_channel(
    restored: np.ndarray,
    c: int,
    kall: np.ndarray,
    kmax: np.ndarray,
    pairs: _Pairs,
    model: _Model,
    stats: dict,
) -> None:
    """Descend the energy of channel ``c`` (others fixed) in place: coarse-to-fine region moves."""
    o = model.o
    a = restored[c].ravel().copy()
    k = kall[c].ravel().copy()
    km = kmax[c].ravel()
    guides = _guides(restored, c, pairs, model)
    energy = _channel_energy(a, pairs, model, guides)
    steps = [s * t for t in range(1, o.max_step + 1) for s in (1, -1)]
    cuts = 0
    for link in o.links:
        while cuts < o.max_cuts:
            n_nodes, node = _regions(a, pairs, link)
            improved = False
            for t in steps:
                x, de = _move(a, k, km, node, n_nodes, pairs, model, guides, t)
                cuts += 1
                if de < -1e-9 * max(1.0, abs(energy)):
                    a[x] += t * model.period
                    k[x] += t
                    energy += de
                    improved = True
                    stats["accepted"] += 1
                if cuts >= o.max_cuts:
                    break
            if not improved:
                break
    stats["cuts"] += cuts
    restored[c] = a.reshape(restored.shape[1:])
    kall[c] = k.reshape(kall.shape[1:])


def _region_gaps(
    a: np.ndarray, k: np.ndarray, kmax: np.ndarray, pairs: _Pairs, model: _Model, guides: list[np.ndarray], link: float
) -> np.ndarray:
    """Per pixel: the smallest energy increase of moving its region (``link``) alone by one period up or down.

    Infeasible moves (``k`` leaving ``[0, kmax]``) count as infinite. A small gap means a second solution that
    the model finds almost as good: the rollover count there is uncertain.
    """
    n_nodes, node = _regions(a, pairs, link)
    pi, pj = pairs.i, pairs.j
    ni, nj = node[pi], node[pj]
    same = ni == nj
    best = np.full(n_nodes, np.inf)
    for t in (1, -1):
        shift = float(t * model.period)
        ai, aj = a[pi], a[pj]
        e00 = model.pair(ai, aj, guides)
        gain = np.bincount(node, weights=model.unary(a + shift) - model.unary(a), minlength=n_nodes)
        e11 = model.pair(ai[same] + shift, aj[same] + shift, _guides_sel(guides, same)) - e00[same]
        gain += np.bincount(ni[same], weights=e11, minlength=n_nodes)
        cross = ~same
        e10 = model.pair(ai[cross] + shift, aj[cross], _guides_sel(guides, cross)) - e00[cross]
        e01 = model.pair(ai[cross], aj[cross] + shift, _guides_sel(guides, cross)) - e00[cross]
        gain += np.bincount(ni[cross], weights=e10, minlength=n_nodes)
        gain += np.bincount(nj[cross], weights=e01, minlength=n_nodes)
        bad = (k + t < 0) | (k + t > kmax)
        gain[np.unique(node[bad])] = np.inf
        best = np.minimum(best, gain)
    return np.maximum(best, 0.0)[node]


def _guides_sel(guides: list[np.ndarray], mask: np.ndarray) -> list[np.ndarray]:
    return [g[mask] for g in guides]


def fit_bounds(k: np.ndarray, kmax: np.ndarray) -> np.ndarray:
    """Shift one channel's ``k`` by the global constant that puts most pixels inside ``[0, kmax]``, then clip.

    Unwrapping fixes ``k`` only up to a constant; when the sensor saturates (``max_count``) the true ``k`` lies in
    ``[0, kmax]``, so the constant is chosen to violate that range at the fewest pixels (ties: the smallest
    shift), and what still falls outside is clipped.
    """
    lo = int(k.min())
    hi = int(k.max())
    best, best_s = -1, 0
    for s in range(-hi, -lo + int(kmax.max()) + 1):
        inside = int(np.count_nonzero((k + s >= 0) & (k + s <= kmax)))
        if inside > best or (inside == best and abs(s) < abs(best_s)):
            best, best_s = inside, s
    return np.clip(k + best_s, 0, kmax)


def unwrap_natural(
    modulus: np.ndarray,
    bits: int = 8,
    *,
    init: np.ndarray | None = None,
    return_confidence: bool = False,
    **options: object,
) -> tuple[np.ndarray, dict]:
    """Unwrap one modulo image (all its channels together) with the natural-image model of this module.

    Args:
        modulus: (C, H, W) or (H, W) array of integers in ``[0, 2**bits)`` (any real dtype).
        bits: the sensor bit depth ``N``.
        init: optional (C, H, W) integer ``k`` to start from; default quality-guided path following.
        return_confidence: also compute ``info["confidence"]`` (see the module notes).
        **options: see :class:`NaturalOptions`.

    Returns:
        ``(restored, info)``: float64 restored counts ``I_m + k 2**bits`` of the input's shape (``k >= 0``), and a
        dict with ``energy`` (final), ``energy_init``, ``cuts``, ``accepted``, ``seconds``.

    Raises:
        TypeError: bad option names or types.
        ValueError: a bad shape, a value outside ``[0, 2**bits)`` or not an integer, bad option values.

    Example:
        >>> ramp = np.arange(0, 1200, 10, dtype=np.float64).reshape(1, 1, -1).repeat(4, axis=1)
        >>> restored, info = unwrap_natural(np.mod(ramp, 256), 8)
        >>> bool(np.array_equal(restored, ramp))
        True
    """
    start = time.perf_counter()
    opts = NaturalOptions.make(**options)
    bits = _check_bits(bits)
    m = np.asarray(modulus)
    if m.dtype == bool or not np.issubdtype(m.dtype, np.number) or np.iscomplexobj(m):
        raise TypeError(f"modulus must be a real numeric array; got dtype {m.dtype}")
    squeeze = m.ndim == 2
    if squeeze:
        m = m[None]
    if m.ndim != 3:
        raise ValueError(f"modulus must be (C, H, W) or (H, W); got shape {np.shape(modulus)}")
    m = m.astype(np.float64)
    period = 1 << bits
    if m.size and (not np.all(np.isfinite(m)) or m.min() < 0 or m.max() >= period or np.any(m != np.floor(m))):
        bad = m[~np.isfinite(m) | (m < 0) | (m >= period) | (m != np.floor(m))]
        raise ValueError(f"modulus must hold integers in [0, {period}); got {float(bad.ravel()[0])!r}")
    c, h, w = m.shape
    info: dict = {"cuts": 0, "accepted": 0}
    if m.size == 0:
        return (m[0] if squeeze else m).copy(), info
    if opts.max_count is not None:
        kmax = np.floor((opts.max_count - m) / period)
        kmax = np.maximum(kmax, 0.0).astype(np.int64)
    else:
        kmax = np.full(m.shape, np.iinfo(np.int64).max // 4, dtype=np.int64)
    if init is not None:
        k = np.asarray(init)
        if k.shape != m.shape:
            raise ValueError(f"init must have the shape of modulus {m.shape}; got {k.shape}")
        k = np.clip(np.round(k).astype(np.int64), 0, kmax)
    else:
        k = np.stack([anchor_k(quality_guided_k(m[ch], bits)) for ch in range(c)])
        if opts.max_count is not None:
            k = np.stack([fit_bounds(k[ch], kmax[ch]) for ch in range(c)])
    restored = m + period * k
    model = _Model(opts, period)
    pairs = _Pairs(h, w, opts.neighborhood)
    info["energy_init"] = natural_energy(restored, bits, **options)
    rounds = opts.rounds if (c > 1 and opts.colour > 0 and opts.potential == "log") else 1
    for _ in range(rounds if opts.links else 0):
        for ch in range(c):
            _solve_channel(restored, ch, k, kmax, pairs, model, info)
    info["energy"] = natural_energy(restored, bits, **options)
    if return_confidence:
        conf = np.empty(m.shape)
        for ch in range(c):
            guides = _guides(restored, ch, pairs, model)
            conf[ch] = _region_gaps(
                restored[ch].ravel(), k[ch].ravel(), kmax[ch].ravel(), pairs, model, guides, opts.confidence_link
            ).reshape(h, w)
        info["confidence"] = conf[0] if squeeze else conf
    info["seconds"] = time.perf_counter() - start
    return (restored[0] if squeeze else restored), info


def unwrap_natural_torch(modulus: torch.Tensor, bits: int = 8, **options: object) -> torch.Tensor:
    """Torch front end of :func:`unwrap_natural`: (B, C, H, W), (C, H, W) or (H, W), same dtype and device.

    Example:
        >>> x = torch.tensor([[[10.0, 100.0, 200.0, 30.0]]])
        >>> unwrap_natural_torch(x).tolist()
        [[[10.0, 100.0, 200.0, 286.0]]]
    """
    _check_tensor(modulus)
    x = modulus.detach().to("cpu", torch.float64).numpy()
    if modulus.ndim == 4:
        out = np.stack([unwrap_natural(img, bits, **options)[0] for img in x]) if len(x) else x.copy()
    else:
        out = unwrap_natural(x, bits, **options)[0]
    return torch.from_numpy(np.ascontiguousarray(out)).to(modulus.device, modulus.dtype)


class NaturalUnwrap(nn.Module):
    """Module twin of :func:`unwrap_natural_torch`.

    Example:
        >>> NaturalUnwrap(bits=8)(torch.tensor([[10.0, 100.0, 200.0, 30.0]])).tolist()
        [[10.0, 100.0, 200.0, 286.0]]
    """

    def __init__(self, bits: int = 8, **options: object) -> None:
        super().__init__()
        self.bits = _check_bits(bits)
        NaturalOptions.make(**options)
        self.options = dict(options)

    def forward(self, modulus: torch.Tensor) -> torch.Tensor:
        return unwrap_natural_torch(modulus, self.bits, **self.options)
