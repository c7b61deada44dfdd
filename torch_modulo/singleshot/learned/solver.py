"""The learned method's entry for the registry: its options, the decoding of one image, the solvers.

:func:`learned_k` runs the edge network tile by tile on its device, then decodes every channel on the CPU: the
spanning tree (:func:`~torch_modulo.singleshot.learned.decode_jumps`), optionally min-cut moves
(:func:`~torch_modulo.singleshot.learned.refine_band`, option ``max_cuts``) and by default the level head's region
moves (:func:`~torch_modulo.singleshot.learned.region_moves`, option ``levels``). :func:`solve_learned` and
:func:`solve_learned_tensor` are the registry's solvers; the caller anchors ``k``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from torch_modulo._checks import check_flag, check_int
from torch_modulo.singleshot.learned.decoding import decode_jumps, refine_band
from torch_modulo.singleshot.learned.inference import TILE, predict_jumps, predict_levels
from torch_modulo.singleshot.learned.levels import region_moves
from torch_modulo.singleshot.learned.network import EdgeJumpNet, LevelNet, load_levels, load_model
from torch_modulo.singleshot.spec import MoveStats, SolverSpec

__all__ = [
    "BAND",
    "LEARNED_OPTIONS",
    "MIN_LEVEL_SIDE",
    "MOSAIC_CUTS",
    "NETWORK_THREADS",
    "check_levels",
    "check_tile",
    "check_weights",
    "learned_k",
    "mosaic_spec",
    "network_threads",
    "refine_photosites",
    "refines_photosites",
    "solve_learned",
    "solve_learned_tensor",
    "solves_cells",
]

#: The default ``max_cuts`` of a mosaic's guide (``unwrap_single(..., cfa=...)``, :func:`mosaic_spec`): its
#: interpolated values mislead the tree more often than a full colour image does, and the cuts outvote them.
MOSAIC_CUTS = 4

#: Planes with a side shorter than this get no level moves: the level head reads 2-D context (it was trained on
#: crops of natural images), and on thinner planes its costs mislead (a one-row ramp came back with whole stretches
#: a period low); the tree, and the cuts when asked for, decode them.
MIN_LEVEL_SIDE = 8

#: The default ``threads`` of ``method="learned"``: the torch threads its networks run on on the CPU
#: (:func:`network_threads`). 0: all of torch's, the fastest on a machine the job has to itself; 1 is faster where
#: other jobs share the cores (docs/singleshot.md).
NETWORK_THREADS = 0

#: With ``max_cuts`` or ``levels``, the costs of the jumps within ``BAND`` of each pair's most likely one are kept for
#: the cuts and the level moves (farther jumps cost :data:`~torch_modulo.singleshot.learned.MAX_COST`):
#: ``2 (2 BAND + 1)`` values per pixel and channel.
BAND = 2


def _level_network(levels: LevelNet | bool | str | Path | None, device: torch.device) -> LevelNet | None:
    """The level network of the ``levels`` option (None: no level moves)."""
    if levels is None or isinstance(levels, nn.Module):
        return levels
    choice = check_levels(levels, "levels")
    return None if choice is False else load_levels(None if choice is True else choice, device=device)


def learned_k(
    moduli: np.ndarray | torch.Tensor,
    bits: int,
    net: EdgeJumpNet | None = None,
    max_cuts: int = 0,
    augment: bool = False,
    tile: int = TILE,
    levels: LevelNet | bool | str | Path | None = None,
    threads: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """``k`` and the confidence of one image's channels (C, H, W), up to one constant per channel.

    The network runs on its own device (the moduli are moved there), tile by tile; the decoding on the CPU. With
    ``max_cuts``, min-cut moves (:func:`~torch_modulo.singleshot.learned.refine_band`) follow the tree. With
    ``levels`` (a :class:`~torch_modulo.singleshot.learned.LevelNet`, ``True`` for the shipped one, or a level
    weights file), regions are then moved by its level costs (:func:`~torch_modulo.singleshot.learned.region_moves`;
    float16 costs per 2 x 2 block, level and channel are kept while the image is decoded; planes with a side shorter
    than :data:`MIN_LEVEL_SIDE` get none). With either, the costs of
    the jumps within :data:`BAND` of each pair's most likely one are kept (``2 (2 BAND + 1)`` floats per pixel and
    channel). The confidence is that of the tree. The channels are decoded side by side on torch's threads. On the
    CPU the network runs on ``threads`` of torch's threads (0: all of them; :func:`network_threads`).

    Example:
        >>> ramp = np.arange(0, 1200, 40).reshape(1, 1, -1).repeat(8, axis=1)
        >>> k, confidence = learned_k(ramp % 256, 8)
        >>> restored = ramp % 256 + 256 * k
        >>> bool((restored - restored.min() == ramp).all())
        True
    """
    net = load_model() if net is None else net
    x = torch.as_tensor(moduli)
    if x.shape[0] == 0:  # no channels: nothing to predict
        return np.zeros(x.shape, dtype=np.int64), np.ones(x.shape)
    k = np.empty(x.shape, dtype=np.int64)
    confidence = np.empty(x.shape)
    device = next(net.parameters()).device
    level_net = _level_network(levels, device)
    if min(x.shape[-2:]) < MIN_LEVEL_SIDE:  # too thin for the level head's 2-D view
        level_net = None
    band = BAND if max_cuts or level_net is not None else 0
    jump, cost, u = _network_costs(x, bits, net, level_net, augment, tile, band, threads)

    def decode(i: int) -> None:  # one channel, from its int64 moduli
        plane = x[i].to(device="cpu", dtype=torch.int64).numpy()
        k[i], confidence[i] = decode_jumps(plane, jump[i], cost[i, :, band] if band else cost[i], bits)
        if max_cuts:
            k[i] = refine_band(plane, k[i], cost[i], jump[i].astype(np.int64) - band, bits, max_cuts)
        if u is not None:  # last: the cuts weigh the pairs alone and would undo what the levels moved
            k[i] = region_moves(plane, k[i], cost[i], jump[i].astype(np.int64) - band, u[i], bits)

    # numpy and scipy let go of the GIL for most of the decoding: the channels run side by side on torch's threads
    threads = min(torch.get_num_threads(), x.shape[0])
    if threads > 1:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(decode, range(x.shape[0])))  # raises what a channel raised
    else:
        for i in range(x.shape[0]):
            decode(i)
    return k, confidence


def _network_costs(
    x: torch.Tensor,
    bits: int,
    net: EdgeJumpNet,
    level_net: LevelNet | None,
    augment: bool,
    tile: int,
    band: int,
    threads: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The jumps, their costs (with ``band``) and the level costs (None without ``level_net``) of (C, H, W) moduli
    ``x``, each network on its own device: one run of the encoder where the level network's trunk is ``net``."""
    device = next(net.parameters()).device
    x_net = x.to(device=device, dtype=torch.float32)
    with network_threads(threads if device.type == "cpu" else 0):
        if level_net is not None and not augment and _same_network(level_net.trunk, net):  # one run of the encoder
            jump, cost, u = predict_jumps(net, x_net, bits, augment, tile, band, level_net)
            return jump, cost, u
        jump, cost = predict_jumps(net, x_net, bits, augment, tile, band)
        if level_net is None:
            return jump, cost, None
        level_device = next(level_net.parameters()).device
        return jump, cost, predict_levels(level_net, x.to(device=level_device, dtype=torch.float32), bits, tile)


