"""Capture models: Eq. 1 of the paper and the quantised modulo and intensity (conventional) sensors.

A noise-free sensor with exposure ``tau`` reads the counts ``I = floor(tau * E)`` of the radiance ``E``. A
modulo sensor keeps the low ``bits`` bits, ``I_m = mod(I, 2**bits)`` (Eq. 1); a conventional ("intensity")
sensor clips at ``2**bits - 1``.

Gradients:
    - :func:`modulo_wrap` passes gradients through unchanged: ``d mod(x, P) / dx = 1`` almost everywhere.
    - :func:`capture_modulo` and :func:`capture_intensity` contain ``floor``, whose true derivative is 0
      almost everywhere, so by default no gradient reaches the radiance. With ``straight_through=True`` the
      floor is treated as the identity in the backward pass (a straight-through estimator), so
      ``d I_m / d E = tau`` (and 0 where the intensity sensor clips), which is what training pipelines that
      learn through the sensor usually want.

Speed:
    Without autograd the outputs are computed in place in a single freshly allocated buffer with cheap
    floating-point operations (``x - P * floor(x / P)`` instead of ``torch.remainder``), which keeps these
    layers close to the cost of ``tensor.clone()`` (see ``scripts/bench_elementwise.py``).
"""

from __future__ import annotations

import torch
from torch import nn

from torch_modulo._checks import (
    check_bits,
    check_finite,
    check_floating,
    check_nonnegative,
    exposure_tensor,
)

__all__ = [
    "IntensityCapture",
    "ModuloCapture",
    "ModuloWrap",
    "capture_intensity",
    "capture_modulo",
    "modulo_wrap",
]


def _needs_grad(*tensors: torch.Tensor) -> bool:
    return torch.is_grad_enabled() and any(t.requires_grad for t in tensors)


#: Elements per tile for in-place CPU kernels: small enough that a scratch tile stays in cache.
CPU_TILE = 1 << 18


def _wrap_inplace(y: torch.Tensor, period: float) -> torch.Tensor:
    """``y <- y - period * floor(y / period)`` in place; exact for integer-valued ``y``.

    ``period`` is a power of two, so ``y / period`` and the product are exact; the subtraction of two
    multiples of ``ulp(y)`` is exact too. On the CPU the quotient goes through one cache-sized scratch tile
    (allocating and faulting in a full-size temporary costs more than the arithmetic).
    """
    if y.device.type != "cpu" or not y.is_contiguous() or y.numel() <= CPU_TILE:
        q = torch.mul(y, 1.0 / period).floor_()
        return y.sub_(q, alpha=period)
    flat = y.view(-1)
    scratch = torch.empty(CPU_TILE, dtype=y.dtype)
    for start in range(0, flat.numel(), CPU_TILE):
        tile = flat[start : start + CPU_TILE]
        q = scratch[: tile.numel()]
        torch.mul(tile, 1.0 / period, out=q).floor_()
        tile.sub_(q, alpha=period)
    return y


