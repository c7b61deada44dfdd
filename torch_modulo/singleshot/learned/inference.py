"""Windowed inference of the learned method's networks: jump costs and level costs of images of any size.

A large image is predicted in *tiles*: squares of ``tile`` pixels (the core of each tile) seen with the network's
receptive radius of context on every side (:func:`tile_margin`, :func:`level_margin`), so every pair is predicted
from the same pixels as in the whole image and memory grows with the tile, not with the image. A tile with its
context is the *window* the network sees (:func:`window_grid`). Within a window, the head's logits exist one strip
of :data:`STRIP` rows at a time.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator

import numpy as np
import torch
import torch.nn.functional as F

from torch_modulo.singleshot.learned.decoding import MAX_COST
from torch_modulo.singleshot.learned.network import SLOTS, EdgeJumpNet, LevelNet, edge_features

__all__ = [
    "STRIP",
    "TILE",
    "block_slices",
    "level_margin",
    "predict_edges",
    "predict_jumps",
    "predict_levels",
    "tile_margin",
    "window_costs",
    "window_grid",
]

#: Side of the square of pixels the network predicts at once (option ``tile`` of ``method="learned"``): larger
#: images are predicted in tiles of that side plus the network's receptive radius (:func:`tile_margin`) on every
#: side, so memory is bounded.
TILE = 768

#: Rows of a tile whose jump logits, and the input of the network's last full-resolution stage, exist at once
#: (:func:`predict_edges`; the result is the same up to float rounding).
STRIP = 64

#: Half-resolution pixels of context the level head's convolutions (dilations 1, 2, 4) see on every side.
_HALO = 7


def tile_margin(net: EdgeJumpNet) -> int:
    """The context a tile needs on every side: the network's receptive radius (``4 sum(dilations) + 18`` pixels,
    plus ``8 sum(coarse) + 13`` with a 1/8 level), plus the pair's second pixel, rounded up to a multiple of the
    network's stride (the pooling grid). 144 for the shipped network.

    Example:
        >>> tile_margin(EdgeJumpNet(width=4, dilations=(1, 2, 4, 8)))
        80
    """
    coarse = net.config.get("coarse", ())
    radius = 4 * sum(net.config["dilations"]) + 18 + 1 + (8 * sum(coarse) + 13 if coarse else 0)
    return radius + (-radius % net.stride)


def level_margin(net: LevelNet) -> int:
    """The context a tile of :func:`predict_levels` needs on every side: the trunk's (:func:`tile_margin`) plus the
    head's at half resolution, rounded up to a multiple of the stride."""
    margin = tile_margin(net.trunk) + 2 * _HALO + 2
    return margin + (-margin % net.stride)


def _tile_spans(n: int, tile: int, margin: int, stride: int = 4) -> list[tuple[int, int, int, int]]:
    """The tiles along one axis of ``n`` pixels: ``(start, stop, core_start, core_stop)`` of each window and its
    core of ``tile`` pixels.

    One window covers everything when ``tile`` is 0 or ``n <= tile + 2 margin``; windows start at multiples of
    ``stride`` (``tile`` is rounded down to one, ``margin`` is one), so every window sees the whole-image pooling
    grid.
    """
    if tile <= 0 or n <= tile + 2 * margin:
        return [(0, n, 0, n)]
    core = max(stride, tile - tile % stride)
    out = []
    for c0 in range(0, n, core):
        c1 = min(n, c0 + core)
        out.append((max(0, c0 - margin), min(n, c1 + margin), c0, c1))
    return out


