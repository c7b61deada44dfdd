"""Learned single-shot unwrapping: a small network predicts every neighbour step, an exact integer decoder picks ``k``.

``method="learned"`` of :func:`~torch_modulo.singleshot.unwrap_single`. Smoothness alone cannot tell a step of
``d`` counts from one of ``d + 2^N``; what can is knowledge of natural HDR scenes (a lamp is brighter than the wall
around it, a sky brighter than the ground). :class:`EdgeJumpNet` is a small fully convolutional U-Net that sees the
modulus image and its wrapped differences (for colour, all channels together) and predicts, for every horizontal and
vertical neighbour pair, a distribution over the integer *jump* ``n`` in ``I_j - I_i = w(I_m,j - I_m,i) + n 2^N``,
``n`` in ``[-J, J]``, where ``w`` wraps into ``[-2^(N-1), 2^(N-1))`` (``n = 0``: the wrapped step is right, as
path following assumes).

Decoding is exact and integer (:func:`decode_edges`): every pair gets its most likely jump and that jump's
probability; the maximum-likelihood spanning tree (Kruskal over ``-log p``) joins the most confident pairs first,
and ``k`` is integrated along it, so the output is always ``I_m + k 2^N`` with integer ``k``. The probability of
the path from the root, ``prod p``, is a confidence per pixel. By default a small head's level costs (per 2 x 2
block) then move whole regions (option ``levels``, :mod:`torch_modulo.singleshot.levels`). :func:`solve_learned` is the
registry's solver; the caller anchors ``k`` (:func:`~torch_modulo.singleshot.anchor.anchor_k`).

The shipped weights (``weights/edge_jump.pt``, record in ``weights/MODEL_CARD.md``) load offline from the package
(:func:`load_model`). Training: :func:`edge_targets` and :func:`edge_loss` (cross-entropy, weighted up on the pairs
whose wrapped step is wrong); the recipe that made the shipped weights is ``references/learned_single/train.py``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from torch_modulo._checks import check_flag, check_int
from torch_modulo.singleshot.grid import grid_components, path_to_root

__all__ = [
    "BAND",
    "LEARNED_OPTIONS",
    "MOSAIC_CUTS",
    "STRIP",
    "TILE",
    "TREE_PIXELS",
    "WEIGHTS",
    "EdgeJumpNet",
    "check_levels",
    "check_weights",
    "decode_edges",
    "decode_jumps",
    "edge_features",
    "edge_loss",
    "edge_targets",
    "learned_confidence",
    "learned_k",
    "load_model",
    "mosaic_spec",
    "predict_edges",
    "predict_jumps",
    "refine_band",
    "refine_cut",
    "solve_learned",
    "tile_margin",
    "weights_path",
    "window_grid",
]

#: The file name of the shipped weights inside ``torch_modulo/singleshot/weights``.
WEIGHTS = "edge_jump.pt"

#: Channels the network sees at once: one image's RGB (a single channel is repeated three times).
SLOTS = 3

#: The two pair directions as ``(first end, second end)`` slices of a plane: to the right, and down.
_DIRECTIONS = ((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :]))


def _wrap(d: torch.Tensor, period: float) -> torch.Tensor:
    """Wrap differences into ``[-period / 2, period / 2)``."""
    half = period / 2
    return torch.remainder(d + half, period) - half


def edge_features(modulus: torch.Tensor, bits: int) -> torch.Tensor:
    """The network input for (B, 3, H, W) moduli: per channel ``I_m / 2^N``, its phasor, and the wrapped steps.

    Per channel: ``I_m / 2^N - 0.5``, ``cos`` and ``sin`` of ``2 pi I_m / 2^N``, and the wrapped horizontal and
    vertical differences to the next pixel divided by ``2^N`` (0 where the next pixel is outside the image).

    Returns:
        (B, 15, H, W) float32.
    """
    period = float(2**bits)
    m = modulus.float()
    dx = F.pad(_wrap(m[..., :, 1:] - m[..., :, :-1], period), (0, 1))
    dy = F.pad(_wrap(m[..., 1:, :] - m[..., :-1, :], period), (0, 0, 0, 1))
    phase = m * (2 * torch.pi / period)
    return torch.cat([m / period - 0.5, torch.cos(phase), torch.sin(phase), dx / period, dy / period], dim=1)


def _block(cin: int, cout: int, dilation: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=dilation, dilation=dilation), nn.ReLU(inplace=True))


class EdgeJumpNet(nn.Module):
    """A small U-Net from :func:`edge_features` to jump logits of every horizontal and vertical pair, per channel.

    Full resolution, 1/2 and 1/4 with a dilated residual bottleneck (dilations ``dilations``), skip connections;
    with ``coarse``, a residual branch at 1/8 (``8 width`` channels, dilations ``coarse``) added to the bottleneck.

    Args:
        width: channels at full resolution (doubled at 1/2, quadrupled at 1/4).
        max_jump: ``J``: the jumps predicted are ``-J .. J``.
        dilations: dilations of the bottleneck's residual blocks (the receptive field grows with their sum).
        coarse: dilations of the residual blocks at 1/8 resolution (none: no such level).

    Shape:
        - Input: (B, 15, H, W) features, ``H`` and ``W`` multiples of :attr:`stride` (4, or 8 with ``coarse``;
          :func:`predict_edges` pads).
        - Output: (B, 3, 2, 2J + 1, H, W) logits: channel, direction (0: to the right neighbour, 1: to the one
          below), jump ``n + J``; with ``forward(x, channels)``, those of the first ``channels`` channels alone (a
          grey image, repeated into the three slots, needs one).

    Example:
        >>> net = EdgeJumpNet(width=4, max_jump=2)
        >>> net(torch.zeros(1, 15, 8, 8)).shape
        torch.Size([1, 3, 2, 5, 8, 8])
    """

    def __init__(
        self,
        width: int = 16,
        max_jump: int = 15,
        dilations: tuple[int, ...] = (1, 2, 4, 8),
        coarse: tuple[int, ...] = (),
    ) -> None:
        super().__init__()
        w = int(width)
        self.config: dict[str, Any] = {
            "width": w,
            "max_jump": int(max_jump),
            "dilations": tuple(int(d) for d in dilations),
        }
        if coarse:  # only then: the configs of networks without the branch stay as they were
            self.config["coarse"] = tuple(int(d) for d in coarse)
        self.max_jump = int(max_jump)
        #: The inputs' sides must be multiples of this (the coarsest pooling grid).
        self.stride = 8 if coarse else 4
        self.enc1 = nn.Sequential(_block(5 * SLOTS, w), _block(w, w))
        self.enc2 = nn.Sequential(_block(w, 2 * w), _block(2 * w, 2 * w))
        self.enc3 = _block(2 * w, 4 * w)
        self.mid = nn.ModuleList(_block(4 * w, 4 * w, d) for d in self.config["dilations"])
        self.dec2 = nn.Sequential(_block(4 * w + 2 * w, 2 * w), _block(2 * w, 2 * w))
        self.dec1 = nn.Sequential(_block(2 * w + w, w), _block(w, w))
        self.head = nn.Conv2d(w, SLOTS * 2 * (2 * self.max_jump + 1), 1)
        if coarse:
            self.enc4 = _block(4 * w, 8 * w)
            self.deep = nn.ModuleList(_block(8 * w, 8 * w, d) for d in self.config["coarse"])
            self.up4 = nn.Conv2d(8 * w, 4 * w, 1)

    def forward(self, x: torch.Tensor, channels: int = SLOTS) -> torch.Tensor:
        return self.logits(self.trunk(x), channels)

    def trunk(self, x: torch.Tensor) -> torch.Tensor:
        """(B, width, H, W) full-resolution features of (B, 15, H, W) inputs: everything but the head."""
        return self.decode(*self.encode(x))

    def encode(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """What :meth:`decode` needs: the (B, width, H, W) first features and the (B, 2 width, H / 2, W / 2) ones
        of the half-resolution decoder."""
        e1 = self.enc1(x)
        e2 = self.enc2(F.avg_pool2d(e1, 2))
        e3 = self.enc3(F.avg_pool2d(e2, 2))
        for block in self.mid:
            e3 = e3 + block(e3)
        if self.stride == 8:
            e4 = self.enc4(F.avg_pool2d(e3, 2))
            for block in self.deep:
                e4 = e4 + block(e4)
            e3 = e3 + self.up4(F.interpolate(e4, scale_factor=2.0, mode="nearest"))
        return e1, self.dec2(torch.cat([F.interpolate(e3, scale_factor=2.0, mode="nearest"), e2], dim=1))

    def decode(self, e1: torch.Tensor, d2: torch.Tensor, start: int = 0, stop: int | None = None) -> torch.Tensor:
        """The full-resolution features of rows ``start .. stop - 1`` (default: all) from :meth:`encode`'s output.

        The last stage's two 3 x 3 convolutions see two rows beyond the range on each side, so a range gives the
        same features as the whole image, and the full-resolution input of those convolutions (three times the
        features' size) exists for the range alone.
        """
        h = e1.shape[-2]
        stop = h if stop is None else stop
        a, b = max(0, start - 2), min(h, stop + 2)
        up = F.interpolate(d2[..., a // 2 : (b + 1) // 2, :], scale_factor=2.0, mode="nearest")
        up = up[..., a - 2 * (a // 2) : b - 2 * (a // 2), :]
        return self.dec1(torch.cat([up, e1[..., a:b, :]], dim=1))[..., start - a : stop - a, :]

    def logits(self, features: torch.Tensor, channels: int = SLOTS) -> torch.Tensor:
        """(B, channels, 2, 2J + 1, h, w) logits of any (B, width, h, w) window of :meth:`trunk`'s features (the
        head is a 1 x 1 convolution, so a window of features gives the same window of logits)."""
        b, _, h, w = features.shape
        n = channels * 2 * (2 * self.max_jump + 1)  # the head's outputs are channel-major: the first n
        # channels first (the reductions over jumps that follow are faster so): see _cpu_layout
        out = F.conv2d(features.contiguous(), self.head.weight[:n], self.head.bias[:n])
        return out.view(b, channels, 2, 2 * self.max_jump + 1, h, w)


@functools.lru_cache(maxsize=4)
def _load_cached(path: str, device: str) -> EdgeJumpNet:
    try:
        record = torch.load(path, map_location="cpu", weights_only=True)
        net = EdgeJumpNet(**record["config"])
        net.load_state_dict({k: v.float() for k, v in record["state"].items()})
    except Exception as error:  # a file of another kind, another network, a truncated download: name the file
        raise ValueError(
            f"{path!r} is not a weights file of the training recipe ({{'config': ..., 'state': ...}} for "
            f"EdgeJumpNet): {type(error).__name__}: {error}"
        ) from error
    # one cached copy per device: moving a shared copy would move it for every caller
    return _cpu_layout(net.eval().to(device))


def _cpu_layout(net: nn.Module) -> nn.Module:
    """``net`` with its 3 x 3 convolutions' weights channels last when it is on the CPU (their outputs follow): oneDNN
    runs those faster. The 1 x 1 heads stay channels first, with their input made so, as the reductions over jumps
    and levels after them are faster on channels-first logits. The results are the same up to float rounding."""
    if next(net.parameters()).device.type == "cpu":
        for module in net.modules():
            if isinstance(module, nn.Conv2d) and module.kernel_size != (1, 1):
                module.to(memory_format=torch.channels_last)
    return net


def load_model(path: str | Path | None = None, device: torch.device | str = "cpu") -> EdgeJumpNet:
    """The trained :class:`EdgeJumpNet` (eval mode, no gradients needed), loaded offline.

    Args:
        path: a weights file written by the training recipe (``{"config": ..., "state": ...}``); ``None`` loads
            the weights shipped in the package.
        device: where to put the network.

    Raises:
        FileNotFoundError: there is no file at ``path``.
        ValueError: the file is not a weights file of the training recipe (the message names it).

    Example:
        >>> load_model().max_jump
        15
    """
    return _load_cached(weights_path(path, WEIGHTS), str(torch.device(device)))


def weights_path(path: str | Path | None, shipped: str) -> str:
    """``path`` as a string, or the shipped file ``shipped`` inside ``torch_modulo/singleshot/weights`` for ``None``.

    Raises:
        FileNotFoundError: there is no file at ``path``.
    """
    if path is None:
        return str(resources.files("torch_modulo.singleshot").joinpath("weights", shipped))
    if not Path(path).is_file():
        raise FileNotFoundError(2, "weights file not found", str(path))
    return str(path)


def _unflip(logp: torch.Tensor, dims: tuple[int, ...]) -> torch.Tensor:
    """Map (S, 2, K, H, W) log-probabilities predicted on an image flipped along ``dims`` back to the image.

    Flipping an axis moves each pair along it one pixel and reverses its orientation (jump ``n`` becomes ``-n``).
    """
    for d in dims:
        logp = logp.flip(d).clone()
        direction = 0 if d == -1 else 1
        logp[:, direction] = torch.roll(logp[:, direction].flip(1), -1, dims=d)
    return logp


#: Side of the square of pixels the network predicts at once (:func:`predict_edges`, option ``tile``): larger
#: images are predicted in tiles of that side plus the network's receptive radius (:func:`tile_margin`) on every
#: side, so memory is bounded.
TILE = 768

#: Rows of a tile whose jump logits, and the input of the network's last full-resolution stage, exist at once
#: (:func:`predict_edges`; the result is the same up to float rounding).
STRIP = 64

#: Cost of a jump outside ``-J .. J`` (and the most any jump costs): ``-log`` of a negligible probability.
_MAX_COST = 30.0

#: The default ``max_cuts`` of a mosaic's guide (``unwrap_single(..., cfa=...)``, :func:`mosaic_spec`): its
#: interpolated values mislead the tree more often than a full colour image does, and the cuts outvote them.
MOSAIC_CUTS = 4

#: With ``max_cuts`` or ``levels``, the costs of the jumps within ``BAND`` of each pair's most likely one are kept for
#: the cuts (:func:`refine_band`) and the level moves (farther jumps cost :data:`_MAX_COST`): ``2 (2 BAND + 1)``
#: values per pixel and channel.
BAND = 2

#: A pair this likely (``p >= 0.99``) joins the reference region of :func:`decode_jumps`' confidence.
_CONFIDENT = 0.99

#: :func:`decode_jumps` builds the spanning tree of a plane of more pixels than this from blocks of rows of at most
#: this many (as ``"guided"``'s ``tile_pixels``): a minimum spanning tree of the same pairs in less memory, which
#: may differ from the whole-image tree where pairs cost the same.
TREE_PIXELS = 2**22


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


def _tiles(n: int, tile: int, margin: int, stride: int = 4) -> list[tuple[int, int, int, int]]:
    """Windows along one axis of ``n`` pixels: ``(start, stop, core_start, core_stop)``, cores of ``tile`` pixels.

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
    exist one strip at a time. With ``augment``, the four
    flips' probabilities of the whole window are averaged (their mean, not that of the log-probabilities, which
    would make a pair the flips disagree on look sure) and the core comes back in one piece. ``hook`` (not
    with ``augment``) gets the window's features and the encoder's half-resolution output ``d2`` first (the level
    head reads them, :mod:`torch_modulo.singleshot.levels`).
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
    flips = ((), (-1,), (-2,), (-1, -2))
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
    levels: Any = None,
    costs: np.ndarray | None = None,
) -> Iterator[tuple[tuple[slice, slice], torch.Tensor]]:
    """Per tile of (C, H, W) moduli (C = 1 or 3), piece by piece (:func:`_window_logp`): the piece's slices and its
    (C, 2, 2J + 1, h, w) log-probabilities.

    The image is padded (replicated) to a multiple of the network's stride once, so every window, flipped or not,
    sees the whole image's pooling grid; a tile's window reaches the network's receptive radius beyond it
    (:func:`tile_margin`), so every pair of the tile (its last column's pair to the next column included) is
    predicted from the same pixels as in the whole image. With ``levels`` (a level network on this network's
    encoder), each window's level costs are written into ``costs`` from the same run of the encoder, and the windows
    take the larger context of the two (:func:`~torch_modulo.singleshot.levels.level_margin`).
    """
    hook = None
    margin = tile_margin(net)
    if levels is not None:  # a level head on this network's encoder: its costs of each window go into `costs`
        from torch_modulo.singleshot.levels import _block_slices, level_margin, window_costs

        margin = max(margin, level_margin(levels))
    c = moduli.shape[0]
    for window, core, (ys, xs) in window_grid(moduli, tile, margin, net.stride):
        if levels is not None and costs is not None:

            def hook(features: torch.Tensor, d2: torch.Tensor, core=core, at=(ys, xs)) -> None:
                costs[(slice(None), slice(None), *_block_slices(*at))] = (
                    window_costs(levels, features, d2, c, *core).cpu().numpy()
                )

        for r, logp in _window_logp(net, window, bits, augment, c, core, hook):
            yield (slice(ys.start + r, ys.start + r + logp.shape[-2]), xs), logp


