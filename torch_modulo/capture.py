"""Capture models: Eq. 1 of the paper and the quantised modulo and intensity (conventional) sensors.

:func:`capture_stack` and :class:`MultiExposureCapture` take one radiance at several exposures. The function
returns a plain tensor, the (B, M, C, H, W) stack of modulus images that :func:`~torch_modulo.unwrap_multi`
decodes; the layer returns it with its exposures as an :class:`ExposureStack`, which
:class:`~torch_modulo.MultiExposureUnwrap` takes as its one input, so
``nn.Sequential(MultiExposureCapture(...), MultiExposureUnwrap(...))`` chains. A sensor returns the third form,
a :class:`~torch_modulo.sensors.FrameStack`, which adds the bit depth, the kind of sensor, the colour filter array
and metadata; ``FrameStack(*exposure_stack, bits=N)`` and
:meth:`~torch_modulo.sensors.FrameStack.to_exposure_stack` convert between the two.

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

Precision:
    Counts are held in the radiance's dtype, which holds integers exactly only up to ``2**24`` in float32
    (``2**11`` in float16, ``2**8`` in bfloat16): :func:`capture_modulo` warns when the counts go beyond that,
    because their low bits, the ones a modulo sensor keeps, are then lost. Use float64 radiance for such counts.

Speed:
    Without autograd the outputs are computed in place in a single freshly allocated buffer with cheap
    floating-point operations (``x - P * floor(x / P)`` instead of ``torch.remainder``); on the CPU the work runs
    chunk by chunk through cache-sized buffers (:mod:`torch_modulo._chunks`), so these layers cost about as much as
    ``tensor.clone()``.

Compilation:
    Under ``torch.compile`` the layers use whole-tensor operations with the same arithmetic (no CPU chunks), and
    with :func:`torch_modulo.validation` off they hold no data-dependent branch, so
    ``torch.compile(layer, fullgraph=True)`` traces them in one graph. The compiled output equals the eager one.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from typing import NamedTuple, Self

import torch
from torch import nn

from torch_modulo._checks import (
    MAX_BITS,
    check_bits,
    check_finite,
    check_flag,
    check_floating,
    check_image_shape,
    exposure_tensor,
    nonnegative_max,
    validation_enabled,
)
from torch_modulo._chunks import column_chunks

__all__ = [
    "ExposureStack",
    "IntensityCapture",
    "ModuloCapture",
    "ModuloWrap",
    "MultiExposureCapture",
    "capture_intensity",
    "capture_modulo",
    "capture_stack",
    "modulo_wrap",
]


def _needs_grad(*tensors: torch.Tensor) -> bool:
    return torch.is_grad_enabled() and any(t.requires_grad for t in tensors)


def _compiling() -> bool:
    """Whether ``torch.compile`` is tracing: take whole-tensor operations instead of the chunked CPU loops."""
    return torch.compiler.is_compiling()


def _wrap(y: torch.Tensor, period: float) -> torch.Tensor:
    """``y - period * floor(y / period)`` out of place: the arithmetic of :func:`_wrap_rows_`."""
    return y - period * torch.floor(y * (1.0 / period))


def _wrap_rows_(y: torch.Tensor, period: float, scratch: torch.Tensor) -> torch.Tensor:
    """``y <- y - period * floor(y / period)`` in place; exact for integer-valued ``y``.

    ``period`` is a power of two, so ``y / period`` and the product are exact, and the difference of two multiples
    of ``ulp(y)`` is exact too.
    """
    torch.mul(y, 1.0 / period, out=scratch).floor_()
    return y.sub_(scratch, alpha=period)


def _as_rows(x: torch.Tensor, tau: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | float] | None:
    """View ``x`` as (rows, n) with one exposure per row, or None when the layout does not allow it."""
    if not x.is_contiguous():
        return None
    if tau.dim() == 0:
        return x.view(1, -1), float(tau)
    if x.dim() >= 1 and tau.numel() == x.shape[0] and tau.shape == (x.shape[0],) + (1,) * (x.dim() - 1):
        return x.view(x.shape[0], math.prod(x.shape[1:])), tau.reshape(-1, 1)  # not -1: an empty batch has 0 rows
    return None


def _elementwise_(
    x: torch.Tensor, tau: torch.Tensor | float, period: float, *, floor: bool, clip_top: float | None
) -> torch.Tensor:
    """``wrap(floor(tau * x))`` (or clip instead of wrap) without autograd, chunk by chunk in cache on the CPU."""
    if _compiling():
        y = x * tau
        if floor:
            y = torch.floor(y)
        return y.clamp(max=clip_top) if clip_top is not None else _wrap(y, period)
    tau_t = tau if isinstance(tau, torch.Tensor) else torch.tensor(tau, dtype=x.dtype, device=x.device)
    rows = _as_rows(x, tau_t) if x.device.type == "cpu" else None
    if rows is None:
        y = torch.mul(x, tau)
        if floor:
            y.floor_()
        return y.clamp_(max=clip_top) if clip_top is not None else _wrap_rows_(y, period, torch.empty_like(y))
    flat, t = rows
    out = torch.empty_like(flat)
    chunks = column_chunks(flat.shape[1], flat.shape[0])
    scratch = torch.empty((flat.shape[0], chunks[0].stop - chunks[0].start if chunks else 0), dtype=x.dtype)
    for cols in chunks:
        o = out[:, cols]
        torch.mul(flat[:, cols], t, out=o)
        if floor:
            o.floor_()
        if clip_top is not None:
            o.clamp_(max=clip_top)
        else:
            _wrap_rows_(o, period, scratch[:, : o.shape[1]])
    return out.view(x.shape)


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
        out = _elementwise_(counts, 1.0, period, floor=False, clip_top=None)
    # Tiny negative non-integers can round up to exactly ``period``; keep the result in [0, period).
    if _compiling() or out.device.type == "meta":  # no value to read: the same result without the test
        out = torch.where(out >= period, out - period, out)
    elif out.numel() and float(out.detach().max()) >= period:
        out = torch.where(out >= period, out - period, out)
    return out


def _capture(
    radiance: torch.Tensor, exposure: float | torch.Tensor, bits: int, straight_through: bool, clip: bool
) -> torch.Tensor:
    """Validate, then ``floor(exposure * radiance)`` wrapped (or clipped) with the chosen gradient."""
    check_floating(radiance, "radiance")
    bits = check_bits(bits, radiance.dtype)
    straight_through = check_flag(straight_through, "straight_through")
    tau = _broadcast_exposure(exposure_tensor(exposure, radiance), radiance)
    if validation_enabled():
        peak = nonnegative_max(radiance, "radiance")
        if not clip:
            _warn_inexact_counts(peak, tau, radiance.dtype)
    period = float(2**bits)
    if not _needs_grad(radiance, tau):
        return _elementwise_(radiance, tau, period, floor=True, clip_top=period - 1 if clip else None)
    return _counts_autograd(radiance * tau, period, straight_through, clip)


def _counts_autograd(y: torch.Tensor, period: float, straight_through: bool, clip: bool) -> torch.Tensor:
    """``floor(y)`` wrapped (or clipped) with autograd: floor's zero gradient, or the straight-through one."""
    counts = torch.floor(y)
    if straight_through:
        counts = y + (counts - y).detach()
    if clip:
        return torch.clamp(counts, max=period - 1)
    return counts - period * torch.floor(counts / period).detach()