def window_grid(
    moduli: torch.Tensor, tile: int, margin: int, stride: int
) -> Iterator[tuple[torch.Tensor, tuple[slice, slice], tuple[slice, slice]]]:
    """The windows a network sees of (C, H, W) moduli (C = 1, repeated into the three slots, or 3): per tile, the
    (1, 3, h, w) float window, its core's slices inside the window and the core's slices in the image.

    The image is padded (replicated) to a multiple of ``stride`` once, so every window sees the whole image's pooling
    grid; the padding's own pixels are in no core.
    """
    c, h, w = moduli.shape
    x = moduli.float()[None].expand(1, SLOTS, h, w) if c == 1 else moduli.float()[None]
    ph, pw = -h % stride, -w % stride
    x = F.pad(x, (0, pw, 0, ph), mode="replicate") if ph or pw else x
    for y0, y1, cy0, cy1 in _tile_spans(h + ph, tile, margin, stride):
        for x0, x1, cx0, cx1 in _tile_spans(w + pw, tile, margin, stride):
            cy1, cx1 = min(cy1, h), min(cx1, w)
            core = (slice(cy0 - y0, cy1 - y0), slice(cx0 - x0, cx1 - x0))
            yield x[..., y0:y1, x0:x1], core, (slice(cy0, cy1), slice(cx0, cx1))


