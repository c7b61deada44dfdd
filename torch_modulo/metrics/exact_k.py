"""Rollover-count accuracy: is the ``k`` of Eq. 2 (``I = I_m + k 2^N``) right, after removing the global offset?"""

from __future__ import annotations

import torch
from torch import nn

from torch_modulo._checks import check_bits, check_flag, check_nonnegative
from torch_modulo.metrics._common import as_bchw, float_pair, image_pair, real_image

__all__ = ["ExactKShare", "exact_k_map", "exact_k_share"]


def _row_mode(d: torch.Tensor) -> torch.Tensor:
    """Most common value of each row of a 2-D tensor; ties go to the smallest value, on every device.

    After one sort per row, ``run[j] = j - start(j)`` (plus one) is the length so far of the run of equal values
    holding position ``j``; the first position where it peaks ends the first longest run (the smallest mode).
    """
    s, _ = torch.sort(d, dim=1)
    n = s.shape[1]
    index_dtype = torch.int32 if n < 2**31 else torch.int64
    pos = torch.arange(n, device=d.device, dtype=index_dtype).expand_as(s)
    new_run = torch.ones_like(s, dtype=torch.bool)
    new_run[:, 1:] = s[:, 1:] != s[:, :-1]
    start = torch.cummax(torch.where(new_run, pos, 0), dim=1).values
    run = pos - start
    last = run.argmax(dim=1, keepdim=True)  # argmax returns the first maximal position
    return s.gather(1, last).squeeze(1)


def _wide_counts(x: torch.Tensor) -> torch.Tensor:
    """Integer counts as int64 (exact, and wide enough for any period); floating counts as they are."""
    return x if x.is_floating_point() else x.to(torch.int64)


def exact_k_map(
    restored: torch.Tensor,
    truth: torch.Tensor,
    bits: int = 8,
    *,
    align: bool = True,
) -> torch.Tensor:
    """Where the rollover count ``k = floor(I / 2^bits)`` (Eq. 2) of the restored counts is right.

    Unwrapping recovers ``k`` only up to a constant per image and channel. With ``align=True`` that constant is
    estimated as the most common difference ``d = k_restored - k_truth`` over each channel of each image (ties go
    to the smallest ``d``) and removed; a value is right when its aligned difference is 0.

    Args:
        restored: restored counts (integers stored as floats, ``>= 0``), ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        truth: the true counts, same shape.
        bits: sensor bit depth ``N``; the rollover period is ``2^N``.
        align: remove each channel's most common offset first (default); ``False`` compares ``k`` as it is.

    Returns:
        A bool tensor of the input's shape, ``True`` where the (aligned) rollover count is right.

    Raises:
        TypeError: an input is not a real tensor, or ``bits`` is not an integer.
        ValueError: shapes differ, a value is NaN, infinite or negative, an image has no pixels, or ``bits < 1``.

    Example:
        >>> truth = torch.tensor([[10.0, 300.0], [600.0, 20.0]])
        >>> exact_k_map(truth + 256, truth)  # every k one too high: aligned away
        tensor([[True, True],
                [True, True]])
        >>> exact_k_map(truth + 256, truth, align=False)
        tensor([[False, False],
                [False, False]])
    """
    shape = real_image(restored, "restored").shape
    r, t = image_pair(restored, truth, ("restored", "truth"))
    bits = check_bits(bits, torch.float64)
    align = check_flag(align, "align")
    check_nonnegative(r, "restored")
    check_nonnegative(t, "truth")
    b, c, h, w = r.shape
    if b and c * h * w == 0:
        raise ValueError(f"restored and truth must have at least one pixel per image; got shape {tuple(shape)}")
    period = 2**bits
    # Integer counts divide exactly in int64 (a uint8 tensor cannot even hold the period 256).
    k_r = torch.div(_wide_counts(r), period, rounding_mode="floor")
    k_t = torch.div(_wide_counts(t), period, rounding_mode="floor")
    k_r, k_t = float_pair(k_r, k_t)
    d = (k_r - k_t).reshape(b * c, h * w)
    if align and d.numel():
        d = d - _row_mode(d)[:, None]
    return (d == 0).reshape(shape)


def exact_k_share(
    restored: torch.Tensor,
    truth: torch.Tensor,
    bits: int = 8,
    *,
    align: bool = True,
) -> torch.Tensor:
    """Share of values whose rollover count ``k`` (Eq. 2) is right, per image: the single-shot benchmark's exact-k.

    ``k = floor(I / 2^bits)`` for the restored and the true counts. With ``align=True`` each channel's global offset
    is removed first: the most common difference ``k_restored - k_truth`` over that channel (see
    :func:`exact_k_map`). The score is the share of values over ``(C, H, W)`` whose aligned difference is 0.

    Args:
        restored: restored counts (integers stored as floats, ``>= 0``), ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        truth: the true counts, same shape.
        bits: sensor bit depth ``N``; the rollover period is ``2^N``.
        align: remove each channel's most common offset first (default).

    Returns:
        ``(B,)`` shares in ``[0, 1]`` in the floating dtype of the inputs (float32 for integer inputs); ``(1,)`` for
        unbatched inputs, ``(0,)`` for an empty batch.

    Raises:
        TypeError: an input is not a real tensor, or ``bits`` is not an integer.
        ValueError: shapes differ, a value is NaN, infinite or negative, an image has no pixels, or ``bits < 1``.

    Example:
        >>> truth = torch.tensor([[10.0, 300.0], [600.0, 20.0]])
        >>> restored = truth + torch.tensor([[0.0, 0.0], [256.0, 0.0]])  # one wrong rollover count
        >>> exact_k_share(restored, truth)
        tensor([0.7500])
        >>> exact_k_share(restored + 512, truth)  # a global offset of two rollovers is aligned away
        tensor([0.7500])
    """
    ok = as_bchw(exact_k_map(restored, truth, bits, align=align))
    dtype = torch.promote_types(restored.dtype, truth.dtype)
    if not dtype.is_floating_point:
        dtype = torch.get_default_dtype()
    return ok.flatten(1).to(dtype).mean(dim=1)


class ExactKShare(nn.Module):
    """Module twin of :func:`exact_k_share`.

    Shape:
        - restored, truth: ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        - Output: ``(B,)``.

    Example:
        >>> ExactKShare(bits=4)(torch.tensor([[1.0, 17.0]]), torch.tensor([[1.0, 1.0]]))
        tensor([0.5000])
    """

    def __init__(self, bits: int = 8, *, align: bool = True) -> None:
        super().__init__()
        self.bits = check_bits(bits, torch.float64)
        self.align = check_flag(align, "align")

    def forward(self, restored: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
        return exact_k_share(restored, truth, self.bits, align=self.align)

    def extra_repr(self) -> str:
        return f"bits={self.bits}, align={self.align}"