def _warn_inexact_counts(peak: float, tau: torch.Tensor, dtype: torch.dtype, stacklevel: int = 4) -> None:
    """Warn when the largest count ``floor(peak * max(tau))`` is beyond the integers ``dtype`` holds exactly; raise
    when it is beyond the dtype's range (float16 past 65504)."""
    limit = MAX_BITS.get(dtype)
    if limit is None or peak == 0.0 or not tau.numel():
        return
    top = peak * float(tau.detach().max())
    if top > torch.finfo(dtype).max:  # the product overflows: its modulus would be NaN, not merely inexact
        raise ValueError(
            f"counts reach {top:.6g}, beyond the largest {dtype} ({torch.finfo(dtype).max:.6g}): use float32 or "
            "float64 radiance"
        )
    if top >= 2.0**limit + 1:
        warnings.warn(
            f"counts reach {top:.0f}, beyond what {dtype} holds exactly (2**{limit} = {2**limit}): their low bits, "
            "which the modulo sensor keeps, are lost; use float64 radiance for exact counts",
            UserWarning,
            stacklevel=stacklevel,
        )


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
        Modulus image of integers in ``[0, 2**bits)``, same shape, dtype and device as ``radiance``.

    Raises:
        TypeError: ``radiance`` is not a floating tensor, ``bits`` not an integer or ``straight_through`` not a bool.
        ValueError: negative, NaN or infinite radiance, a bad exposure, more bits than the dtype holds, or counts
            beyond the dtype's range (float16: 65504).

    Warns:
        UserWarning: the counts go beyond the integers the dtype holds exactly (``2**24`` in float32), so their
        low bits are lost; float64 radiance keeps them.

    Example:
        >>> capture_modulo(torch.tensor([0.5, 100.0, 300.0]), exposure=2.0, bits=8)
        tensor([  1., 200.,  88.])
    """
    return _capture(radiance, exposure, bits, straight_through, clip=False)


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
    return _capture(radiance, exposure, bits, straight_through, clip=True)


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


class _ExactExposures(nn.Module):
    """Base of the capture layers: their float64 exposure buffers keep float64 through dtype casts.

    ``Module.half()``, ``.bfloat16()``, ``.float()`` and ``.to(dtype)`` convert every floating buffer. An exposure
    is a sensor setting, not a weight: converted, it changes the counts (1/3 becomes 0.33398 in bfloat16, 90000
    becomes inf in float16). :meth:`_apply` therefore restores the buffers named in :attr:`_exact_buffers` in
    their previous dtype, on the device the conversion chose, so ``.to(device)`` still moves them. The layers
    cast the exposure to the radiance's dtype when they use it, as the functions do.
    """

    #: Names of the buffers whose dtype survives ``Module`` conversions.
    _exact_buffers: tuple[str, ...] = ()

    def _apply(self, fn: Callable[[torch.Tensor], torch.Tensor], recurse: bool = True) -> Self:
        kept = {name: self._buffers.get(name) for name in self._exact_buffers}  # None once it is a Parameter
        super()._apply(fn, recurse)
        for name, old in kept.items():
            new = self._buffers.get(name)
            if old is not None and new is not None and new.dtype != old.dtype:
                self._buffers[name] = old.to(device=new.device)
        return self


class _Capture(_ExactExposures):
    _exact_buffers = ("exposure",)
    exposure: torch.Tensor

    def __init__(self, exposure: float | torch.Tensor = 1.0, bits: int = 8, straight_through: bool = False) -> None:
        super().__init__()
        self.bits = check_bits(bits, torch.float64)
        self.straight_through = check_flag(straight_through, "straight_through")
        tau = exposure_tensor(exposure, torch.empty((), dtype=torch.float64))
        self.register_buffer("exposure", tau, persistent=False)

    def extra_repr(self) -> str:
        tau = self.exposure.tolist()
        return f"exposure={tau}, bits={self.bits}, straight_through={self.straight_through}"


class ModuloCapture(_Capture):
    """Module twin of :func:`capture_modulo`: a noise-free modulo sensor with a fixed exposure.

    The exposure is a float64 buffer: ``.to(device)`` moves it, while dtype casts (``.half()``,
    ``.to(torch.bfloat16)``) leave it float64, so the layer's counts do not change.

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