def block_slices(rows: slice, cols: slice) -> tuple[slice, slice]:
    """The 2 x 2 blocks of the pixels ``rows, cols``, which start at even offsets (the windows' cores do: they start
    at multiples of the trunk's stride).

    Example:
        >>> block_slices(slice(4, 9), slice(0, 2))
        (slice(2, 5, None), slice(0, 1, None))
    """
    return slice(rows.start // 2, (rows.stop + 1) // 2), slice(cols.start // 2, (cols.stop + 1) // 2)


def window_costs(
    net: LevelNet, features: torch.Tensor, d2: torch.Tensor, channels: int, rows: slice, cols: slice
) -> torch.Tensor:
    """The (channels, levels, ceil(rows / 2), ceil(cols / 2)) costs of the 2 x 2 blocks of the core ``rows, cols`` of
    one window (starting at even offsets) from its (1, 15, h, w) features and its trunk's ``d2``."""
    logits = net.head_logits(features, d2)[(0, slice(channels), slice(None), *block_slices(rows, cols))]
    return -torch.log_softmax(logits.float(), dim=1)


def _unflip(logp: torch.Tensor, dims: tuple[int, ...]) -> torch.Tensor:
    """Map (S, 2, K, H, W) log-probabilities predicted on an image flipped along ``dims`` back to the image.

    Flipping an axis moves each pair along it one pixel and reverses its orientation (jump ``n`` becomes ``-n``).
    """
    for d in dims:
        logp = logp.flip(d).clone()
        direction = 0 if d == -1 else 1
        logp[:, direction] = torch.roll(logp[:, direction].flip(1), -1, dims=d)
    return logp


@torch.no_grad()  # on a generator: only while it runs, so the caller's mode holds between the pieces
def _window_logp(
    net: EdgeJumpNet,
    x: torch.Tensor,
    bits: int,
    augment: bool,
    channels: int,
    core: tuple[slice, slice],
    hook: Callable[[torch.Tensor, torch.Tensor], None] | None = None,
) -> Iterator[tuple[int, torch.Tensor]]:
    """Jump log-probabilities of the ``core`` (rows, columns) of one (1, 3, h, w) window of moduli (``h`` and ``w``
    multiples of the network's stride): ``(first row of the piece in the core, (channels, 2, 2J + 1, rows, core
    width))``.

    Without ``augment``, the pieces are strips of :data:`STRIP` rows, so the head's logits (``2 (2J + 1)`` values
    per pixel and channel, the largest array of the network) and the last stage's input (:meth:`EdgeJumpNet.decode`)
    exist one strip at a time. With ``augment``, the four flips' probabilities of the whole window are averaged
    (their mean, not that of the log-probabilities, which would make a pair the flips disagree on look sure) and the
    core comes back in one piece. ``hook`` (not with ``augment``) gets the window's features and the encoder's
    half-resolution output ``d2`` first (the level head reads them).
    """
    rows, cols = core
    if not augment:
        features = edge_features(x, bits)
        e1, d2 = net.encode(features)
        if hook is not None:
            hook(features, d2)
        for r0 in range(rows.start, rows.stop, STRIP):
            strip = net.decode(e1, d2, r0, min(rows.stop, r0 + STRIP))[..., cols]
            yield r0 - rows.start, torch.log_softmax(net.logits(strip, channels).float(), dim=3)[0]
        return
    flips: tuple[tuple[int, ...], ...] = ((), (-1,), (-2,), (-1, -2))
    total = None  # log of the sum of the flips' probabilities, one flip at a time
    for dims in flips:
        logp = torch.log_softmax(net(edge_features(x.flip(dims) if dims else x, bits), channels).float(), dim=3)
        logp = _unflip(logp[0], dims) if dims else logp[0]
        total = logp if total is None else torch.logaddexp(total, logp)
    assert total is not None
    yield 0, total[..., rows, cols] - math.log(len(flips))


def _windows(
    net: EdgeJumpNet,
    moduli: torch.Tensor,
    bits: int,
    augment: bool,
    tile: int,
    levels: LevelNet | None = None,
    costs: np.ndarray | None = None,
) -> Iterator[tuple[tuple[slice, slice], torch.Tensor]]:
    """Per tile of (C, H, W) moduli (C = 1 or 3), piece by piece (:func:`_window_logp`): the piece's slices and its
    (C, 2, 2J + 1, h, w) log-probabilities.

    A tile's window reaches the network's receptive radius beyond it (:func:`tile_margin`), so every pair of the tile
    (its last column's pair to the next column included) is predicted from the same pixels as in the whole image.
    With ``levels`` (a level network on this network's encoder), each window's level costs are written into
    ``costs`` from the same run of the encoder, and the windows take the larger context of the two
    (:func:`level_margin`).
    """
    hook = None
    margin = tile_margin(net) if levels is None else max(tile_margin(net), level_margin(levels))
    c = moduli.shape[0]
    for window, core, (ys, xs) in window_grid(moduli, tile, margin, net.stride):
        if levels is not None and costs is not None:

            def hook(features: torch.Tensor, d2: torch.Tensor, core=core, at=(ys, xs)) -> None:
                assert levels is not None and costs is not None
                costs[(slice(None), slice(None), *block_slices(*at))] = (
                    window_costs(levels, features, d2, c, *core).cpu().numpy()
                )

        for r, logp in _window_logp(net, window, bits, augment, c, core, hook):
            yield (slice(ys.start + r, ys.start + r + logp.shape[-2]), xs), logp


def predict_edges(
    net: EdgeJumpNet, moduli: torch.Tensor, bits: int, augment: bool = False, tile: int = 0
) -> torch.Tensor:
    """Jump log-probabilities of one image's channels: (C, 2, 2J + 1, H, W) float32 on the moduli's device.

    Args:
        net: the network.
        moduli: (C, H, W) moduli, C = 1 (seen as grey: repeated into the three slots) or 3 (seen together); other
            channel counts are predicted one channel at a time.
        bits: the sensor bit depth ``N``.
        augment: average the probabilities over the four flips of the image (four times the work).
        tile: predict in tiles of this side (plus :func:`tile_margin` of context; 0: the whole image at once).
            The result is the same up to rounding; the output itself still holds ``2 (2J + 1)`` values per pixel
            and channel (:func:`predict_jumps` keeps two).
    """
    c, h, w = moduli.shape
    if c not in (1, SLOTS):
        return torch.cat([predict_edges(net, moduli[i : i + 1], bits, augment, tile) for i in range(c)])
    out = None
    for (ys, xs), logp in _windows(net, moduli, bits, augment, tile):
        if out is None:
            out = logp.new_empty(c, 2, logp.shape[2], h, w)
        out[..., ys, xs] = logp
    assert out is not None
    return out


def predict_jumps(
    net: EdgeJumpNet,
    moduli: torch.Tensor,
    bits: int,
    augment: bool = False,
    tile: int = TILE,
    band: int = 0,
    levels: LevelNet | None = None,
) -> tuple[np.ndarray, ...]:
    """The most likely jump of every pair and its cost ``-log p``: what the tree decoder needs, two values per pair.

    The network runs on the moduli's device, tile by tile (see :func:`predict_edges`); only the two values per pair
    come back to the CPU, so memory grows with the tile, not with the image. With ``band``, the costs of the jumps
    ``n - band .. n + band`` around the most likely ``n`` come back too (what the cuts and level moves weigh).

    With ``levels``, a :class:`~torch_modulo.singleshot.learned.LevelNet` whose trunk is this network (not with
    ``augment``), its level costs come from the same run of the encoder, as a third value (the same as
    :func:`predict_levels`; the tiles take the larger context of the two).

    Returns:
        ``(jump, cost)``: int16 (C, 2, H, W) jumps ``n`` in ``[-J, J]`` (direction 0: to the right neighbour, 1: to
        the one below) and float32 costs ``>= 0``, (C, 2, H, W), or with ``band`` (C, 2, 2 band + 1, H, W) with the
        most likely jump's at index ``band`` (jumps beyond ``+-J`` cost :data:`MAX_COST`); with ``levels``,
        ``(jump, cost, level_costs)``, float16 (C, levels, ceil(H / 2), ceil(W / 2)), one per 2 x 2 block.
    """
    c, h, w = moduli.shape
    if c not in (0, 1, SLOTS):
        parts = [predict_jumps(net, moduli[i : i + 1], bits, augment, tile, band, levels) for i in range(c)]
        return tuple(np.concatenate([p[i] for p in parts]) for i in range(len(parts[0])))
    if levels is not None and augment:
        raise ValueError("predict_jumps shares the encoder with the levels without augment only")
    level_costs = None
    if levels is not None:  # one per 2 x 2 block
        level_costs = np.empty((c, levels.head.levels, (h + 1) // 2, (w + 1) // 2), dtype=np.float16)
    jump = np.empty((c, 2, h, w), dtype=np.int16)
    cost = np.empty((c, 2, *((2 * band + 1,) if band else ()), h, w), dtype=np.float32)
    if c == 0:  # no channels: nothing to predict
        return (jump, cost) if level_costs is None else (jump, cost, level_costs)
    offsets = torch.arange(-band, band + 1, device=moduli.device).view(1, 1, -1, 1, 1)
    for (ys, xs), logp in _windows(net, moduli, bits, augment, tile, levels, level_costs):
        best, index = logp.max(dim=2)
        jump[:, :, ys, xs] = index.cpu().numpy() - net.max_jump
        if band:
            around = index.unsqueeze(2) + offsets
            inside = (around >= 0) & (around < logp.shape[2])
            near = torch.gather(logp, 2, around.clamp(0, logp.shape[2] - 1))
            cost[:, :, :, ys, xs] = torch.where(inside, -near, MAX_COST).clamp(0.0, MAX_COST).cpu().numpy()
        else:
            cost[:, :, ys, xs] = (-best).clamp_min(0.0).cpu().numpy()
    return (jump, cost) if level_costs is None else (jump, cost, level_costs)


@torch.no_grad()
def _level_pieces(
    net: LevelNet, moduli: torch.Tensor, bits: int, tile: int
) -> Iterator[tuple[tuple[slice, slice], torch.Tensor]]:
    """Per tile of (C, H, W) moduli (C = 1 or 3): the slices of the tile's 2 x 2 blocks and their (C, levels, h, w)
    costs."""
    # windows and cores start at multiples of the stride, so on the half-resolution grid too
    for window, core, at in window_grid(moduli, tile, level_margin(net), net.stride):
        features = edge_features(window, bits)
        yield block_slices(*at), window_costs(net, features, net.trunk.encode(features)[1], moduli.shape[0], *core)


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
        >>> from torch_modulo.singleshot.learned import load_levels
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
