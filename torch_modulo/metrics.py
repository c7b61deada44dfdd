"""Quality metrics for recovered HDR images: rollover-count accuracy, PSNR (linear, log, PU21), tone-mapped SSIM.

Every metric reduces each batch item to one number and returns a tensor of shape ``(B,)`` on the input's device and
dtype. Images may be ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``; unbatched inputs count as a batch of one, so
the result then has shape ``(1,)``. Both images must have the same shape.

- :func:`exact_k_share` / :func:`exact_k_map`: is the rollover count ``k`` of Eq. 2 (``I = I_m + k 2^N``) right?
  Unwrapping fixes ``k`` only up to a global constant per image and channel, so that constant is aligned first.
- :func:`psnr`: PSNR on linear values with a given peak.
- :func:`psnr_log`: PSNR on ``log2`` radiance relative to the reference's peak.
- :func:`pu21_encode` / :func:`psnr_pu21`: PSNR on the PU21 perceptually uniform encoding (Mantiuk and Azimi, 2021).
- :func:`ssim_tonemapped`: SSIM (Kornia) on tone-mapped images.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import kornia
import torch
from torch import nn

from torch_modulo._checks import check_bits, check_finite, check_nonnegative, check_tensor

__all__ = [
    "PSNR",
    "PU21_LUMINANCE_RANGE",
    "PU21_PARAMETERS",
    "PSNRLog",
    "PSNRPU21",
    "PU21Encode",
    "SSIMToneMapped",
    "ExactKShare",
    "exact_k_map",
    "exact_k_share",
    "log_relative_tonemap",
    "psnr",
    "psnr_log",
    "psnr_pu21",
    "pu21_encode",
    "ssim_tonemapped",
]


# --------------------------------------------------------------------------------------------------------------------
# shared helpers
# --------------------------------------------------------------------------------------------------------------------


def _check_real(x: object, name: str) -> torch.Tensor:
    """A real (floating or integer, not bool or complex) tensor with 2 to 4 dimensions."""
    x = check_tensor(x, name)
    if x.dtype == torch.bool or x.is_complex():
        raise TypeError(f"{name} must hold real numbers; got dtype {x.dtype}")
    if not 2 <= x.dim() <= 4:
        raise ValueError(f"{name} must have shape (B, C, H, W), (C, H, W) or (H, W); got {tuple(x.shape)}")
    return x


def _pair(x: object, y: object, names: tuple[str, str]) -> tuple[torch.Tensor, torch.Tensor]:
    """Validate two images of the same shape and return them as ``(B, C, H, W)`` views."""
    x = _check_real(x, names[0])
    y = _check_real(y, names[1])
    if x.shape != y.shape:
        raise ValueError(
            f"{names[0]} and {names[1]} must have the same shape; got {tuple(x.shape)} and {tuple(y.shape)}"
        )
    if x.device != y.device:
        raise ValueError(f"{names[0]} and {names[1]} must be on the same device; got {x.device} and {y.device}")
    return _as_bchw(x), _as_bchw(y)


def _as_bchw(x: torch.Tensor) -> torch.Tensor:
    if x.dim() == 2:
        return x[None, None]
    if x.dim() == 3:
        return x[None]
    return x


def _float_pair(x: torch.Tensor, y: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Promote to a common floating dtype (integer inputs become the default float dtype)."""
    dtype = torch.promote_types(x.dtype, y.dtype)
    if not dtype.is_floating_point:
        dtype = torch.get_default_dtype()
    return x.to(dtype), y.to(dtype)