class ExposureStack(NamedTuple):
    """Modulus images of one radiance taken at several exposures, with those exposures: the layers' form of a stack.

    What :class:`MultiExposureCapture` returns and :class:`~torch_modulo.MultiExposureUnwrap` takes as its one
    input. A named tuple, so it unpacks (``moduli, exposures = stack``), pickles, and batches in a ``DataLoader``
    (the default collate stacks both fields: (M, C, H, W) samples give (B, M, C, H, W) moduli and (B, M)
    exposures). The functions take its fields as tensors (``unwrap_multi(*stack, bits)``);
    ``FrameStack(*stack, bits=N)`` makes the sensors' form of it, which also records the bit depth, and
    :meth:`~torch_modulo.sensors.FrameStack.to_exposure_stack` gives it back.

    Example:
        >>> stack = MultiExposureCapture(exposures=[1.0, 8.0], bits=8)(torch.tensor([[[[3.0, 40.0]]]]))
        >>> stack.moduli[0, :, 0, 0]
        tensor([[ 3., 40.],
                [24., 64.]])
        >>> stack.exposures
        tensor([1., 8.], dtype=torch.float64)
    """

    #: (B, M, C, H, W) or (M, C, H, W) modulus images, integers in ``[0, 2**bits)``.
    moduli: torch.Tensor
    #: Exposure per frame: (M,) shared by the batch, or (B, M).
    exposures: torch.Tensor


