"""Where to trust a single-shot result: a per-pixel confidence in the recovered rollover count ``k``.

Unwrapping one modulus image can only integrate differences that are smaller than half a period: a pixel
whose every path to the rest of the image crosses a larger step is at a level the data do not determine
(any solver guesses it). :func:`unwrap_confidence` measures this on a restored image: for every pixel, the
*bottleneck* ``b`` is the smallest value such that a path of neighbour steps ``|I_i - I_j| <= b`` joins it to
a reference pixel (in the largest region joined by steps of at most an eighth of a period); the confidence is
``clip(1 - b / (2**bits / 2), 0, 1)``. It is near 1 in smooth regions connected to the reference, falls as the
best path has to cross steeper steps, and is 0 where every path crosses a step of half a period or more.

The bottleneck of every pixel is read off a minimum spanning tree of the neighbour graph weighted by
``|I_i - I_j|`` (the tree path between two nodes minimises the largest weight on the path), with scipy, and
the largest weight on each tree path is taken by pointer jumping: whole-array calls, no per-pixel loop.

Where a result is mostly right, its errors sit among the least confident pixels (docs/singleshot.md has the
measurements). It cannot flag a region that was put at a wrong level *consistently*: where half of the image is
one level off behind a long edge, both halves look smooth (a second exposure, :func:`torch_modulo.unwrap_multi`,
settles it).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from torch_modulo._checks import (
    check_bits,
    check_finite,
    check_floating,
    check_image_shape,
    check_nonempty_image,
    check_tensor,
)
from torch_modulo.singleshot.grid import components, pair_indices, pair_offsets, path_to_root, spanning_tree

__all__ = ["UnwrapConfidence", "bottleneck_steps", "unwrap_confidence"]


def bottleneck_steps(image: np.ndarray, bits: int = 8, neighborhood: int = 8) -> np.ndarray:
    """Per pixel, the smallest ``b`` such that steps ``<= b`` join it to the reference region (numpy, one plane).

    Args:
        image: (H, W) restored counts (any real values).
        bits: sensor bit depth ``N``; the reference region is joined by steps ``<= 2**bits / 8``.
        neighborhood: 8 or 4.

    Returns:
        float64 (H, W) bottlenecks, in counts.
    """
    image = np.asarray(image, dtype=np.float64)
    h, w = image.shape
    n = h * w
    if n <= 1:
        return np.zeros((h, w))
    pairs = [pair_indices(h, w, off) for off in pair_offsets(neighborhood)]
    i = np.concatenate([p[0] for p in pairs])
    j = np.concatenate([p[1] for p in pairs])
    flat = image.ravel()
    step = np.abs(flat[i] - flat[j])
    joined = step <= (1 << bits) / 8
    _, labels = components(n, i[joined], j[joined])
    root = int(np.argmax(labels == np.bincount(labels).argmax()))  # a pixel of the largest region
    # scipy reads a stored 0 as "no edge": every weight is shifted by 1 (the tree is the same).
    parent = spanning_tree(n, i, j, step + 1.0, root)
    # The step from each pixel up to its parent (0 at the root), then the largest one on each path to the root.
    return path_to_root(parent, np.abs(flat - flat[parent]), np.maximum).reshape(h, w)


def unwrap_confidence(restored: torch.Tensor, bits: int = 8, *, neighborhood: int = 8) -> torch.Tensor:
    """Per-pixel confidence in the rollover count of a single-shot result, in ``[0, 1]``.

    ``1 - b / 2**(bits - 1)`` clipped to ``[0, 1]``, where ``b`` is the steepest step on the best path from the
    pixel to a reference pixel in the largest smooth region (see the module docstring). 0 means that every path
    crosses a step of at least half a period, so the pixel's level was guessed: take a second exposure there.

    Args:
        restored: restored counts ``I_m + k 2**bits`` (e.g. from :func:`~torch_modulo.unwrap_single`), floating,
            shape (B, C, H, W), (C, H, W) or (H, W), on any device.
        bits: sensor bit depth ``N``.
        neighborhood: 8 or 4.

    Returns:
        Confidence with the shape, dtype and device of ``restored``; each image and channel separately.

    Raises:
        TypeError: ``restored`` is not a floating tensor.
        ValueError: NaN or infinite values, an empty image, a wrong number of dimensions, bad ``bits`` or
            ``neighborhood``.

    Example:
        >>> steps = torch.tensor([[0.0, 16.0, 32.0, 400.0, 416.0]])  # a 368-count cliff
        >>> unwrap_confidence(steps, bits=8)
        tensor([[1.0000, 0.8750, 0.8750, 0.0000, 0.0000]])
    """
    check_tensor(restored, "restored")
    check_floating(restored, "restored")
    check_image_shape(restored, "restored", 2, 4)
    bits = check_bits(bits, restored.dtype)
    pair_offsets(neighborhood)
    check_nonempty_image(restored, "restored")
    h, w = restored.shape[-2:]
    check_finite(restored, "restored")
    if restored.numel() == 0:  # an empty batch
        return torch.empty_like(restored)
    planes = restored.detach().to("cpu", torch.float64).reshape(-1, h, w).numpy()
    half = float(1 << (bits - 1))
    out = np.stack([bottleneck_steps(plane, bits, neighborhood) for plane in planes])
    confidence = np.clip(1.0 - out / half, 0.0, 1.0)
    return torch.from_numpy(confidence).reshape(restored.shape).to(device=restored.device, dtype=restored.dtype)


class UnwrapConfidence(nn.Module):
    """Module twin of :func:`unwrap_confidence`.

    Args:
        bits: sensor bit depth ``N``.
        neighborhood: 8 or 4.

    Shape:
        - Input: (B, C, H, W), (C, H, W) or (H, W) restored counts.
        - Output: same as the input.

    Example:
        >>> UnwrapConfidence(bits=8)(torch.tensor([[0.0, 100.0, 200.0]]))
        tensor([[1.0000, 0.2188, 0.2188]])
    """

    def __init__(self, bits: int = 8, *, neighborhood: int = 8) -> None:
        super().__init__()
        self.bits = check_bits(bits, torch.float64)
        pair_offsets(neighborhood)
        self.neighborhood = neighborhood

    def forward(self, restored: torch.Tensor) -> torch.Tensor:
        return unwrap_confidence(restored, self.bits, neighborhood=self.neighborhood)
