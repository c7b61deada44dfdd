r"""Colour filter arrays: Bayer mosaics of a colour modulo camera, from RGB radiance to mosaic and back.

A colour sensor puts a colour filter over every pixel, in a 2 x 2 pattern repeated over the sensor (Bayer): each
photosite sees one colour, and a colour modulo camera delivers one mosaicked frame, (B, 1, H, W), not three
planes. The pattern is named by its top-left 2 x 2 cell read row by row: ``"RGGB"`` (red at (0, 0), green at (0, 1)
and (1, 0), blue at (1, 1)), ``"BGGR"``, ``"GRBG"`` and ``"GBRG"`` (:data:`CFA_PATTERNS`).

- :func:`mosaic` keeps, of an RGB image, the colour each photosite sees.
- :func:`split_planes` cuts a mosaic into its four colour planes (B, 4, H/2, W/2), one per position of the 2 x 2
  cell, in the order (0, 0), (0, 1), (1, 0), (1, 1); :func:`merge_planes` puts them back.
- :func:`interpolate_wrapped` turns a wrapped mosaic into the wrapped RGB image a sensor with three full colour
  planes would have seen, interpolated on the circle: the guide ``unwrap_single(mosaic, bits, cfa=...)`` unwraps
  (the three colours on one shared tree, at full resolution) before it keeps the rollover counts of the photosites.
  Unwrapping the mosaic as one grey image fails: neighbours see different colours, so every step between them
  looks steep.
- :func:`demosaic` interpolates the two missing colours of every photosite: (B, 1, H, W) counts to (B, 3, H, W).
  It is linear in the counts (no clipping at the top, no tone curve), so it works on HDR values of any range.

Demosaicing mixes neighbouring photosites, so it happens after unwrapping, never on wrapped values: a wrapped
mosaic interpolated across a rollover gives values that are neither the modulus nor the counts.

Every function has a layer twin (:class:`Mosaic`, :class:`Demosaic`) whose ``forward`` only calls it.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from torch_modulo._checks import check_bits, check_choice, check_floating, check_modulus, check_tensor

__all__ = [
    "CFA_PATTERNS",
    "DEMOSAIC_METHODS",
    "Demosaic",
    "Mosaic",
    "cfa_colours",
    "check_cfa",
    "demosaic",
    "interpolate_wrapped",
    "merge_planes",
    "mosaic",
    "split_planes",
]

#: The Bayer patterns, named by their top-left 2 x 2 cell read row by row.
CFA_PATTERNS: tuple[str, ...] = ("RGGB", "BGGR", "GRBG", "GBRG")

#: The interpolations of :func:`demosaic`, the default first.
DEMOSAIC_METHODS: tuple[str, ...] = ("malvar", "bilinear")

_CHANNEL = {"R": 0, "G": 1, "B": 2}


def check_cfa(cfa: object, name: str = "cfa") -> str:
    """Return ``cfa`` if it is one of :data:`CFA_PATTERNS`; else raise a ``ValueError`` naming it.

    Example:
        >>> check_cfa("RGGB")
        'RGGB'
        >>> check_cfa("rggb")
        Traceback (most recent call last):
        ...
        ValueError: cfa must be one of 'BGGR', 'GBRG', 'GRBG', 'RGGB'; got 'rggb'
    """
    return check_choice(cfa, name, CFA_PATTERNS)


def cfa_colours(cfa: str) -> tuple[int, int, int, int]:
    """The colour channel (0 red, 1 green, 2 blue) of the photosites (0, 0), (0, 1), (1, 0), (1, 1) of ``cfa``.

    These are also the colours of the four planes of :func:`split_planes`, in order.

    Example:
        >>> cfa_colours("RGGB"), cfa_colours("GBRG")
        ((0, 1, 1, 2), (1, 2, 0, 1))
    """
    cfa = check_cfa(cfa)
    return tuple(_CHANNEL[c] for c in cfa)  # type: ignore[return-value]


def _check_layout(x: torch.Tensor, name: str, channels: int) -> None:
    """Refuse a tensor that is not (*, channels, H, W) with even H and W, naming its shape."""
    check_tensor(x, name)
    if x.dim() < 3 or x.shape[-3] != channels:
        raise ValueError(f"{name} must have shape (*, {channels}, H, W); got {tuple(x.shape)}")
    h, w = x.shape[-2:]
    if h % 2 or w % 2:
        raise ValueError(
            f"{name} must have an even height and width (whole 2 x 2 colour cells); got {h} x {w} "
            f"(shape {tuple(x.shape)}): crop a row or column first"
        )


def split_planes(mosaic: torch.Tensor) -> torch.Tensor:
    """The four colour planes of a mosaic: photosites (0, 0), (0, 1), (1, 0), (1, 1) of every 2 x 2 cell.

    A pure rearrangement (as ``pixel_unshuffle``, empty batches included): any dtype and device, differentiable.

    Args:
        mosaic: (*, 1, H, W) with even H and W.

    Returns:
        (*, 4, H/2, W/2); plane ``i`` has colour ``cfa_colours(cfa)[i]``.

    Raises:
        TypeError: ``mosaic`` is not a tensor.
        ValueError: not one channel, or an odd height or width.

    Example:
        >>> m = torch.arange(16.0).view(1, 1, 4, 4)
        >>> split_planes(m)[0, :, 0, 0], split_planes(m).shape
        (tensor([0., 1., 4., 5.]), torch.Size([1, 4, 2, 2]))
    """
    _check_layout(mosaic, "mosaic", 1)
    lead, (h, w) = mosaic.shape[:-3], mosaic.shape[-2:]
    cells = mosaic.reshape(*lead, h // 2, 2, w // 2, 2).movedim((-3, -1), (-4, -3))  # (*, 2, 2, h/2, w/2)
    return cells.reshape(*lead, 4, h // 2, w // 2)


def merge_planes(planes: torch.Tensor) -> torch.Tensor:
    """The mosaic of four colour planes: the inverse of :func:`split_planes`.

    Args:
        planes: (*, 4, h, w), the photosites (0, 0), (0, 1), (1, 0), (1, 1) of every 2 x 2 cell.

    Returns:
        (*, 1, 2h, 2w).

    Raises:
        TypeError: ``planes`` is not a tensor.
        ValueError: not four channels.

    Example:
        >>> m = torch.arange(16.0).view(1, 1, 4, 4)
        >>> torch.equal(merge_planes(split_planes(m)), m)
        True
    """
    check_tensor(planes, "planes")
    if planes.dim() < 3 or planes.shape[-3] != 4:
        raise ValueError(f"planes must have shape (*, 4, h, w); got {tuple(planes.shape)}")
    lead, (h, w) = planes.shape[:-3], planes.shape[-2:]
    cells = planes.reshape(*lead, 2, 2, h, w).movedim((-4, -3), (-3, -1))  # (*, h, 2, w, 2)
    return cells.reshape(*lead, 1, 2 * h, 2 * w)


def mosaic(rgb: torch.Tensor, cfa: str) -> torch.Tensor:
    """Keep, of an RGB image, the colour each photosite of the colour filter array ``cfa`` sees.

    Args:
        rgb: (*, 3, H, W) red, green and blue (radiance or counts), even H and W.
        cfa: one of :data:`CFA_PATTERNS`.

    Returns:
        (*, 1, H, W), same dtype and device; differentiable (a selection).

    Raises:
        TypeError: ``rgb`` is not a tensor.
        ValueError: an unknown pattern, not three channels, or an odd height or width.

    Example:
        >>> rgb = torch.stack([torch.full((2, 2), v) for v in (1.0, 2.0, 3.0)])   # R = 1, G = 2, B = 3
        >>> mosaic(rgb, "RGGB")
        tensor([[[1., 2.],
                 [2., 3.]]])
    """
    colours = cfa_colours(cfa)
    _check_layout(rgb, "rgb", 3)
    planes = [rgb[..., c, dy::2, dx::2] for c, (dy, dx) in zip(colours, ((0, 0), (0, 1), (1, 0), (1, 1)), strict=True)]
    return merge_planes(torch.stack(planes, dim=-3))


# ------------------------------------------------------------------------------------------------- demosaicing

# Five 5 x 5 interpolation kernels per method, each applied at every photosite; which one gives which colour depends
# on the photosite's own colour and on its neighbours' (see _selection). Order: the photosite itself; green at a red
# or blue photosite; the colour of the left and right neighbours; that of the upper and lower ones; that of the
# diagonal ones.
_KERNELS = {
    # Malvar, He and Cutler (ICASSP 2004): bilinear plus a gain times the Laplacian of the photosite's own colour;
    # the gains are the paper's (1/2, 5/8, 3/4), which give the integer kernels below, divided by 8.
    "malvar": [
        [[0, 0, 0, 0, 0], [0, 0, 0, 0, 0], [0, 0, 8, 0, 0], [0, 0, 0, 0, 0], [0, 0, 0, 0, 0]],
        [[0, 0, -1, 0, 0], [0, 0, 2, 0, 0], [-1, 2, 4, 2, -1], [0, 0, 2, 0, 0], [0, 0, -1, 0, 0]],
        [[0, 0, 0.5, 0, 0], [0, -1, 0, -1, 0], [-1, 4, 5, 4, -1], [0, -1, 0, -1, 0], [0, 0, 0.5, 0, 0]],
        [[0, 0, -1, 0, 0], [0, -1, 4, -1, 0], [0.5, 0, 5, 0, 0.5], [0, -1, 4, -1, 0], [0, 0, -1, 0, 0]],
        [[0, 0, -1.5, 0, 0], [0, 2, 0, 2, 0], [-1.5, 0, 6, 0, -1.5], [0, 2, 0, 2, 0], [0, 0, -1.5, 0, 0]],
    ],
    # Bilinear: the mean of the nearest photosites of the missing colour.
    "bilinear": [
        [[0, 0, 0, 0, 0], [0, 0, 0, 0, 0], [0, 0, 8, 0, 0], [0, 0, 0, 0, 0], [0, 0, 0, 0, 0]],
        [[0, 0, 0, 0, 0], [0, 0, 2, 0, 0], [0, 2, 0, 2, 0], [0, 0, 2, 0, 0], [0, 0, 0, 0, 0]],
        [[0, 0, 0, 0, 0], [0, 0, 0, 0, 0], [0, 4, 0, 4, 0], [0, 0, 0, 0, 0], [0, 0, 0, 0, 0]],
        [[0, 0, 0, 0, 0], [0, 0, 4, 0, 0], [0, 0, 0, 0, 0], [0, 0, 4, 0, 0], [0, 0, 0, 0, 0]],
        [[0, 0, 0, 0, 0], [0, 2, 0, 2, 0], [0, 0, 0, 0, 0], [0, 2, 0, 2, 0], [0, 0, 0, 0, 0]],
    ],
}
_SELF, _GREEN, _ROW, _COLUMN, _DIAGONAL = range(5)


def _selection(cfa: str) -> list[list[int]]:
    """``sel[channel][cell]``: the kernel that gives ``channel`` at the photosites of the 2 x 2 cell ``cell``."""
    colours = cfa_colours(cfa)
    sel = [[0] * 4 for _ in range(3)]
    for cell, own in enumerate(colours):
        dy, dx = divmod(cell, 2)
        if own == 1:  # green: the other two colours sit left/right and above/below
            sel[1][cell] = _SELF
            sel[colours[dy * 2 + 1 - dx]][cell] = _ROW
            sel[colours[(1 - dy) * 2 + dx]][cell] = _COLUMN
        else:  # red or blue: green on the cross, the other colour on the diagonals
            sel[own][cell] = _SELF
            sel[1][cell] = _GREEN
            sel[2 - own][cell] = _DIAGONAL
    return sel


def _mirror(n: int, pad: int, device: torch.device) -> torch.Tensor:
    """Indices of ``range(-pad, n + pad)`` mirrored into ``[0, n)`` without repeating the edge; keeps parity."""
    period = 2 * (n - 1)
    idx = torch.arange(-pad, n + pad, device=device).remainder(period)
    return torch.where(idx >= n, period - idx, idx)


def demosaic(counts: torch.Tensor, cfa: str, method: str = "malvar") -> torch.Tensor:
    """Interpolate the two missing colours of every photosite: a mosaic of linear counts to RGB.

    Demosaic after unwrapping, never wrapped values: the interpolation mixes neighbouring photosites, which is only
    meaningful for counts (or radiance), not for moduli that roll over between them.

    Both methods are linear filters of the mosaic with no clipping at the top, so they keep HDR values of any
    range. ``"malvar"`` (default) is the gradient-corrected linear interpolation of Malvar, He and Cutler (2004):
    bilinear plus a share of the Laplacian of the photosite's own colour, which follows edges better; it can
    overshoot below zero next to very steep edges, and those values are set to 0 (radiance is not negative), or to
    the image's own darkest value where that is negative. ``"bilinear"`` averages the nearest photosites of each
    missing colour (as ``kornia.color.raw_to_rgb``) and never overshoots. The measured PSNR of both on the dev
    scenes is in ``docs/cfa.md``. Borders are mirrored without repeating the edge, which keeps the pattern. In both
    methods the photosites' own values are kept exactly, negative ones (dark-subtracted counts, say) included, and
    a flat colour comes back exactly whatever its sign.

    Args:
        counts: (*, 1, H, W) mosaic of unwrapped counts or radiance (floating), even H and W.
        cfa: its pattern, one of :data:`CFA_PATTERNS`.
        method: one of :data:`DEMOSAIC_METHODS`.

    Returns:
        (*, 3, H, W) red, green and blue, same dtype and device as ``counts``; differentiable. An empty batch or
        an empty image (H or W 0) gives an empty result of that shape, as :func:`mosaic` does.

    Raises:
        TypeError: ``counts`` is not a floating tensor.
        ValueError: an unknown pattern or method, not one channel, or an odd height or width.

    Example:
        >>> rgb = torch.stack([torch.full((4, 4), v) for v in (100.0, 2000.0, 30000.0)])[None]
        >>> demosaic(mosaic(rgb, "RGGB"), "RGGB")[0, :, 1, 1]          # flat colours come back exactly
        tensor([  100.,  2000., 30000.])
        >>> demosaic(mosaic(rgb, "GBRG"), "GBRG", method="bilinear").shape
        torch.Size([1, 3, 4, 4])
    """
    sel = _selection(check_cfa(cfa))
    check_choice(method, "method", DEMOSAIC_METHODS)
    check_floating(counts, "counts")
    _check_layout(counts, "counts", 1)
    lead, (h, w) = counts.shape[:-3], counts.shape[-2:]
    if counts.numel() == 0:  # an empty batch or empty images: nothing to interpolate (reshape(-1, ...) cannot say)
        return counts.new_zeros((*lead, 3, h, w))
    x = counts.reshape(-1, 1, h, w)
    padded = x[:, :, _mirror(h, 2, x.device)][:, :, :, _mirror(w, 2, x.device)]
    bilinear = torch.tensor(_KERNELS["bilinear"], dtype=x.dtype, device=x.device).unsqueeze(1) / 8
    filtered = F.conv2d(padded, bilinear)  # (N, 5, H, W)
    if method == "malvar":
        # The gradient correction alone (the photosite's own colour only), added to the bilinear part: summing the
        # two colours in one kernel would round the dim one to the precision of the bright one.
        correction = torch.tensor(_KERNELS["malvar"], dtype=x.dtype, device=x.device).unsqueeze(1) / 8 - bilinear
        filtered = filtered + F.conv2d(padded, correction)
    index = torch.tensor(sel, device=x.device).view(3, 2, 2).repeat(1, h // 2, w // 2)
    rgb = torch.gather(filtered, 1, index.expand(x.shape[0], 3, h, w))
    if method == "malvar":
        # The overshoot floor: 0, or the image's darkest value where it is negative, so that no photosite's own
        # value is changed. Per image, without a host sync; an image holding NaN keeps the floor 0, as before.
        darkest = x.detach().amin(dim=(1, 2, 3)).clamp(max=0.0)
        rgb = rgb.clamp(min=darkest.nan_to_num(nan=0.0, neginf=-math.inf).view(-1, 1, 1, 1))
    return rgb.reshape(*lead, 3, h, w)


def interpolate_wrapped(modulus: torch.Tensor, cfa: str, bits: int = 8) -> torch.Tensor:
    """The wrapped RGB image of a wrapped mosaic, interpolated on the circle: a guide for unwrapping the mosaic.

    Each photosite keeps its own modulus; each missing colour is the bilinear mean of the phasors
    ``exp(2 pi i I_m / 2**bits)`` of the nearest photosites of that colour, taken back to ``[0, 2**bits)`` and
    rounded. Where the scene is smooth this is the modulus of the missing colour; across steep steps it is a guess.
    The result is what single-shot unwrapping of a mosaic solves (``unwrap_single(mosaic, bits, cfa=...)``: the
    three colours at full resolution on one shared tree), after which only the photosites' own values are kept
    (:func:`mosaic` of the restored image). Its interpolated values are not colour: to see colour, unwrap first and
    :func:`demosaic` the restored counts.

    Args:
        modulus: (*, 1, H, W) wrapped mosaic, integers in ``[0, 2**bits)``, even H and W.
        cfa: its pattern, one of :data:`CFA_PATTERNS`.
        bits: the sensor's bit depth ``N``.

    Returns:
        (*, 3, H, W) integers in ``[0, 2**bits)``, same dtype and device as ``modulus``; ``mosaic(out, cfa)`` equals
        ``modulus``. An empty batch or an empty image gives an empty result of that shape.

    Raises:
        TypeError: ``modulus`` is not a floating tensor, or ``bits`` not an integer.
        ValueError: an unknown pattern, values that are not integers in ``[0, 2**bits)``, not one channel, or an
            odd height or width.

    Example:
        >>> m = torch.tensor([[[250.0, 10.0], [12.0, 20.0]]])              # RGGB: R 250, G 10 and 12, B 20
        >>> interpolate_wrapped(m, "RGGB")[:, 0, 0]                       # R, G (10 and 12 meet at 11), B
        tensor([250.,  11.,  20.])
    """
    colours = cfa_colours(cfa)
    check_floating(modulus, "modulus")
    _check_layout(modulus, "modulus", 1)
    bits = check_bits(bits, modulus.dtype)
    check_modulus(modulus, bits)
    work = torch.float32 if modulus.device.type == "mps" else torch.float64
    period = float(2**bits)
    angle = modulus.to(work) * (2 * torch.pi / period)
    cos, sin = demosaic(torch.cos(angle), cfa, "bilinear"), demosaic(torch.sin(angle), cfa, "bilinear")
    out = torch.remainder(torch.round(torch.atan2(sin, cos) * (period / (2 * torch.pi))), period)
    for c, (dy, dx) in zip(colours, ((0, 0), (0, 1), (1, 0), (1, 1)), strict=True):
        out[..., c, dy::2, dx::2] = modulus[..., 0, dy::2, dx::2]  # exactly the photosites' own moduli
    return out.to(modulus.dtype)


class Mosaic(nn.Module):
    """Module twin of :func:`mosaic`: RGB to the mosaic of a colour filter array.

    Args:
        cfa: one of :data:`CFA_PATTERNS`.

    Shape:
        - Input: (*, 3, H, W), even H and W.
        - Output: (*, 1, H, W).

    Example:
        >>> Mosaic("BGGR")(torch.arange(12.0).view(3, 2, 2))
        tensor([[[8., 5.],
                 [6., 3.]]])
    """

    def __init__(self, cfa: str) -> None:
        super().__init__()
        self.cfa = check_cfa(cfa)

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        return mosaic(rgb, self.cfa)

    def extra_repr(self) -> str:
        return f"cfa={self.cfa!r}"


class Demosaic(nn.Module):
    """Module twin of :func:`demosaic`: unwrapped counts of a colour filter array to RGB.

    Args:
        cfa: one of :data:`CFA_PATTERNS`.
        method: one of :data:`DEMOSAIC_METHODS`.

    Shape:
        - Input: (*, 1, H, W), even H and W.
        - Output: (*, 3, H, W).

    Example:
        >>> Demosaic("RGGB")(torch.full((1, 1, 2, 2), 500.0))
        tensor([[[[500., 500.],
                  [500., 500.]],
        <BLANKLINE>
                 [[500., 500.],
                  [500., 500.]],
        <BLANKLINE>
                 [[500., 500.],
                  [500., 500.]]]])
    """

    def __init__(self, cfa: str, method: str = "malvar") -> None:
        super().__init__()
        self.cfa = check_cfa(cfa)
        self.method = check_choice(method, "method", DEMOSAIC_METHODS)

    def forward(self, counts: torch.Tensor) -> torch.Tensor:
        return demosaic(counts, self.cfa, self.method)

    def extra_repr(self) -> str:
        return f"cfa={self.cfa!r}, method={self.method!r}"