def _stack_exposures(tau: torch.Tensor, batch: int, unbatched: bool) -> torch.Tensor:
    """Shape (M,) or (B, M) exposures as (1 or B, M, 1, 1, 1) for a (B, C, H, W) radiance."""
    if tau.dim() == 1 and tau.numel():
        return tau.view(1, -1, 1, 1, 1)
    if tau.dim() == 2 and not unbatched and tau.shape[0] == batch and tau.shape[1]:
        return tau.view(batch, -1, 1, 1, 1)
    wanted = "(M,)" if unbatched else f"(M,) or (B, M) with B = {batch}"
    raise ValueError(f"exposures must have shape {wanted} and M >= 1; got {tuple(tau.shape)}")


def _stack_chunked(x: torch.Tensor, tau: torch.Tensor, period: float) -> torch.Tensor:
    """CPU path of :func:`capture_stack`: each chunk of the radiance is read from cache once per exposure."""
    b = x.shape[0]
    flat = x.reshape(b, x[0].numel() if b else 0)
    m = tau.shape[1]
    rates = tau.reshape(tau.shape[0], m)  # (1 or B, M)
    out = torch.empty((b, m, flat.shape[1]), dtype=x.dtype)
    chunks = column_chunks(flat.shape[1], b * m)
    scratch = torch.empty((b, chunks[0].stop if chunks else 0), dtype=x.dtype)
    for cols in chunks:
        for i in range(m):
            o = out[:, i, cols]
            torch.mul(flat[:, cols], rates[:, i : i + 1], out=o).floor_()
            _wrap_rows_(o, period, scratch[:, : o.shape[1]])
    return out.view(b, m, *x.shape[1:])


def capture_stack(
    radiance: torch.Tensor,
    exposures: list[float] | tuple[float, ...] | torch.Tensor,
    bits: int = 8,
    *,
    straight_through: bool = False,
) -> torch.Tensor:
    r"""Noise-free modulo sensor at several exposures, stacked on a new exposure dimension (Eq. 1 per frame).

    Frame ``i`` holds :math:`I_m^{(i)} = \mathrm{mod}(\lfloor \tau^{(i)} E \rfloor, 2^N)`.

    Equal to ``torch.stack([capture_modulo(radiance, t, bits) for t in exposures], dim=1)`` for (B, C, H, W)
    radiance, in one pass that validates the radiance once. The result is a plain tensor, what
    :func:`~torch_modulo.unwrap_multi` decodes with the same exposures; the layer :class:`MultiExposureCapture`
    returns it with its exposures as an :class:`ExposureStack`.

    Args:
        radiance: non-negative radiance ``E``, (B, C, H, W) or (C, H, W).
        exposures: ``tau`` > 0 per frame: (M,) shared by the batch, or (B, M) for (B, C, H, W) radiance; any
            sequence or tensor.
        bits: counter bit depth ``N``, 1 to 24 in float32 (53 in float64).
        straight_through: gradients flow as if ``floor`` were the identity (see :func:`capture_modulo`).

    Returns:
        Modulus images, (B, M, C, H, W) for (B, C, H, W) radiance or (M, C, H, W) for (C, H, W), on the
        radiance's device and dtype.

    Raises:
        TypeError: ``radiance`` is not a floating tensor, ``bits`` not an integer or ``straight_through`` not a bool.
        ValueError: a bad shape, negative, NaN or infinite radiance, non-positive exposures, more bits than the
            dtype holds, or counts beyond the dtype's range.

    Warns:
        UserWarning: the counts go beyond the integers the dtype holds exactly (see :func:`capture_modulo`).

    Example:
        >>> capture_stack(torch.tensor([[[[3.0, 40.0]]]]), [1.0, 8.0], bits=8)[0, :, 0, 0]
        tensor([[ 3., 40.],
                [24., 64.]])
    """
    check_floating(radiance, "radiance")
    check_image_shape(radiance, "radiance", 3, 4)
    bits = check_bits(bits, radiance.dtype)
    straight_through = check_flag(straight_through, "straight_through")
    unbatched = radiance.dim() == 3
    x = radiance.unsqueeze(0) if unbatched else radiance
    tau = _stack_exposures(exposure_tensor(exposures, radiance, "exposures"), x.shape[0], unbatched)
    if validation_enabled():
        peak, scale = nonnegative_max(radiance, "radiance"), tau
        if tau.shape[0] > 1 and x.numel():  # a row of exposures per item: each item's peak times its own exposures
            top = x.detach().flatten(1).amax(1).double() * tau.detach().flatten(1).amax(1).double()
            peak, scale = float(top.max()), tau.new_ones(())
        _warn_inexact_counts(peak, scale, radiance.dtype, stacklevel=3)
    period = float(2**bits)
    y = x.unsqueeze(1)
    if _needs_grad(radiance, tau):
        out = _counts_autograd(y * tau, period, straight_through, clip=False)
    elif _compiling() or x.device.type != "cpu" or not x.is_contiguous():
        out = _wrap(torch.floor(y * tau), period)
    else:
        out = _stack_chunked(x, tau, period)
    return out[0] if unbatched else out


