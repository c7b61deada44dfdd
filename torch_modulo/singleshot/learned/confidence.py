"""The learned method's confidence map: how sure the network is of each pixel's level, as a function and a layer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from torch_modulo._checks import (
    check_bits,
    check_flag,
    check_floating,
    check_image_shape,
    check_modulus,
    check_nonempty_image,
    check_tensor,
)
from torch_modulo.singleshot.learned.inference import TILE
from torch_modulo.singleshot.learned.network import load_model
from torch_modulo.singleshot.learned.solver import check_tile, check_weights, learned_k

__all__ = ["LearnedConfidence", "learned_confidence"]


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
    :func:`~torch_modulo.singleshot.learned.decode_jumps`). Low values mark pixels whose level hangs on an unsure
    jump: check them, or take a second exposure there. Like :func:`~torch_modulo.unwrap_confidence` (which reads the
    restored image alone), it cannot flag a region the network puts at a wrong level with confidence. Runs the
    network again (same options as the method); ``unwrap_single(..., return_info=True)`` gives the same map from
    its own run (:attr:`~torch_modulo.singleshot.SingleShotInfo.confidence`).

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
    check_tensor(modulus, "modulus")
    check_floating(modulus, "modulus")
    check_image_shape(modulus, "modulus", 2, 4)
    check_nonempty_image(modulus, "modulus")
    bits = check_bits(bits, modulus.dtype)
    check_modulus(modulus, bits)
    net = load_model(check_weights(weights, "weights"), device=modulus.device)
    augment, tile = check_flag(augment, "augment"), check_tile(tile, "tile")
    if modulus.numel() == 0:  # no images or no channels
        return torch.ones_like(modulus)
    batch = modulus.detach().reshape(-1, *((1, 1, *modulus.shape)[-3:]))
    maps = [learned_k(image, bits, net, 0, augment, tile)[1] for image in batch]
    out = torch.from_numpy(np.stack(maps))
    return out.to(device=modulus.device, dtype=modulus.dtype).reshape(modulus.shape)


class LearnedConfidence(nn.Module):
    """Module twin of :func:`learned_confidence`. Not differentiable (the map comes from a decoded tree).

    Args:
        bits: sensor bit depth ``N``.
        weights: ``None`` (the shipped weights) or a weights file.
        augment: average the network over the four flips of the image.
        tile: tile side of the network's prediction.

    Shape:
        - Input: (B, C, H, W), (C, H, W) or (H, W) moduli.
        - Output: same as the input.

    Example:
        >>> ramp = torch.arange(0.0, 1200.0, 40.0).reshape(1, -1).repeat(8, 1)
        >>> bool(torch.equal(LearnedConfidence()(ramp % 256), learned_confidence(ramp % 256)))
        True
    """

    def __init__(
        self, bits: int = 8, *, weights: str | Path | None = None, augment: bool = False, tile: int = TILE
    ) -> None:
        super().__init__()
        self.bits = check_bits(bits, torch.float64)
        self.weights = check_weights(weights, "weights")
        self.augment = check_flag(augment, "augment")
        self.tile = check_tile(tile, "tile")

    def forward(self, modulus: torch.Tensor) -> torch.Tensor:
        return learned_confidence(modulus, self.bits, weights=self.weights, augment=self.augment, tile=self.tile)