def refines_photosites(spec: SolverSpec) -> bool:
    """Whether a mosaic solved through its interpolated guide (``unwrap_single(..., cfa=...)``) with ``spec`` then
    has its photosites' rollover counts moved by :func:`refine_photosites`: ``"learned"`` by default (its option
    ``levels`` not False, ``cells`` False)."""
    if spec.method != "learned" or solves_cells(spec):
        return False
    return spec.option("levels") is not False


def refine_photosites(
    moduli: torch.Tensor, k: np.ndarray, spec: SolverSpec, channels: tuple[int, ...] = (0, 1, 2)
) -> np.ndarray:
    """``k`` (not anchored) of one colour image of photosites, (3, h, w) moduli of one colour each (the (R, G, B)
    of every 2 x 2 cell of a mosaic, nothing interpolated), moved by the level moves
    (:func:`~torch_modulo.singleshot.learned.region_moves`) under the networks' costs of that image itself.

    A mosaic's guide is solved from interpolated colours, which mislead the tree and the cuts where a region's
    border is steep (docs/cfa.md); the image of its photosites has only measured values, and the moves lower the
    jump and level costs its own networks give, starting from the guide's counts (the cells' own tree puts other
    regions a period off). The networks run on the moduli's device, with ``spec``'s ``weights``, ``levels``,
    ``augment``, ``tile`` and ``threads``; planes thinner than :data:`MIN_LEVEL_SIDE` are returned as they are.
    Only ``channels`` are moved (the networks see all three); the others are returned as they are.
    """
    device = moduli.device
    level_net = _level_network(spec.option("levels"), device)
    if level_net is None or min(k.shape[-2:]) < MIN_LEVEL_SIDE:
        return k
    net = load_model(spec.option("weights"), device=device)
    bits = spec.params.bits
    tile, threads = int(spec.option("tile")), int(spec.option("threads"))
    jump, cost, u = _network_costs(moduli, bits, net, level_net, spec.option("augment"), tile, BAND, threads)
    assert u is not None
    planes = moduli.to(device="cpu", dtype=torch.int64).numpy()
    first = jump.astype(np.int64) - BAND
    out = k.copy()
    for i in channels:
        out[i] = region_moves(planes[i], k[i], cost[i], first[i], u[i], bits)
    return out


