"""The learned method's networks and their shipped weights: the edge network, the level head, one weight cache.

:class:`EdgeJumpNet` is a small fully convolutional U-Net that sees the modulus image and its wrapped differences
(:func:`edge_features`; for colour, all channels together) and predicts, for every horizontal and vertical neighbour
pair, a distribution over the integer *jump* ``n`` in ``I_j - I_i = w(I_m,j - I_m,i) + n 2^N``, ``n`` in
``[-J, J]``, where ``w`` wraps into ``[-2^(N-1), 2^(N-1))``. :class:`LevelNet` puts a :class:`LevelHead` on that
network's encoder: a distribution over the rollover count ``k`` per 2 x 2 block.

The shipped weights (``torch_modulo/singleshot/weights``: :data:`WEIGHTS` and :data:`LEVEL_WEIGHTS`, their record in
``MODEL_CARD.md``) load offline (:func:`load_model`, :func:`load_levels`), through one cache of loaded networks per
file and device.
"""

from __future__ import annotations

import functools
from importlib import resources
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

__all__ = [
    "LEVELS",
    "LEVEL_WEIGHTS",
    "SLOTS",
    "WEIGHTS",
    "EdgeJumpNet",
    "LevelHead",
    "LevelNet",
    "cpu_layout",
    "edge_features",
    "load_levels",
    "load_model",
    "weights_path",
    "wrap_difference",
]

#: The file name of the shipped edge network's weights inside ``torch_modulo/singleshot/weights``.
WEIGHTS = "edge_jump.pt"

#: The file name of the shipped level weights inside ``torch_modulo/singleshot/weights``.
LEVEL_WEIGHTS = "levels.pt"

#: Channels the networks see at once: one image's RGB (a single channel is repeated three times).
SLOTS = 3

#: The levels the shipped head tells apart: ``k = 0 .. LEVELS - 1`` (its training labels were clipped at the last).
LEVELS = 16


def wrap_difference(d: torch.Tensor, period: float) -> torch.Tensor:
    """Wrap differences into ``[-period / 2, period / 2)``.

    Example:
        >>> wrap_difference(torch.tensor([200.0, -200.0, 128.0]), 256.0)
        tensor([ -56.,   56., -128.])
    """
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
    dx = F.pad(wrap_difference(m[..., :, 1:] - m[..., :, :-1], period), (0, 1))
    dy = F.pad(wrap_difference(m[..., 1:, :] - m[..., :-1, :], period), (0, 0, 0, 1))
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
          :func:`~torch_modulo.singleshot.learned.predict_edges` pads).
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
        # channels first (the reductions over jumps that follow are faster so): see cpu_layout
        bias = self.head.bias
        assert bias is not None
        out = F.conv2d(features.contiguous(), self.head.weight[:n], bias[:n])
        return out.view(b, channels, 2, 2 * self.max_jump + 1, h, w)


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
        hidden = self.net[:-1](features).contiguous()  # channels first for the 1 x 1 convolution (cpu_layout)
        return self.net[-1](hidden).view(b, SLOTS, self.levels, h, w)


class LevelNet(nn.Module):
    """A :class:`LevelHead` at half resolution on an :class:`EdgeJumpNet`'s encoder.

    The head sees the encoder's half-resolution features (``d2`` of :meth:`EdgeJumpNet.encode`) and the input pooled
    2 x 2; no full-resolution decoder stage runs, so the levels cost a fraction of the edge network. The trunk is a
    copy of the edge network it was trained on (its jump head is not used).

    Args:
        config: the trunk's :class:`EdgeJumpNet` arguments.
        width: the head's channels.
        levels: the levels told apart (``k = 0 .. levels - 1``).

    Shape:
        - Input: (B, 15, H, W) :func:`edge_features`, ``H`` and ``W`` multiples of :attr:`stride`.
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


def cpu_layout(net: nn.Module) -> nn.Module:
    """``net`` with its 3 x 3 convolutions' weights channels last when it is on the CPU (their outputs follow): oneDNN
    runs those faster. The 1 x 1 heads stay channels first, with their input made so, as the reductions over jumps
    and levels after them are faster on channels-first logits. The results are the same up to float rounding."""
    if next(net.parameters()).device.type == "cpu":
        for module in net.modules():
            if isinstance(module, nn.Conv2d) and module.kernel_size != (1, 1):
                module.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # not in the stubs
    return net


def _edge_network(record: dict) -> EdgeJumpNet:
    net = EdgeJumpNet(**record["config"])
    net.load_state_dict({k: v.float() for k, v in record["state"].items()})
    return net


def _level_network(record: dict) -> LevelNet:
    levels = int(record["head"]["net.6.bias"].numel()) // SLOTS
    net = LevelNet(record["config"], width=int(record["head"]["net.0.bias"].numel()), levels=levels)
    net.trunk.load_state_dict({k: v.float() for k, v in record["state"].items()})
    net.head.load_state_dict({k: v.float() for k, v in record["head"].items()})
    return net


#: What each kind of weights file holds and how its network is built from it.
_KINDS = {
    "edges": ("a weights file of the training recipe ({'config': ..., 'state': ...} for EdgeJumpNet)", _edge_network),
    "levels": (
        "a level weights file ({'config': ..., 'state': ..., 'head': ...} as the level recipe exports it)",
        _level_network,
    ),
}


@functools.lru_cache(maxsize=8)
def _load(path: str, device: str, kind: str) -> nn.Module:
    """The network of the weights file ``path`` of ``kind`` on ``device``, in eval mode: one cached copy per file and
    device (moving a shared copy would move it for every caller)."""
    what, build = _KINDS[kind]
    try:
        net = build(torch.load(path, map_location="cpu", weights_only=True))
    except Exception as error:  # a file of another kind, another network, a truncated download: name the file
        raise ValueError(f"{path!r} is not {what}: {type(error).__name__}: {error}") from error
    return cpu_layout(net.eval().to(device))


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
    net = _load(weights_path(path, WEIGHTS), str(torch.device(device)), "edges")
    assert isinstance(net, EdgeJumpNet)
    return net


def load_levels(path: str | Path | None = None, device: torch.device | str = "cpu") -> LevelNet:
    """The trained :class:`LevelNet` (eval mode), loaded offline.

    Args:
        path: a level weights file (as the level recipe in ``references/learned_single`` exports it); ``None``
            loads the shipped one.
        device: where to put the network.

    Raises:
        FileNotFoundError: there is no file at ``path``.
        ValueError: the file is not a level weights file (the message names it).

    Example:
        >>> load_levels().head.levels
        16
    """
    net = _load(weights_path(path, LEVEL_WEIGHTS), str(torch.device(device)), "levels")
    assert isinstance(net, LevelNet)
    return net