def _broadcast_exposure(tau: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Shape an exposure for broadcasting against ``x``: a scalar, or one value per batch item."""
    if tau.dim() == 0:
        return tau
    if x.dim() == 4 and tau.dim() == 1 and tau.shape[0] == x.shape[0]:
        return tau.view(-1, 1, 1, 1)
    if tau.numel() == 1:
        return tau.reshape(())
    try:
        torch.broadcast_shapes(tau.shape, x.shape)
    except RuntimeError:
        raise ValueError(
            f"exposure of shape {tuple(tau.shape)} does not broadcast against radiance of shape {tuple(x.shape)}"
            " (give a float, one value per batch item (B,), or a broadcastable tensor)"
        ) from None
    return tau


def modulo_wrap(counts: torch.Tensor, bits: int = 8) -> torch.Tensor:
    r"""Wrap counts into ``[0, 2**bits)``: Eq. 1, :math:`I_m = \mathrm{mod}(I, 2^N)`.

    Any finite real input is accepted (negative values wrap like Python's ``%``); the result is always in
    ``[0, 2**bits)``. Gradients pass through unchanged (derivative 1 almost everywhere).

    Args:
        counts: floating tensor of any shape.
        bits: the counter's bit depth ``N``, 1 to 24 in float32 (53 in float64).

    Returns:
        Tensor of the same shape, dtype and device as ``counts``.

    Example:
        >>> modulo_wrap(torch.tensor([0.0, 255.0, 256.0, 1000.0]), bits=8)
        tensor([  0., 255.,   0., 232.])
    """
    check_floating(counts, "counts")
    bits = check_bits(bits, counts.dtype)
    check_finite(counts, "counts")
    period = float(2**bits)
    if _needs_grad(counts):
        out = counts - period * torch.floor(counts / period).detach()
    else:
        out = _wrap_inplace(counts.clone(), period)
    # Tiny negative non-integers can round up to exactly ``period``; keep the result in [0, period).
    if out.numel() and float(out.detach().max()) >= period:
        out = torch.where(out >= period, out - period, out)
    return out


def _counts(
    radiance: torch.Tensor, exposure: float | torch.Tensor, bits: int, straight_through: bool
) -> tuple[torch.Tensor, int]:
    """Validate and return ``floor(exposure * radiance)`` (with the chosen gradient) and ``bits``."""
    check_floating(radiance, "radiance")
    bits = check_bits(bits, radiance.dtype)
    check_nonnegative(radiance, "radiance")
    tau = _broadcast_exposure(exposure_tensor(exposure, radiance), radiance)
    if _needs_grad(radiance, tau):
        y = radiance * tau
        floored = torch.floor(y)
        if straight_through:
            floored = y + (floored - y).detach()
        return floored, bits
    y = torch.mul(radiance, tau)
    return y.floor_(), bits


def capture_modulo(
    radiance: torch.Tensor,
    exposure: float | torch.Tensor = 1.0,
    bits: int = 8,
    *,
    straight_through: bool = False,
) -> torch.Tensor:
    r"""Noise-free modulo sensor: :math:`I_m = \mathrm{mod}(\lfloor \tau E \rfloor, 2^N)`.

    Args:
        radiance: non-negative radiance ``E`` in counts per unit exposure, any shape; images are (B, C, H, W).
        exposure: ``tau`` > 0: a float, one value per batch item (a (B,) tensor for (B, C, H, W) input), or a
            tensor that broadcasts against ``radiance``.
        bits: counter bit depth ``N``, 1 to 24 in float32 (53 in float64).
        straight_through: if True, gradients flow as if ``floor`` were the identity
            (``d I_m / d E = tau``); by default floor's true zero gradient is kept.

    Returns:
        Modulus image of integers in ``[0, 2**bits)``, same shape, dtype and device as ``radiance``. Counts
        above ``2**24`` are not exact in float32: use float64 radiance for them.

    Example:
        >>> capture_modulo(torch.tensor([0.5, 100.0, 300.0]), exposure=2.0, bits=8)
        tensor([  1., 200.,  88.])
    """
    counts, bits = _counts(radiance, exposure, bits, straight_through)
    period = float(2**bits)
    if counts.requires_grad:
        return counts - period * torch.floor(counts / period).detach()
    return _wrap_inplace(counts, period)


def capture_intensity(
    radiance: torch.Tensor,
    exposure: float | torch.Tensor = 1.0,
    bits: int = 8,
    *,
    straight_through: bool = False,
) -> torch.Tensor:
    r"""Noise-free conventional sensor: :math:`I = \min(\lfloor \tau E \rfloor, 2^N - 1)`.

    Arguments as for :func:`capture_modulo`. With ``straight_through=True`` the gradient is ``tau`` below
    saturation and 0 where the sensor clips.

    Example:
        >>> capture_intensity(torch.tensor([0.5, 100.0, 300.0]), exposure=2.0, bits=8)
        tensor([  1., 200., 255.])
    """
    counts, bits = _counts(radiance, exposure, bits, straight_through)
    top = float(2**bits - 1)
    if counts.requires_grad:
        return torch.clamp(counts, max=top)
    return counts.clamp_(max=top)


class ModuloWrap(nn.Module):
    """Module twin of :func:`modulo_wrap` (Eq. 1).

    Args:
        bits: counter bit depth ``N``.

    Shape:
        - Input: any shape.
        - Output: same as input.

    Example:
        >>> ModuloWrap(bits=4)(torch.tensor([15.0, 16.0, 17.0]))
        tensor([15.,  0.,  1.])
    """

    def __init__(self, bits: int = 8) -> None:
        super().__init__()
        self.bits = check_bits(bits, torch.float64)

    def forward(self, counts: torch.Tensor) -> torch.Tensor:
        return modulo_wrap(counts, self.bits)

    def extra_repr(self) -> str:
        return f"bits={self.bits}"


class _Capture(nn.Module):
    def __init__(self, exposure: float | torch.Tensor = 1.0, bits: int = 8, straight_through: bool = False) -> None:
        super().__init__()
        self.bits = check_bits(bits, torch.float64)
        self.straight_through = bool(straight_through)
        tau = exposure_tensor(exposure, torch.empty((), dtype=torch.float64))
        self.register_buffer("exposure", tau, persistent=False)

    def extra_repr(self) -> str:
        tau = self.exposure.tolist()
        return f"exposure={tau}, bits={self.bits}, straight_through={self.straight_through}"


class ModuloCapture(_Capture):
    """Module twin of :func:`capture_modulo`: a noise-free modulo sensor with a fixed exposure.

    The exposure is a buffer, so ``.to(device)`` moves it.

    Shape:
        - Input: (B, C, H, W) radiance (any shape works).
        - Output: same as input.

    Example:
        >>> ModuloCapture(exposure=4.0, bits=8)(torch.tensor([[[[70.0]]]]))
        tensor([[[[24.]]]])
    """

    def forward(self, radiance: torch.Tensor) -> torch.Tensor:
        return capture_modulo(radiance, self.exposure, self.bits, straight_through=self.straight_through)


class IntensityCapture(_Capture):
    """Module twin of :func:`capture_intensity`: a noise-free conventional (clipping) sensor.

    Example:
        >>> IntensityCapture(exposure=4.0, bits=8)(torch.tensor([[[[70.0]]]]))
        tensor([[[[255.]]]])
    """

    def forward(self, radiance: torch.Tensor) -> torch.Tensor:
        return capture_intensity(radiance, self.exposure, self.bits, straight_through=self.straight_through)