@contextlib.contextmanager
def network_threads(threads: int):
    """Run the block on ``threads`` of torch's intra-op threads (at most as many as torch has; 0: unchanged), and
    give torch its own number back after it.

    The networks' convolutions are small (16 to 64 channels): each splits its work among the threads and waits for
    the slowest at the end. On a machine whose cores other jobs share, a thread that loses its core stalls every
    convolution, and on 2 shared cores 2 threads took 4 to 5 times as long as one (docs/singleshot.md, "Worst scenes
    and speed"); on a machine the job has to itself, 0 (all of torch's threads) is faster. torch's thread count is
    per process: other threads that run torch meanwhile get the same number.
    """
    before = torch.get_num_threads()
    if threads <= 0 or threads >= before:
        yield
        return
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _same_network(a: nn.Module, b: nn.Module) -> bool:
    """Whether two networks hold the same weights on the same device (checked every call: a network may change)."""
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(
        sa[k].shape == sb[k].shape and sa[k].device == sb[k].device and torch.equal(sa[k], sb[k]) for k in sa
    )


def check_weights(value: object, name: str) -> str | None:
    """The ``weights`` option: ``None`` (the shipped weights) or the path of a weights file, as a string (the file is
    loaded, and cached, to check it).

    Example:
        >>> check_weights(None, "weights") is None
        True
    """
    if value is None:
        return None
    if not isinstance(value, (str, Path)):
        raise TypeError(f"{name} must be None or a path to a weights file; got {value!r}")
    if not Path(value).is_file():
        raise ValueError(f"{name} must be an existing weights file; got {str(value)!r}")
    load_model(str(value))  # a file that is not one fails here, naming it, not at the first image
    return str(value)


def check_levels(value: object, name: str) -> bool | str:
    """The ``levels`` option: ``True`` (the shipped level weights), ``False`` (none) or the path of a level weights
    file, as a string (the file is loaded, and cached, to check it).

    Example:
        >>> check_levels(False, "levels")
        False
    """
    if isinstance(value, (str, Path)):
        if not Path(value).is_file():
            raise ValueError(f"{name} must be True, False or an existing level weights file; got {str(value)!r}")
        load_levels(str(value))  # a file that is not one fails here, naming it
        return str(value)
    try:
        return check_flag(value, name)
    except TypeError:
        raise TypeError(f"{name} must be True, False or a path to a level weights file; got {value!r}") from None


def check_tile(value: object, name: str) -> int:
    """The ``tile`` option: 0 (the whole image at once) or a side of at least 4 pixels.

    Example:
        >>> check_tile(512, "tile")
        512
    """
    tile = check_int(value, name, 0)
    if 0 < tile < 4:
        raise ValueError(f"{name} must be 0 (no tiles) or at least 4 pixels; got {value!r}")
    return tile


def _check_count(value: object, name: str) -> int:
    """A whole number >= 0 (``max_cuts``, ``threads``)."""
    return check_int(value, name, 0)