def window_grid(
    moduli: torch.Tensor, tile: int, margin: int, stride: int
) -> Iterator[tuple[torch.Tensor, tuple[slice, slice], tuple[slice, slice]]]:
    """The windows a network sees of (C, H, W) moduli (C = 1, repeated into the three slots, or 3): per tile
    (:func:`_tiles`), the (1, 3, h, w) float window, its core's slices inside the window and the core's slices in the
    image.

    The image is padded (replicated) to a multiple of ``stride`` once, so every window sees the whole image's pooling
    grid; the padding's own pixels are in no core.
    """
    c, h, w = moduli.shape
    x = moduli.float()[None].expand(1, SLOTS, h, w) if c == 1 else moduli.float()[None]
    ph, pw = -h % stride, -w % stride
    x = F.pad(x, (0, pw, 0, ph), mode="replicate") if ph or pw else x
    for y0, y1, cy0, cy1 in _tiles(h + ph, tile, margin, stride):
        for x0, x1, cx0, cx1 in _tiles(w + pw, tile, margin, stride):
            cy1, cx1 = min(cy1, h), min(cx1, w)
            core = (slice(cy0 - y0, cy1 - y0), slice(cx0 - x0, cx1 - x0))
            yield x[..., y0:y1, x0:x1], core, (slice(cy0, cy1), slice(cx0, cx1))


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
    levels: Any = None,
) -> tuple[np.ndarray, ...]:
    """The most likely jump of every pair and its cost ``-log p``: what the tree decoder needs, two values per pair.

    The network runs on the moduli's device, tile by tile (see :func:`predict_edges`); only the two values per pair
    come back to the CPU, so memory grows with the tile, not with the image. With ``band``, the costs of the jumps
    ``n - band .. n + band`` around the most likely ``n`` come back too (what :func:`refine_band` weighs).

    With ``levels``, a :class:`~torch_modulo.singleshot.levels.LevelNet` whose trunk is this network (not with
    ``augment``), its level costs come from the same run of the encoder, as a third value (the same as
    :func:`~torch_modulo.singleshot.levels.predict_levels`; the tiles take the larger context of the two).

    Returns:
        ``(jump, cost)``: int16 (C, 2, H, W) jumps ``n`` in ``[-J, J]`` (direction 0: to the right neighbour, 1: to
        the one below) and float32 costs ``>= 0``, (C, 2, H, W), or with ``band`` (C, 2, 2 band + 1, H, W) with the
        most likely jump's at index ``band`` (jumps beyond ``+-J`` cost ``30``); with ``levels``, ``(jump, cost,
        level_costs)``, float16 (C, levels, ceil(H / 2), ceil(W / 2)), one per 2 x 2 block.
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
            cost[:, :, :, ys, xs] = torch.where(inside, -near, _MAX_COST).clamp(0.0, _MAX_COST).cpu().numpy()
        else:
            cost[:, :, ys, xs] = (-best).clamp_min(0.0).cpu().numpy()
    return (jump, cost) if level_costs is None else (jump, cost, level_costs)


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
    from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

    from torch_modulo.singleshot.pathfollow import _kruskal_graph

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

    tree = minimum_spanning_tree(_kruskal_graph(pair_weights, h, w, TREE_PIXELS), overwrite=True)
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


def _pair_costs(
    m: np.ndarray, k: np.ndarray, table: np.ndarray, first: np.ndarray, period: int, shift_a: int, shift_b: int
) -> list:
    """Per direction, the cost of the jump every pair has when ``k`` moves by ``shift_a`` at its first end and
    ``shift_b`` at its second: ``table[d, n - first[d]]``, :data:`_MAX_COST` outside the table."""
    size = table.shape[1]
    out = []
    for direction, (a, b) in enumerate(_DIRECTIONS):
        restored_a, restored_b = m[a] + period * (k[a] + shift_a), m[b] + period * (k[b] + shift_b)
        wd = np.mod(m[b] - m[a] + period // 2, period) - period // 2
        n = (restored_b - restored_a - wd) // period - first[direction][a]
        inside = (n >= 0) & (n < size)
        c = np.take_along_axis(table[direction][(slice(None), *a)], np.clip(n, 0, size - 1)[None], 0)[0]
        out.append(np.where(inside, c, _MAX_COST))
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
            ``table[d, i]`` is the cost of the jump ``first[d] + i``; jumps outside cost :data:`_MAX_COST`, and
            costs are clipped to it.
        first: (2, H, W) integers: the jump of ``table``'s first entry per pair.
        bits: the sensor bit depth ``N``.
        max_cuts: the most minimum cuts.
        block: the side of the squares superpixels stay inside.

    Returns:
        int64 (H, W) rollover counts.
    """
    import maxflow

    m = np.asarray(modulus, dtype=np.int64)
    k = np.asarray(k, dtype=np.int64).copy()
    first = np.asarray(first, dtype=np.int64)
    h, w = m.shape
    period = 1 << bits
    table = np.clip(np.asarray(table, dtype=np.float32), 0.0, _MAX_COST)

    def costs(kk: np.ndarray, shift_a: int = 0, shift_b: int = 0) -> list:
        return _pair_costs(m, kk, table, first, period, shift_a, shift_b)

    same = costs(k)
    rows, cols = np.arange(h)[:, None] // block, np.arange(w)[None, :] // block
    square = rows * (-(-w // block)) + cols
    joined = [(c < _SURE) & (square[a] == square[b]) for (a, b), c in zip(_DIRECTIONS, same, strict=True)]
    n, labels = grid_components(*joined)
    labels = labels.reshape(h, w)
    # Pairs inside a superpixel keep their jump under every move: only the pairs between superpixels enter a graph.
    ends = [(labels[a][x], labels[b][x], x) for (a, b) in _DIRECTIONS for x in [labels[a] != labels[b]]]
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


def learned_k(
    moduli: np.ndarray | torch.Tensor,
    bits: int,
    net: EdgeJumpNet | None = None,
    max_cuts: int = 0,
    augment: bool = False,
    tile: int = TILE,
    levels: Any = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``k`` and the confidence of one image's channels (C, H, W), up to one constant per channel.

    The network runs on its own device (the moduli are moved there), tile by tile; the decoding on the CPU. With
    ``max_cuts``, min-cut moves (:func:`refine_band`) follow the tree. With ``levels`` (a
    :class:`~torch_modulo.singleshot.levels.LevelNet`, ``True`` for the shipped one, or a level weights file), regions
    are then moved by
    its level costs (:func:`~torch_modulo.singleshot.levels.region_moves`; ``LEVELS`` float16 costs per 2 x 2 block
    and channel are kept while the image is decoded). With either, the costs of the jumps within :data:`BAND` of each
    pair's most likely one are kept (``2 (2 BAND + 1)`` floats per pixel and channel). The confidence is that of
    the tree.

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
    if levels is not None and not isinstance(levels, nn.Module):  # True, False or a level weights file
        from torch_modulo.singleshot.levels import load_levels

        choice = check_levels(levels, "levels")
        levels = None if choice is False else load_levels(None if choice is True else choice, device=device)
    band = BAND if max_cuts or levels is not None else 0
    x_net = x.to(device=device, dtype=torch.float32)
    if levels is not None and not augment and _same_network(levels.trunk, net):  # one run of the encoder for both
        jump, cost, u = predict_jumps(net, x_net, bits, augment, tile, band, levels)
    else:
        jump, cost = predict_jumps(net, x_net, bits, augment, tile, band)
        if levels is not None:
            from torch_modulo.singleshot.levels import predict_levels

            level_device = next(levels.parameters()).device
            u = predict_levels(levels, x.to(device=level_device, dtype=torch.float32), bits, tile)
    if levels is not None:
        from torch_modulo.singleshot.levels import region_moves

    def decode(i: int) -> None:  # one channel, from its int64 moduli
        plane = x[i].to(device="cpu", dtype=torch.int64).numpy()
        k[i], confidence[i] = decode_jumps(plane, jump[i], cost[i, :, band] if band else cost[i], bits)
        if max_cuts:
            k[i] = refine_band(plane, k[i], cost[i], jump[i].astype(np.int64) - band, bits, max_cuts)
        if levels is not None:  # last: the cuts weigh the pairs alone and would undo what the levels moved
            k[i] = region_moves(plane, k[i], cost[i], jump[i].astype(np.int64) - band, u[i], bits)

    # The channels are decoded side by side on torch's threads: numpy and scipy let go of the GIL for most of the work.
    threads = min(torch.get_num_threads(), x.shape[0])
    if threads > 1:
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(decode, range(x.shape[0])))  # raises what a channel raised
    else:
        for i in range(x.shape[0]):
            decode(i)
    return k, confidence


def _same_network(a: nn.Module, b: nn.Module) -> bool:
    """Whether two networks hold the same weights on the same device (checked every call: a network may change)."""
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(
        sa[k].shape == sb[k].shape and sa[k].device == sb[k].device and torch.equal(sa[k], sb[k]) for k in sa
    )


def learned_confidence(
    modulus: torch.Tensor,
    bits: int = 8,
    *,
    weights: str | Path | None = None,
    augment: bool = False,
    tile: int = TILE,
) -> torch.Tensor:
    """Per-pixel confidence of ``unwrap_single(modulus, bits, method="learned")``, from the network's probabilities.

    The probability the network gives the least likely pair on the pixel's path, in the decoder's spanning tree,
    to the reference region (the largest region joined by pairs it is at least 99% sure of; see
    :func:`decode_jumps`). Low values mark pixels whose level hangs on an unsure jump: check them, or take a second
    exposure there. Like :func:`~torch_modulo.unwrap_confidence` (which reads the restored image alone), it cannot
    flag a region the network puts at a wrong level with confidence. Runs the network again (same options as the
    method); ``unwrap_single(..., return_info=True)`` gives the same map from its own run
    (:attr:`~torch_modulo.singleshot.SingleShotInfo.confidence`).

    Args:
        modulus: wrapped values in ``[0, 2**bits)``, floating, (B, C, H, W), (C, H, W) or (H, W), on any device.
        bits: sensor bit depth ``N``.
        weights: ``None`` (the shipped weights) or a weights file, as for the method.
        augment: average the network over the four flips of the image, as for the method.
        tile: tile side of the network's prediction, as for the method.

    Returns:
        Confidence in ``(0, 1]`` with the shape, dtype and device of ``modulus``.

    Example:
        >>> ramp = torch.arange(0.0, 1200.0, 40.0).reshape(1, -1).repeat(8, 1)
        >>> confidence = learned_confidence(ramp % 256)
        >>> confidence.shape, bool((confidence > 0.5).all())
        (torch.Size([8, 30]), True)
    """
    from torch_modulo._checks import (
        check_bits,
        check_floating,
        check_image_shape,
        check_modulus,
        check_nonempty_image,
        check_tensor,
    )

    check_tensor(modulus, "modulus")
    check_floating(modulus, "modulus")
    check_image_shape(modulus, "modulus", 2, 4)
    check_nonempty_image(modulus, "modulus")
    bits = check_bits(bits, modulus.dtype)
    check_modulus(modulus, bits)
    net = load_model(check_weights(weights, "weights"), device=modulus.device)
    augment, tile = check_flag(augment, "augment"), _check_tile(tile, "tile")
    if modulus.numel() == 0:  # no images or no channels
        return torch.ones_like(modulus)
    batch = modulus.detach().reshape(-1, *((1, 1, *modulus.shape)[-3:]))
    maps = [learned_k(image, bits, net, 0, augment, tile)[1] for image in batch]
    out = torch.from_numpy(np.stack(maps))
    return out.to(device=modulus.device, dtype=modulus.dtype).reshape(modulus.shape)


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
    _load_cached(str(value), "cpu")  # a file that is not one fails here, naming it, not at the first image
    return str(value)


def check_levels(value: object, name: str) -> bool | str:
    """The ``levels`` option: ``True`` (the shipped level weights), ``False`` (none) or the path of a level weights
    file, as a string (the file is loaded, and cached, to check it).

    Example:
        >>> check_levels(False, "levels")
        False
    """
    if isinstance(value, (str, Path)):
        from torch_modulo.singleshot.levels import _load_cached as load_level_file

        if not Path(value).is_file():
            raise ValueError(f"{name} must be True, False or an existing level weights file; got {str(value)!r}")
        load_level_file(str(value), "cpu")  # a file that is not one fails here, naming it
        return str(value)
    try:
        return check_flag(value, name)
    except TypeError:
        raise TypeError(f"{name} must be True, False or a path to a level weights file; got {value!r}") from None


def mosaic_spec(spec: Any) -> Any:
    """``spec`` for a mosaic's interpolated guide: ``"learned"`` runs :data:`MOSAIC_CUTS` cuts and no level moves
    unless told otherwise (on mosaics the cuts gain and the level moves do not; docs/cfa.md).

    The other methods, and the ``max_cuts`` and ``levels`` the caller chose, are kept as they are.
    """
    if spec.method != "learned":
        return spec
    options = {"max_cuts": MOSAIC_CUTS, "levels": False, **dict(spec.options)}
    return dataclasses.replace(spec, options=tuple(sorted(options.items())))


def _check_cuts(value: object, name: str) -> int:
    return check_int(value, name, 0)


def _check_tile(value: object, name: str) -> int:
    tile = check_int(value, name, 0)
    if 0 < tile < 4:
        raise ValueError(f"{name} must be 0 (no tiles) or at least 4 pixels; got {value!r}")
    return tile


#: The options of ``method="learned"``: name -> (default, check). ``weights``: ``None`` (the shipped weights) or
#: a weights file; ``levels``: move the tree's regions by learned level costs
#: (:mod:`~torch_modulo.singleshot.levels`; ``True``: the shipped level weights, a path: a level weights file,
#: ``False``: no level moves); ``max_cuts``: the most binary moves of :func:`refine_band` after the tree (0: none);
#: ``augment``: average the network's output over the four flips of the image (:func:`predict_edges`); ``tile``:
#: the side of the tiles the network predicts at once (:data:`TILE`; 0: the whole image).
LEARNED_OPTIONS: dict[str, tuple[Any, Callable[[Any, str], Any]]] = {
    "weights": (None, check_weights),
    "levels": (True, check_levels),
    "max_cuts": (0, _check_cuts),
    "augment": (False, check_flag),
    "tile": (TILE, _check_tile),
}


def _learned_ks(moduli: np.ndarray | torch.Tensor, spec: Any) -> tuple[np.ndarray, np.ndarray]:
    """``k`` (not anchored) and the confidence of one image's channels under ``spec``'s options, the network on the
    moduli's device."""
    device = moduli.device if isinstance(moduli, torch.Tensor) else torch.device("cpu")
    net = load_model(spec.option("weights"), device=device)
    options = (int(spec.option("max_cuts")), spec.option("augment"), int(spec.option("tile")))
    return learned_k(moduli, spec.params.bits, net, *options, levels=spec.option("levels"))


def solve_learned(moduli: np.ndarray, spec: Any, stats: list[Any]) -> np.ndarray:
    """The registry's solver: (G, H, W) int64 moduli of one image's channels to restored counts (not anchored).

    Options (``spec.option``): :data:`LEARNED_OPTIONS`.
    """
    from torch_modulo.singleshot.graphcut import plane_energy
    from torch_modulo.singleshot.grid import pair_offsets

    start = time.perf_counter()
    p = spec.params
    restored = moduli + p.period * _learned_ks(moduli, spec)[0]
    for plane, st in zip(restored, stats, strict=True):
        st.energies.append(plane_energy(plane, p, pair_offsets(spec.neighborhood)))
        st.tick("learned", start)
    return restored


def solve_learned_tensor(moduli: torch.Tensor, spec: Any) -> tuple[torch.Tensor, torch.Tensor]:
    """The registry's tensor solver: a (B, C, H, W) batch to ``k`` (not anchored) and the confidence of every value
    (float64, as :func:`learned_confidence`, from the same run of the network), both on the CPU.

    The network runs where the moduli are (a GPU when they are there); the integer decoding runs on the CPU.
    """
    if len(moduli) == 1:  # no copy
        k, confidence = _learned_ks(moduli[0], spec)
        return torch.from_numpy(k)[None], torch.from_numpy(confidence)[None]
    k = torch.empty(moduli.shape, dtype=torch.int64)
    confidence = torch.empty(moduli.shape, dtype=torch.float64)
    for i, image in enumerate(moduli):  # filled image by image: no list of the batch's arrays, no stacked copy
        ki, ci = _learned_ks(image, spec)
        k[i], confidence[i] = torch.from_numpy(ki), torch.from_numpy(ci)
    return k, confidence


# ------------------------------------------------------------------------------------------------------- training


def edge_targets(counts: torch.Tensor, bits: int, max_jump: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Jump classes of the true counts and a mask of the pairs whose wrapped step is wrong.

    Args:
        counts: (B, C, H, W) true counts.
        bits: the sensor bit depth ``N``.
        max_jump: ``J``; jumps beyond it are clipped to ``+-J``.

    Returns:
        ``(target, hard)``: (B, C, 2, H, W) int64 classes ``n + J`` (direction 0: to the right neighbour, 1: to the
        one below; the last column / row, which has no neighbour, holds ``J``) and a bool mask of ``n != 0``.

    Example:
        >>> target, hard = edge_targets(torch.tensor([[[[10.0, 300.0, 310.0]]]]), 8, 2)
        >>> target[0, 0, 0].tolist(), hard[0, 0, 0].tolist()
        ([[3, 2, 2]], [[True, False, False]])
    """
    period = float(2**bits)
    c = counts.double()
    m = torch.remainder(c, period)
    out = []
    for dim in (-1, -2):
        d = torch.diff(c, dim=dim)
        wd = _wrap(torch.diff(m, dim=dim), period)
        n = torch.round((d - wd) / period).clamp(-max_jump, max_jump).long() + max_jump
        pad = (0, 1) if dim == -1 else (0, 0, 0, 1)
        out.append(F.pad(n, pad, value=max_jump))
    target = torch.stack(out, dim=2)
    return target, target != max_jump


def edge_loss(logits: torch.Tensor, target: torch.Tensor, hard_weight: float = 5.0) -> torch.Tensor:
    """Cross-entropy of (B, 3, 2, 2J + 1, H, W) logits against :func:`edge_targets` classes (B, 3, 2, H, W).

    Pairs whose wrapped step is wrong (class ``!= J``) weigh ``hard_weight``; the others 1. The last column's
    horizontal and the last row's vertical pairs (no neighbour) are left out.
    """
    j = (logits.shape[3] - 1) // 2
    ce = F.cross_entropy(logits.movedim(3, 1), target, reduction="none")
    weight = 1.0 + (hard_weight - 1.0) * (target != j).float()
    weight[:, :, 0, :, -1] = 0.0
    weight[:, :, 1, -1, :] = 0.0
    return (ce * weight).sum() / weight.sum().clamp_min(1.0)