def _positive_float(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(f"{name} must be a positive number; got {value!r}")
    value = float(value)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be positive and finite; got {value}")
    return value


# --------------------------------------------------------------------------------------------------------------------
# rollover-count accuracy
# --------------------------------------------------------------------------------------------------------------------


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
    shape = _check_real(restored, "restored").shape
    r, t = _pair(restored, truth, ("restored", "truth"))
    bits = check_bits(bits, torch.float64)
    check_nonnegative(r, "restored")
    check_nonnegative(t, "truth")
    b, c, h, w = r.shape
    if b and c * h * w == 0:
        raise ValueError(f"restored and truth must have at least one pixel per image; got shape {tuple(shape)}")
    period = 2**bits
    k_r = torch.div(r, period, rounding_mode="floor")
    k_t = torch.div(t, period, rounding_mode="floor")
    k_r, k_t = _float_pair(k_r, k_t)
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
    ok = _as_bchw(exact_k_map(restored, truth, bits, align=align))
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
        if not isinstance(align, bool):
            raise TypeError(f"align must be a bool; got {align!r}")
        self.align = align

    def forward(self, restored: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
        return exact_k_share(restored, truth, self.bits, align=self.align)

    def extra_repr(self) -> str:
        return f"bits={self.bits}, align={self.align}"


# --------------------------------------------------------------------------------------------------------------------
# PSNR
# --------------------------------------------------------------------------------------------------------------------


def _psnr_bchw(x: torch.Tensor, y: torch.Tensor, peak: torch.Tensor | float) -> torch.Tensor:
    """``10 log10(peak^2 / MSE)`` per batch item of two ``(B, C, H, W)`` float tensors; +inf where they match."""
    mse = (x - y).square().flatten(1).mean(dim=1)
    if not isinstance(peak, torch.Tensor):
        peak = torch.tensor(peak, dtype=x.dtype, device=x.device)
    return 10.0 * torch.log10(peak.square() / mse)


def psnr(x: torch.Tensor, y: torch.Tensor, peak: float) -> torch.Tensor:
    """Peak signal-to-noise ratio per batch item, over all channels: ``10 log10(peak^2 / MSE)`` in dB.

    The benchmark scores restored counts against the true counts with ``peak = 2^12 - 1 = 4095`` (protocol A).
    The metric is symmetric in ``x`` and ``y``; identical images give ``+inf``.

    Args:
        x: an image, ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        y: the reference, same shape.
        peak: the largest possible value (the data range), a positive number.

    Returns:
        ``(B,)`` PSNR in dB, in the floating dtype of the inputs; ``(1,)`` for unbatched inputs.

    Raises:
        TypeError: an input is not a real tensor, or ``peak`` is not a number.
        ValueError: shapes differ, a value is NaN or infinite, an image is empty, or ``peak`` is not positive.

    Example:
        >>> x = torch.tensor([[0.0, 2.0], [0.0, 0.0]])
        >>> psnr(x, torch.zeros(2, 2), peak=1.0)  # MSE = 4 / 4 = 1: 10 log10(1 / 1)
        tensor([0.])
        >>> psnr(x, x, peak=1.0)
        tensor([inf])
    """
    xb, yb = _pair(x, y, ("x", "y"))
    peak = _positive_float(peak, "peak")
    check_finite(xb, "x")
    check_finite(yb, "y")
    if xb.shape[0] and xb[0].numel() == 0:
        raise ValueError(f"x and y must have at least one value per image; got shape {tuple(x.shape)}")
    xb, yb = _float_pair(xb, yb)
    return _psnr_bchw(xb, yb, peak)


class PSNR(nn.Module):
    """Module twin of :func:`psnr`.

    Shape:
        - x, y: ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        - Output: ``(B,)``.

    Example:
        >>> PSNR(peak=10.0)(torch.ones(1, 1, 2, 2), torch.zeros(1, 1, 2, 2))
        tensor([20.])
    """

    def __init__(self, peak: float) -> None:
        super().__init__()
        self.peak = _positive_float(peak, "peak")

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return psnr(x, y, self.peak)

    def extra_repr(self) -> str:
        return f"peak={self.peak}"


# --------------------------------------------------------------------------------------------------------------------
# PSNR on log radiance
# --------------------------------------------------------------------------------------------------------------------


def _reference_peak(y: torch.Tensor) -> torch.Tensor:
    """Per-item maximum of a ``(B, C, H, W)`` reference as ``(B, 1, 1, 1)``; 1 where the reference is all zero."""
    m = y.flatten(1).amax(dim=1) if y.shape[0] else y.new_zeros(0)
    return torch.where(m > 0, m, torch.ones_like(m)).view(-1, 1, 1, 1)


def _log_relative(z: torch.Tensor, m: torch.Tensor, eps: float) -> torch.Tensor:
    """``log2(z / m + eps)``: log radiance in stops relative to the reference peak ``m``, floored by ``eps``."""
    return torch.log2(z / m + eps)


def _check_eps(eps: object) -> float:
    eps = _positive_float(eps, "eps")
    if eps >= 1:
        raise ValueError(f"eps must be in (0, 1); got {eps}")
    return eps


def _nonnegative_pair(x: object, y: object) -> tuple[torch.Tensor, torch.Tensor]:
    xb, yb = _pair(x, y, ("x", "y"))
    check_nonnegative(xb, "x")
    check_nonnegative(yb, "y")
    if xb.shape[0] and xb[0].numel() == 0:
        raise ValueError(f"x and y must have at least one value per image; got shape {tuple(xb.shape[1:])}")
    return _float_pair(xb, yb)


def psnr_log(x: torch.Tensor, y: torch.Tensor, eps: float = 2.0**-16) -> torch.Tensor:
    """PSNR on log radiance, in stops relative to the reference's peak.

    With ``m`` the largest value of the reference ``y`` in each batch item (1 if the reference is all zero), both
    images are mapped to ``v(z) = log2(z / m + eps)``. The reference then spans at most
    ``[log2(eps), log2(1 + eps)]``, and that span is the peak: ``peak = log2((1 + eps) / eps)`` (about 16 stops for
    the default ``eps = 2^-16``, which floors values more than 16 stops below the reference's peak). The score is
    ``10 log10(peak^2 / MSE(v(x), v(y)))`` over all channels. It is invariant to a common scale of ``x`` and ``y``,
    so radiance in any linear unit (counts per unit exposure, relative radiance) gives the same number. Not
    symmetric: ``y`` is the reference.

    Args:
        x: the estimate, linear radiance ``>= 0``, ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        y: the reference, same shape.
        eps: floor relative to the reference's peak, in ``(0, 1)``.

    Returns:
        ``(B,)`` PSNR in dB; ``+inf`` where the images are equal.

    Raises:
        TypeError: an input is not a real tensor, or ``eps`` is not a number.
        ValueError: shapes differ, a value is NaN, infinite or negative, an image is empty, or ``eps`` is not in
            ``(0, 1)``.

    Example:
        >>> y = torch.tensor([[1.0, 4.0], [16.0, 64.0]])
        >>> round(float(psnr_log(2 * y, y, eps=2.0**-16)[0]), 2)  # every value about one stop off, of 16
        24.08
    """
    eps = _check_eps(eps)
    xb, yb = _nonnegative_pair(x, y)
    m = _reference_peak(yb)
    peak = math.log2((1 + eps) / eps)
    return _psnr_bchw(_log_relative(xb, m, eps), _log_relative(yb, m, eps), peak)


class PSNRLog(nn.Module):
    """Module twin of :func:`psnr_log`.

    Shape:
        - x, y: ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        - Output: ``(B,)``.

    Example:
        >>> PSNRLog()(torch.ones(1, 1, 2, 2), torch.ones(1, 1, 2, 2))
        tensor([inf])
    """

    def __init__(self, eps: float = 2.0**-16) -> None:
        super().__init__()
        self.eps = _check_eps(eps)

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return psnr_log(x, y, self.eps)

    def extra_repr(self) -> str:
        return f"eps={self.eps}"


# --------------------------------------------------------------------------------------------------------------------
# PU21
# --------------------------------------------------------------------------------------------------------------------

#: Published PU21 parameters ``p1 .. p7`` (Mantiuk and Azimi 2021; the values of the authors' reference encoder).
#: ``banding_glare`` is the variant the authors recommend and the default here.
PU21_PARAMETERS: dict[str, tuple[float, ...]] = {
    "banding": (1.070275272, 0.4088273932, 0.153224308, 0.2520326168, 1.063512885, 1.14115047, 521.4527484),
    "banding_glare": (
        0.353487901,
        0.3734658629,
        8.277049286e-05,
        0.9062562627,
        0.09150303166,
        0.9099517204,
        596.3148142,
    ),
}

#: Luminance range of PU21, in cd/m^2; values outside are clamped to it (as the reference encoder does).
PU21_LUMINANCE_RANGE: tuple[float, float] = (0.005, 10000.0)


def _check_variant(variant: object) -> str:
    if not isinstance(variant, str):
        raise TypeError(f"variant must be a string; got {variant!r}")
    if variant not in PU21_PARAMETERS:
        raise ValueError(f"variant must be one of {sorted(PU21_PARAMETERS)}; got {variant!r}")
    return variant


def _pu21(y: torch.Tensor, variant: str) -> torch.Tensor:
    p1, p2, p3, p4, p5, p6, p7 = PU21_PARAMETERS[variant]
    yp = y.clamp(*PU21_LUMINANCE_RANGE).pow(p4)
    return (p7 * (((p1 + p2 * yp) / (1 + p3 * yp)).pow(p5) - p6)).clamp_min(0.0)


def pu21_encode(luminance: torch.Tensor, variant: str = "banding_glare") -> torch.Tensor:
    r"""PU21 perceptually uniform encoding of absolute luminance.

    From R. K. Mantiuk and M. Azimi, "PU21: A novel perceptually uniform encoding for adapting existing quality
    metrics for HDR", Picture Coding Symposium 2021:

    .. math::
        V = \max\left(p_7 \left[\left(\frac{p_1 + p_2 Y^{p_4}}{1 + p_3 Y^{p_4}}\right)^{p_5} - p_6\right], 0\right)

    with ``Y`` clamped to ``[0.005, 10000]`` cd/m^2 and the parameters ``p1 .. p7`` of :data:`PU21_PARAMETERS`
    (default variant ``"banding_glare"``, the one the authors recommend; ``"banding"`` is also available). ``V`` runs
    from 0 to about 600, with 100 cd/m^2 near 256, so that SDR metrics can be applied with a peak of 256.

    Args:
        luminance: absolute luminance (or one colour channel's linear value) in cd/m^2, ``>= 0``, any shape.
        variant: ``"banding_glare"`` (default) or ``"banding"``.

    Returns:
        The encoded values, same shape, device and dtype (float32 for integer inputs).

    Raises:
        TypeError: ``luminance`` is not a real tensor, or ``variant`` is not a string.
        ValueError: a value is NaN, infinite or negative, or ``variant`` is unknown.

    Example:
        >>> pu21_encode(torch.tensor([0.005, 100.0, 10000.0])).round(decimals=1)
        tensor([  0.0000, 256.4000, 595.4000])
    """
    check_tensor(luminance, "luminance")
    if luminance.dtype == torch.bool or luminance.is_complex():
        raise TypeError(f"luminance must hold real numbers; got dtype {luminance.dtype}")
    variant = _check_variant(variant)
    check_nonnegative(luminance, "luminance")
    if not luminance.is_floating_point():
        luminance = luminance.to(torch.get_default_dtype())
    return _pu21(luminance, variant)


class PU21Encode(nn.Module):
    """Module twin of :func:`pu21_encode`.

    Shape:
        - Input: any shape, absolute luminance in cd/m^2.
        - Output: same shape.

    Example:
        >>> PU21Encode(variant="banding")(torch.tensor([100.0])).round(decimals=1)
        tensor([261.8000])
    """

    def __init__(self, variant: str = "banding_glare") -> None:
        super().__init__()
        self.variant = _check_variant(variant)

    def forward(self, luminance: torch.Tensor) -> torch.Tensor:
        return pu21_encode(luminance, self.variant)

    def extra_repr(self) -> str:
        return f"variant={self.variant!r}"


def _check_peak_luminance(value: object) -> float | None:
    return None if value is None else _positive_float(value, "peak_luminance")


def psnr_pu21(
    x: torch.Tensor,
    y: torch.Tensor,
    peak_luminance: float | None = 4000.0,
    *,
    variant: str = "banding_glare",
    peak: float = 256.0,
) -> torch.Tensor:
    """PU21-PSNR: PSNR on PU21-encoded values (Mantiuk and Azimi 2021), as the authors' ``pu21_metric(.., 'PSNR')``.

    Relative radiance is mapped to absolute luminance the way the PU21 examples do: both images of a batch item are
    multiplied by ``peak_luminance / max(y)``, so the reference's brightest value lands on a display peak of
    ``peak_luminance`` cd/m^2 (default 4000, an HDR display; an all-zero reference uses a factor of
    ``peak_luminance``). With ``peak_luminance=None`` the inputs are taken as absolute cd/m^2 already. Each colour
    channel is encoded as luminance by :func:`pu21_encode` (values leave ``[0.005, 10000]`` clamped), and the score
    is ``10 log10(peak^2 / MSE)`` over all channels with ``peak = 256`` as in the authors' code. ``y`` is the
    reference.

    Args:
        x: the estimate, linear and ``>= 0``, ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        y: the reference, same shape.
        peak_luminance: display peak in cd/m^2 for the reference's maximum, or ``None`` for absolute inputs.
        variant: PU21 parameter set, ``"banding_glare"`` (default) or ``"banding"``.
        peak: PSNR peak in PU21 units.

    Returns:
        ``(B,)`` PSNR in dB; ``+inf`` where the encoded images are equal.

    Raises:
        TypeError: an input is not a real tensor, or an option has the wrong type.
        ValueError: shapes differ, a value is NaN, infinite or negative, an image is empty, or an option is out of
            range.

    Example:
        >>> y = torch.tensor([[1.0, 0.5], [0.25, 0.125]])
        >>> float(psnr_pu21(y, y)[0])
        inf
        >>> bool(psnr_pu21(1.1 * y, y)[0] > psnr_pu21(1.5 * y, y)[0])
        True
    """
    peak_luminance = _check_peak_luminance(peak_luminance)
    variant = _check_variant(variant)
    peak = _positive_float(peak, "peak")
    xb, yb = _nonnegative_pair(x, y)
    if peak_luminance is not None:
        scale = peak_luminance / _reference_peak(yb)
        xb, yb = xb * scale, yb * scale
    return _psnr_bchw(_pu21(xb, variant), _pu21(yb, variant), peak)


class PSNRPU21(nn.Module):
    """Module twin of :func:`psnr_pu21`.

    Shape:
        - x, y: ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        - Output: ``(B,)``.

    Example:
        >>> PSNRPU21(peak_luminance=None)(torch.full((1, 3, 2, 2), 50.0), torch.full((1, 3, 2, 2), 50.0))
        tensor([inf])
    """

    def __init__(
        self, peak_luminance: float | None = 4000.0, *, variant: str = "banding_glare", peak: float = 256.0
    ) -> None:
        super().__init__()
        self.peak_luminance = _check_peak_luminance(peak_luminance)
        self.variant = _check_variant(variant)
        self.peak = _positive_float(peak, "peak")

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return psnr_pu21(x, y, self.peak_luminance, variant=self.variant, peak=self.peak)

    def extra_repr(self) -> str:
        return f"peak_luminance={self.peak_luminance}, variant={self.variant!r}, peak={self.peak}"


# --------------------------------------------------------------------------------------------------------------------
# SSIM on tone-mapped images
# --------------------------------------------------------------------------------------------------------------------


def log_relative_tonemap(hdr: torch.Tensor, reference: torch.Tensor, eps: float = 2.0**-16) -> torch.Tensor:
    """The default tone map of :func:`ssim_tonemapped`: log radiance normalised by the reference's range.

    ``t(z) = clamp((log2(z / m + eps) - log2(eps)) / log2((1 + eps) / eps), 0, 1)`` with ``m`` the largest value of
    the reference in each batch item (1 if it is all zero): the same log coordinates as :func:`psnr_log`, scaled so
    that the reference spans ``[0, 1]`` (its peak maps to 1, values ``eps`` or more below it to about 0). Global,
    deterministic and monotonic; both images use the reference's ``m`` so their tone maps are the same curve.

    Args:
        hdr: linear radiance ``>= 0``, ``(B, C, H, W)``.
        reference: the reference image whose peak sets the curve, ``(B, C, H, W)``.
        eps: floor relative to the reference's peak, in ``(0, 1)``.

    Returns:
        ``hdr`` tone-mapped into ``[0, 1]``, same shape.

    Example:
        >>> ref = torch.tensor([[[[1.0, 2.0**-8, 2.0**-16]]]])
        >>> log_relative_tonemap(ref, ref, eps=2.0**-16).round(decimals=2)
        tensor([[[[1.0000, 0.5000, 0.0600]]]])
    """
    eps = _check_eps(eps)
    m = _reference_peak(reference)
    lo = math.log2(eps)
    span = math.log2((1 + eps) / eps)
    return ((_log_relative(hdr, m, eps) - lo) / span).clamp(0.0, 1.0)


def _check_window(window_size: object) -> int:
    if isinstance(window_size, bool) or not isinstance(window_size, int):
        raise TypeError(f"window_size must be an odd positive integer; got {window_size!r}")
    if window_size < 1 or window_size % 2 == 0:
        raise ValueError(f"window_size must be an odd positive integer; got {window_size}")
    return window_size


def _check_tonemap(tonemap: object) -> Callable[[torch.Tensor], torch.Tensor] | None:
    if tonemap is not None and not callable(tonemap):
        raise TypeError(f"tonemap must be callable or None; got {tonemap!r}")
    return tonemap


def ssim_tonemapped(
    x: torch.Tensor,
    y: torch.Tensor,
    tonemap: Callable[[torch.Tensor], torch.Tensor] | None = None,
    window_size: int = 11,
) -> torch.Tensor:
    """Mean SSIM per batch item of two tone-mapped HDR images (Kornia's Gaussian-window SSIM).

    Both images are tone-mapped, then ``kornia.metrics.ssim`` (Gaussian window, sigma 1.5, ``'same'`` reflect
    padding, data range 1, no denominator ``eps`` so identical images score exactly 1) gives a per-pixel map that is
    averaged over channels and pixels.

    Args:
        x: the estimate, linear radiance ``>= 0``, ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        y: the reference, same shape.
        tonemap: a function mapping a ``(B, C, H, W)`` HDR tensor to the same shape in ``[0, 1]``, applied to each
            image separately (e.g. a tone map of :mod:`torch_modulo.tonemap`). ``None`` uses
            :func:`log_relative_tonemap` with the reference's peak for both images.
        window_size: odd Gaussian window size; ``H`` and ``W`` must exceed ``window_size // 2``.

    Returns:
        ``(B,)`` mean SSIM, at most 1.

    Raises:
        TypeError: an input is not a real tensor, ``tonemap`` is not callable or ``window_size`` not an integer.
        ValueError: shapes differ, a value is NaN, infinite or negative, the image is smaller than the window
            needs, ``window_size`` is not odd and positive, or the tone map returns a wrong shape or NaN.

    Example:
        >>> y = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(0)) * 1000
        >>> ssim_tonemapped(y, y).round(decimals=4)
        tensor([1.])
    """
    tonemap = _check_tonemap(tonemap)
    window_size = _check_window(window_size)
    xb, yb = _nonnegative_pair(x, y)
    h, w = xb.shape[-2:]
    if min(h, w) <= window_size // 2:
        raise ValueError(
            f"images must be larger than window_size // 2 = {window_size // 2} in H and W; got {tuple(xb.shape)}"
        )
    if tonemap is None:
        tx, ty = log_relative_tonemap(xb, yb), log_relative_tonemap(yb, yb)
    else:
        tx, ty = tonemap(xb), tonemap(yb)
        for name, t in (("tonemap(x)", tx), ("tonemap(y)", ty)):
            check_tensor(t, name)
            if t.shape != xb.shape:
                raise ValueError(f"{name} must keep the shape {tuple(xb.shape)}; got {tuple(t.shape)}")
            check_finite(t, name)
    if xb.shape[0] == 0:
        return xb.new_zeros(0)
    ssim_map = kornia.metrics.ssim(tx, ty, window_size, max_val=1.0, eps=0.0)
    return ssim_map.flatten(1).mean(dim=1).to(xb.dtype)


class SSIMToneMapped(nn.Module):
    """Module twin of :func:`ssim_tonemapped`.

    Shape:
        - x, y: ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``.
        - Output: ``(B,)``.

    Example:
        >>> SSIMToneMapped(window_size=3)(torch.ones(1, 1, 4, 4), torch.ones(1, 1, 4, 4))
        tensor([1.])
    """

    def __init__(self, tonemap: Callable[[torch.Tensor], torch.Tensor] | None = None, window_size: int = 11) -> None:
        super().__init__()
        self.tonemap = _check_tonemap(tonemap)
        self.window_size = _check_window(window_size)

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return ssim_tonemapped(x, y, self.tonemap, self.window_size)

    def extra_repr(self) -> str:
        return f"tonemap={self.tonemap!r}, window_size={self.window_size}"