#: The options of ``method="learned"``: name -> (default, check). ``weights``: ``None`` (the shipped weights) or
#: a weights file; ``levels``: move the tree's regions by learned level costs
#: (:func:`~torch_modulo.singleshot.learned.region_moves`; ``True``: the shipped level weights, a path: a level
#: weights file, ``False``: no level moves); ``max_cuts``: the most binary moves of
#: :func:`~torch_modulo.singleshot.learned.refine_band` after the tree (0: none); ``augment``: average the network's
#: output over the four flips of the image; ``tile``: the side of the tiles the network predicts at once
#: (:data:`~torch_modulo.singleshot.learned.TILE`; 0: the whole image); ``threads``: the torch threads the networks
#: run on on the CPU (default :data:`NETWORK_THREADS`; 0: all of torch's, :func:`network_threads`); ``cells``: a
#: mosaic's photosites are solved as two half-resolution colour images (:func:`solves_cells`; default False: its
#: interpolated guide, with :func:`mosaic_spec`'s options, then its photosites refined by :func:`refine_photosites`
#: unless ``levels`` is False).
LEARNED_OPTIONS: dict[str, tuple[Any, Callable[[Any, str], Any]]] = {
    "weights": (None, check_weights),
    "levels": (True, check_levels),
    "max_cuts": (0, _check_count),
    "augment": (False, check_flag),
    "tile": (TILE, check_tile),
    "threads": (NETWORK_THREADS, _check_count),
    "cells": (False, check_flag),
}


def mosaic_spec(spec: SolverSpec) -> SolverSpec:
    """``spec`` for a mosaic's interpolated guide: ``"learned"`` runs :data:`MOSAIC_CUTS` cuts and no level moves
    unless told otherwise (on mosaics the cuts gain and the level moves do not; docs/cfa.md).

    The other methods, and the ``max_cuts`` and ``levels`` the caller chose, are kept as they are.
    """
    if spec.method != "learned":
        return spec
    options = {"max_cuts": MOSAIC_CUTS, "levels": False, **dict(spec.options)}
    return dataclasses.replace(spec, options=tuple(sorted(options.items())))


def solves_cells(spec: SolverSpec) -> bool:
    """Whether ``spec`` solves a mosaic (``unwrap_single(..., cfa=...)``) as two half-resolution colour images of its
    photosites (``"learned"`` with ``cells=True``) rather than as its wrapped colours interpolated to full resolution
    (the default, and every other method).

    On the dev scenes mosaicked RGGB the cells were better on average than the guide alone and 3 times faster, but
    put other scenes a period off where the guide did not, and were worse on the validation scenes; the default,
    the guide with its photosites refined in the cells' images (:func:`refine_photosites`), is better than both
    (docs/singleshot.md, "Worst scenes and speed").
    """
    return spec.method == "learned" and bool(spec.option("cells"))


def _learned_ks(moduli: np.ndarray | torch.Tensor, spec: SolverSpec) -> tuple[np.ndarray, np.ndarray]:
    """``k`` (not anchored) and the confidence of one image's channels under ``spec``'s options, the network on the
    moduli's device."""
    device = moduli.device if isinstance(moduli, torch.Tensor) else torch.device("cpu")
    net = load_model(spec.option("weights"), device=device)
    options = (int(spec.option("max_cuts")), spec.option("augment"), int(spec.option("tile")))
    threads = int(spec.option("threads"))
    return learned_k(moduli, spec.params.bits, net, *options, levels=spec.option("levels"), threads=threads)


def solve_learned(moduli: np.ndarray, spec: SolverSpec, stats: list[MoveStats]) -> np.ndarray:
    """The registry's solver: (G, H, W) int64 moduli of one image's channels to restored counts (not anchored).

    Options (``spec.option``): :data:`LEARNED_OPTIONS`.
    """
    start = time.perf_counter()
    restored = moduli + spec.params.period * _learned_ks(moduli, spec)[0]
    for st in stats:
        st.tick("learned", start)
    return restored


def solve_learned_tensor(moduli: torch.Tensor, spec: SolverSpec) -> tuple[torch.Tensor, torch.Tensor]:
    """The registry's tensor solver: a (B, C, H, W) batch to ``k`` (not anchored) and the confidence of every value
    (float64, as :func:`~torch_modulo.singleshot.learned.learned_confidence`, from the same run of the network), both
    on the CPU.

    The network runs where the moduli are (a GPU when they are there); the integer decoding runs on the CPU.
    """
    if len(moduli) == 1:  # no copy
        k, confidence = _learned_ks(moduli[0], spec)
        return torch.from_numpy(k)[None], torch.from_numpy(confidence)[None]
    k_all = torch.empty(moduli.shape, dtype=torch.int64)
    confidence_all = torch.empty(moduli.shape, dtype=torch.float64)
    for i, image in enumerate(moduli):  # filled image by image: no list of the batch's arrays, no stacked copy
        ki, ci = _learned_ks(image, spec)
        k_all[i], confidence_all[i] = torch.from_numpy(ki), torch.from_numpy(ci)
    return k_all, confidence_all
