"""PU21 perceptually uniform encoding (Mantiuk and Azimi, 2021) and PSNR on it."""

from __future__ import annotations

import torch
from torch import nn

from torch_modulo._checks import check_choice, check_nonnegative, check_real, check_tensor
from torch_modulo.metrics._common import POSITIVE, nonnegative_pair, psnr_bchw, reference_peak

__all__ = ["PSNRPU21", "PU21_LUMINANCE_RANGE", "PU21_PARAMETERS", "PU21Encode", "psnr_pu21", "pu21_encode"]


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
    return check_choice(variant, "variant", PU21_PARAMETERS)


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
    return None if value is None else check_real(value, "peak_luminance", positive=True, what=POSITIVE)


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
    peak = check_real(peak, "peak", positive=True, what=POSITIVE)
    xb, yb = nonnegative_pair(x, y)
    if peak_luminance is not None:
        scale = peak_luminance / reference_peak(yb)
        xb, yb = xb * scale, yb * scale
    return psnr_bchw(_pu21(xb, variant), _pu21(yb, variant), peak)


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
        self.peak = check_real(peak, "peak", positive=True, what=POSITIVE)

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        return psnr_pu21(x, y, self.peak_luminance, variant=self.variant, peak=self.peak)

    def extra_repr(self) -> str:
        return f"peak_luminance={self.peak_luminance}, variant={self.variant!r}, peak={self.peak}"