class MultiExposureCapture(_ExactExposures):
    """Module twin of :func:`capture_stack`: a noise-free modulo sensor taking one frame per exposure.

    It returns an :class:`ExposureStack` of the moduli and the exposures, so that the decoder that follows needs
    no second argument: ``nn.Sequential(MultiExposureCapture(taus, bits=8), MultiExposureUnwrap(bits=8))`` maps
    radiance to radiance. The exposures are a float64 buffer: ``.to(device)`` moves them, while dtype casts
    (``.half()``, ``.to(torch.bfloat16)``) leave them float64, so the moduli and exposures do not change; the
    layer pickles, so it works in ``DataLoader`` workers.

    Args:
        exposures: ``tau`` > 0 per frame, (M,): any sequence or tensor.
        bits: counter bit depth ``N``.
        straight_through: gradients flow as if ``floor`` were the identity (see :func:`capture_modulo`).

    Shape:
        - Input: (B, C, H, W) or (C, H, W) radiance.
        - Output: :class:`ExposureStack` with moduli (B, M, C, H, W) or (M, C, H, W) and exposures (M,) in
          float64 on the radiance's device.

    Example:
        >>> from torch_modulo import MultiExposureUnwrap
        >>> radiance = torch.tensor([[[[0.25, 2.75, 70.5]]]])
        >>> chain = nn.Sequential(MultiExposureCapture([1.0, 100.0, 10000.0], bits=8), MultiExposureUnwrap(bits=8))
        >>> chain(radiance)
        tensor([[[[ 0.2500,  2.7500, 70.5000]]]])
    """

    _exact_buffers = ("exposures",)
    exposures: torch.Tensor

    def __init__(
        self,
        exposures: list[float] | tuple[float, ...] | torch.Tensor,
        bits: int = 8,
        straight_through: bool = False,
    ) -> None:
        super().__init__()
        self.bits = check_bits(bits, torch.float64)
        self.straight_through = check_flag(straight_through, "straight_through")
        tau = exposure_tensor(exposures, torch.empty((), dtype=torch.float64), "exposures")
        if tau.dim() != 1 or not tau.numel():
            raise ValueError(f"exposures must be a sequence or (M,) tensor with M >= 1; got shape {tuple(tau.shape)}")
        self.register_buffer("exposures", tau, persistent=False)

    def forward(self, radiance: torch.Tensor) -> ExposureStack:
        moduli = capture_stack(radiance, self.exposures, self.bits, straight_through=self.straight_through)
        return ExposureStack(moduli, self.exposures.to(radiance.device))

    def extra_repr(self) -> str:
        return f"exposures={self.exposures.tolist()}, bits={self.bits}, straight_through={self.straight_through}"
