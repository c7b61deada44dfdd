"""Contrast-limited adaptive histogram equalisation (CLAHE) of log luminance, through Kornia."""

from __future__ import annotations

import math

import kornia
import torch
from torch import nn

from torch_modulo._checks import check_flag, check_int, check_real
from torch_modulo.tonemap._common import as_batch, encode, luminance, needs_grad, restore, widened

__all__ = ["ClaheToneMap", "tonemap_clahe"]


def _check_clahe_args(clip_limit: object, grid_size: object, differentiable: object) -> tuple[float, tuple[int, int]]:
    clip = check_real(clip_limit, "clip_limit", 0.0, what=">= 0 (0 disables clipping)")
    if not isinstance(grid_size, tuple | list) or len(grid_size) != 2:
        raise TypeError(f"grid_size must be a pair of integers (rows, columns); got {grid_size!r}")
    grid = (check_int(grid_size[0], "grid_size[0]", 1), check_int(grid_size[1], "grid_size[1]", 1))
    check_flag(differentiable, "differentiable")
    return clip, grid


def tonemap_clahe(
    hdr: torch.Tensor,
    clip_limit: float = 2.0,
    grid_size: tuple[int, int] = (8, 8),
    *,
    differentiable: bool = False,
    srgb: bool = False,
) -> torch.Tensor:
    r"""Contrast-limited adaptive histogram equalisation of log luminance (``kornia.enhance.equalize_clahe``).

    Per image, brightness :math:`\log Y` is scaled into ``[0, 1]`` between its minimum over non-zero pixels and
    its maximum (Kornia's CLAHE needs values in ``[0, 1]``), equalised by CLAHE, and used as the display
    luminance; R, G and B are scaled by the same factor (black pixels take the equalised value as grey). This
    is the "adaptive histogram equalization" the paper's figures are often taken to mean; the operator the
    paper cites is :func:`tonemap_histogram`.

    Args:
        hdr: linear radiance, (B, C, H, W), (C, H, W) or (H, W), C = 1 or 3, values >= 0.
        clip_limit: CLAHE contrast limit (OpenCV's meaning; 0 disables limiting; Kornia's default is 40).
        grid_size: tiles along (H, W); the image must be larger than the grid along each axis.
        differentiable: use Kornia's slow, differentiable path; the default fast path quantises brightness to
            256 levels and passes no gradient through the equalisation.
        srgb: apply the sRGB transfer function to the result.

    Returns:
        Display values in ``[0, 1]``, same shape, dtype and device as ``hdr``. Monotonic in luminance at each
        pixel position; a local operator, so not between positions (with ``grid_size=(1, 1)`` it is global).
        float16 and bfloat16 input is equalised in float32 and the result cast back.

    Example:
        >>> x = torch.logspace(0, 6, 16).reshape(4, 4)
        >>> y = tonemap_clahe(x, clip_limit=0.0, grid_size=(1, 1))
        >>> bool((y.flatten().diff() >= 0).all()), round(float(y.min()), 3), float(y.max())
        (True, 0.063, 1.0)
    """
    clip, grid = _check_clahe_args(clip_limit, grid_size, differentiable)
    srgb = check_flag(srgb, "srgb")
    x, shape = as_batch(hdr)
    if x.numel() == 0:
        return restore(x.clone(), shape, hdr)
    h, w = x.shape[-2:]
    if h <= grid[0] or w <= grid[1]:
        raise ValueError(
            f"tonemap_clahe needs an image larger than grid_size={grid} along each axis; got {h}x{w} "
            f"(use a smaller grid_size)"
        )
    # Half precision cannot place log luminance on the 256 equalisation levels: widen to float32.
    src = widened(x if needs_grad(x) else x.detach())
    out = encode(_clahe(src, clip, grid, differentiable), srgb)
    return restore(out.to(x.dtype), shape, hdr)


def _clahe(src: torch.Tensor, clip: float, grid: tuple[int, int], differentiable: bool) -> torch.Tensor:
    """CLAHE of the log luminance of a (B, C, H, W) batch; R, G and B scaled by the equalised luminance."""
    y = luminance(src)
    pos = y > 0
    bright = torch.log(torch.where(pos, y, torch.ones_like(y)))
    inf = torch.tensor(math.inf, dtype=src.dtype, device=src.device)
    lo = torch.where(pos, bright, inf).amin(dim=(1, 2, 3), keepdim=True)
    hi = torch.where(pos, bright, -inf).amax(dim=(1, 2, 3), keepdim=True)
    ok = torch.isfinite(lo) & (hi > lo)
    lo = torch.where(torch.isfinite(lo), lo, torch.zeros_like(lo))
    width = torch.where(ok, hi - lo, torch.ones_like(lo))
    level = torch.where(pos, (bright - lo) / width, torch.zeros_like(bright)).clamp(0.0, 1.0)
    eq = kornia.enhance.equalize_clahe(level, clip, grid, slow_and_differentiable=differentiable)
    if src.shape[1] == 1:
        return eq.clamp(0.0, 1.0)
    ratio = eq / y.clamp_min(torch.finfo(src.dtype).tiny)
    return torch.where(pos, src * ratio, eq.expand_as(src)).clamp(0.0, 1.0)


class ClaheToneMap(nn.Module):
    """Module twin of :func:`tonemap_clahe` (CLAHE on log luminance).

    Shape:
        - Input: (B, C, H, W), (C, H, W) or (H, W) with C = 1 or 3; H and W larger than the grid.
        - Output: same as input, values in [0, 1].

    Example:
        >>> ClaheToneMap(grid_size=(2, 2))(torch.rand(1, 3, 16, 16) * 1000).shape
        torch.Size([1, 3, 16, 16])
    """

    def __init__(
        self,
        clip_limit: float = 2.0,
        grid_size: tuple[int, int] = (8, 8),
        differentiable: bool = False,
        srgb: bool = False,
    ) -> None:
        super().__init__()
        self.clip_limit, self.grid_size = _check_clahe_args(clip_limit, grid_size, differentiable)
        self.differentiable = bool(differentiable)
        self.srgb = check_flag(srgb, "srgb")

    def forward(self, hdr: torch.Tensor) -> torch.Tensor:
        return tonemap_clahe(hdr, self.clip_limit, self.grid_size, differentiable=self.differentiable, srgb=self.srgb)

    def extra_repr(self) -> str:
        return (
            f"clip_limit={self.clip_limit}, grid_size={self.grid_size}, differentiable={self.differentiable}, "
            f"srgb={self.srgb}"
        )
