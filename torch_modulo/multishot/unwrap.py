"""unwrap_multi and its module twin: the noise-free rules of :mod:`~torch_modulo.multishot.counting` and the
noise-aware decoder of :mod:`~torch_modulo.multishot.noisy` behind one function."""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from typing import Literal, Protocol, cast, overload

import torch
from torch import nn

from torch_modulo._checks import (
    MAX_BITS,
    check_bits,
    check_choice,
    check_flag,
    check_floating,
    check_has_values,
    check_modulus,
    check_real,
    like_memory_format,
    validation_enabled,
)
from torch_modulo.cfa import check_cfa, merge_planes, split_planes
from torch_modulo.multishot.counting import METHODS, count_rollovers
from torch_modulo.multishot.noisy import decode_noisy
from torch_modulo.multishot.planning import dark_rollover_message, unsafe_ratio_message
from torch_modulo.multishot.stack import neighbour_ratios, sort_stack, stack_exposures
from torch_modulo.noise import NoiseModel, as_noise_model

__all__ = ["MultiExposureUnwrap", "unwrap_multi"]


def _warn_inexact_counts(out: torch.Tensor, tau: torch.Tensor, counts: bool) -> None:
    """Warn when the counts decoded into ``out`` (radiance unless ``counts``) are beyond the integers its dtype holds
    exactly (float16: 2048, float32: 2**24), or beyond its range."""
    limit = MAX_BITS.get(out.dtype, 53)
    if limit >= 53:
        return
    top = out.amax(dim=1).double()  # per item; inf where the dtype overflowed
    if not counts:
        top = top * tau[:, -1].double()  # radiance times the item's longest exposure: its counts, at most
    peak = float(top.max())
    if peak > 2**limit:
        warnings.warn(
            f"counts reach {peak:.0f}, beyond what {out.dtype} holds exactly ({2**limit}): they are rounded (or "
            "infinite past the dtype's range); use float64 moduli for exact counts",
            stacklevel=3,
        )


def _warn_unsafe(
    tau: torch.Tensor,
    ratios: torch.Tensor,
    bits: int,
    noise: NoiseModel,
    sigmas: float,
    spatial: bool,
    narrow: bool = False,
) -> None:
    """Warn when a neighbouring ratio leaves pixels that risk gross errors undecodable in the next frame (with
    ``spatial``, even with their neighbours' evidence; images ``narrow``er than 3 pixels have no 2-D neighbourhood,
    and are held to the limit for each pixel alone)."""
    if not ratios.numel():
        return
    worst = float(ratios.max())
    spatial = spatial and not narrow
    message = unsafe_ratio_message(worst, bits, noise, sigmas, spatial=spatial)
    if message is None:
        return
    if narrow:
        message += " (an image narrower than 3 pixels has no 2-D neighbourhood: each pixel decodes alone)"
    elif not spatial and unsafe_ratio_message(worst, bits, noise, sigmas, spatial=True) is None:
        message += " (or decode with spatial=True, for which these ratios are safe)"  # a plan for the spatial decoder
    span = float((tau[:, -1] / tau[:, 0]).max())
    stops = math.ceil(math.log2(span) + bits)
    plan = f"plan_exposures({stops}, bits={bits}, noise=noise{'' if spatial else ', spatial=False'})"
    warnings.warn(f"{message}, e.g. exposures = {plan}", stacklevel=3)


def _check_dark_counts(tau: torch.Tensor, bits: int, noise: NoiseModel, sigmas: float) -> None:
    """Refuse a noise model whose dark counts alone reach the rollover at the shortest exposure (its frames cannot
    be decoded: every pixel of the shortest frame has rolled over), and warn where they leave no room ``sigmas``
    deviations below it; :func:`~torch_modulo.plan_exposures` refuses the same model with the same words."""
    if noise.dark_counts == 0 or not tau.numel():
        return
    shortest = float(tau[:, 0].max())
    message = dark_rollover_message(bits, noise, sigmas, shortest)
    if message is None:
        return
    if noise.dark_counts * shortest > 2**bits - 1:
        raise ValueError(
            f"{message}: every pixel of the shortest frame has rolled over, so these frames cannot be decoded with "
            "this model; check the model's dark current and the exposures' unit"
        )
    warnings.warn(f"{message}: dark pixels of the shortest frame may have rolled over", stacklevel=3)


def _warn_overflow(values: torch.Tensor, dtype: torch.dtype, what: str) -> None:
    """Warn when the noise-aware decoder's ``values`` (float64, or float32 without it) are beyond ``dtype``'s range,
    so that they come back as ``inf``."""
    if not values.numel():
        return
    peak = float(values.amax())
    limit = torch.finfo(dtype).max
    if peak > limit:
        verb = "reach" if what == "counts" else "reaches"
        warnings.warn(
            f"{what} {verb} {peak:.4g}, beyond the range of {dtype} (at most {limit:.4g}): it is infinite there; "
            "use float64 moduli (or exposures in another unit)",
            stacklevel=3,
        )


def _count_traced(stack: torch.Tensor, tau: torch.Tensor, bits: int, method: str, return_counts: bool) -> torch.Tensor:
    """The noise-free rules of :func:`~torch_modulo.multishot.counting.count_rollovers` in whole-tensor operations.

    The path ``torch.compile`` traces: the same float64 arithmetic (so the same counts), without the CPU chunks or
    data-dependent branches. With validation on, the moduli and ratios are still checked (breaking the graph).

    Args:
        stack: (B, M, C, H, W) moduli, exposures in any order.
        tau: (B, M) float64 exposures.
        bits: the bit depth ``N``.
        method: ``"robust"`` or ``"paper"``.
        return_counts: return the counts ``I^(M)`` instead of the radiance ``I^(M) / tau^(M)``.

    Returns:
        (B, C, H, W) in the stack's dtype.
    """
    b, m = stack.shape[:2]
    tau, order = torch.sort(tau, dim=1, stable=True)
    index = order.view(b, m, *([1] * (stack.dim() - 2))).expand_as(stack)
    frames = torch.take_along_dim(stack.detach(), index, dim=1).reshape(b, m, -1)
    if validation_enabled():
        neighbour_ratios(tau, bits)
        check_modulus(frames, bits, "moduli")
    period = float(2**bits)
    inv_p = 1.0 / period
    work = torch.float64 if stack.device.type in ("cpu", "cuda") else stack.dtype
    scale = (tau[:, 1:] / tau[:, :-1] * inv_p).to(work).unsqueeze(-1)  # (B, M-1, 1): r / P
    acc = frames[:, 0].to(work)
    for i in range(1, m):
        m_i = frames[:, i]
        if method == "robust":
            acc = ((acc + 0.5) * scale[:, i - 1] - m_i * inv_p - 0.5 * inv_p).round().clamp_min(0.0)
        else:
            acc = (acc * scale[:, i - 1]).floor()
        acc = m_i + acc * period
    if not return_counts:
        acc = acc / tau[:, -1:].to(work)
    return acc.to(stack.dtype).view(b, *stack.shape[2:])


@overload
def unwrap_multi(
    moduli: torch.Tensor,
    exposures: Sequence[float] | torch.Tensor,
    bits: int = ...,
    method: str = ...,
    *,
    noise: NoiseModel | str | None = ...,
    sigmas: float = ...,
    spatial: bool = ...,
    cfa: str | None = ...,
    return_counts: bool = ...,
    return_variance: Literal[False] = ...,
) -> torch.Tensor: ...


@overload
def unwrap_multi(
    moduli: torch.Tensor,
    exposures: Sequence[float] | torch.Tensor,
    bits: int = ...,
    method: str = ...,
    *,
    noise: NoiseModel | str | None = ...,
    sigmas: float = ...,
    spatial: bool = ...,
    cfa: str | None = ...,
    return_counts: bool = ...,
    return_variance: Literal[True],
) -> tuple[torch.Tensor, torch.Tensor]: ...


@overload
def unwrap_multi(
    moduli: torch.Tensor,
    exposures: Sequence[float] | torch.Tensor,
    bits: int = ...,
    method: str = ...,
    *,
    noise: NoiseModel | str | None = ...,
    sigmas: float = ...,
    spatial: bool = ...,
    cfa: str | None = ...,
    return_counts: bool = ...,
    return_variance: bool,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]: ...


def unwrap_multi(
    moduli: torch.Tensor,
    exposures: Sequence[float] | torch.Tensor,
    bits: int = 8,
    method: str = "robust",
    *,
    noise: NoiseModel | str | None = None,
    sigmas: float = 3.0,
    spatial: bool = True,
    cfa: str | None = None,
    return_counts: bool = False,
    return_variance: bool = False,
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    r"""Recover radiance from modulus images taken at several exposures (paper Sec. 5.2, Eqs. 6-7).

    Exposures may come in any order; they are sorted per batch item. The shortest exposure must not roll over
    (its modulus is taken as its count), and neighbouring exposure ratios must not exceed ``2**bits``.

    Without ``noise`` the rollover counts follow from each frame's predecessor (the robust rule, or Eq. 6 as
    printed with ``method="paper"``): exact on noise-free frames. With a ``noise`` model (the sensor's), each pixel's
    frames are decoded only while the noise model says the rollover count is determined, and the radiance is the
    weighted least-squares fit to the decoded frames under the model, with the bias of the counter's clip at zero
    corrected (:mod:`torch_modulo.multishot.noisy`); exposures from
    :func:`~torch_modulo.plan_exposures` with the same ``noise`` keep every pixel decodable, and exposure ratios
    that leave dark pixels undecodable draw a warning that says what to use instead.

    The noise-aware decoder works in a power-of-two unit of exposure near the middle of each item's exposures (which
    rounds nothing), so exposures in any unit within float64's range decode; it computes in float32 unless the
    moduli are float64. The noise-free work is vectorised over batch, exposures' pixels and channels; on the CPU it
    runs over cache-sized chunks of pixels with float64 arithmetic in place, so the decisions are exact for counts
    up to ``2**53``. The result carries no gradient (rollover counts are discrete). Under ``torch.compile`` both
    run as whole-tensor operations with the same arithmetic, in one graph (``fullgraph=True``): the value checks
    and warnings are skipped while it traces.

    Args:
        moduli: modulus images, (B, M, C, H, W) or (M, C, H, W), floating, integers in ``[0, 2**bits)``.
        exposures: ``tau`` > 0 per exposure: (M,) shared by the batch, or (B, M).
        bits: the sensor's bit depth ``N``.
        method: ``"robust"`` (default; exact for every neighbouring ratio up to ``2**bits - 1`` and for integer
            ratios up to ``2**bits``) or ``"paper"`` (Eq. 6 as printed; wrong on many pixels unless the ratios
            are exactly ``2**bits``; takes no noise model).
        noise: the sensor's :class:`~torch_modulo.sensors.NoiseModel` (or a preset name such as
            ``"photon-counting"``), or None for noise-free decoding.
        sigmas: with ``noise``: a frame is decoded while the predicted count's standard deviation stays within
            ``2**bits / (2 sigmas)`` (with ``spatial``: the prediction's part; the whole within
            ``2**bits / (2 z)``, ``z = 2 sigmas / 3``).
        spatial: with ``noise``: predict each pixel's next count from the mean of its agreeing 3 x 3 neighbours in
            its image plane (:mod:`torch_modulo.multishot.spatial`; the default), so that the larger ratios of a
            spatial plan (``plan_exposures(..., noise=...)``, whose default it is too) decode; False decodes every
            pixel alone (for the plans of ``plan_exposures(..., spatial=False)``; its reported variance is better
            calibrated: with spatial evidence a few more values carry a wrong rollover count in a bright frame,
            which the variance leaves out). Without ``noise`` it changes nothing. Give a mosaic's ``cfa``: its
            neighbours are other colours.
        cfa: the colour filter array of mosaicked frames (``"RGGB"``, ``"BGGR"``, ``"GRBG"`` or ``"GBRG"``; moduli
            (B, M, 1, H, W) with an even height and width), or None. With ``spatial`` and ``noise`` the four colour
            planes are decoded apart, each as a half-resolution image, so that a photosite's neighbours are of its
            own colour; otherwise each photosite is decoded alone and it changes nothing.
        return_counts: return the counts at the longest exposure instead of radiance (without noise the integer
            counts ``I = I_m + k 2^N``; with noise the estimate's expected count ``tau_max E``).
        return_variance: also return the variance of the radiance (or counts) from the noise model (requires
            ``noise``).

    Returns:
        Radiance (or counts), (B, C, H, W) or (C, H, W), same dtype and device as ``moduli``; with
        ``return_variance=True`` a tuple ``(radiance, variance)``. Without noise the radiance is ``I / tau_max``
        (Eq. 7's convention, the lower edge of the final cell); with noise it is the fit of the model's expected
        readings ``tau E + dark - 1/2 + clip bias`` to the decoded counts (at least 0). Counts above ``2**24`` are
        rounded in float32 (above 2048 in float16, where they overflow past 65504), with a warning: use float64 for
        them.

    Raises:
        TypeError: ``moduli`` is not a floating tensor, ``exposures`` not numbers, ``noise`` not a NoiseModel.
        ValueError: bad shapes, values outside ``[0, 2**bits)``, non-integers, NaN/Inf, non-positive exposures, a
            neighbouring ratio above ``2**bits``, an unknown method, ``method="paper"`` with ``noise``, or a
            ``noise`` model whose dark counts alone pass ``2**bits - 1`` at the shortest exposure (its frames would
            all have rolled over there; :func:`~torch_modulo.plan_exposures` refuses the same model in the same words).

    Warns:
        UserWarning: with ``noise``, when a neighbouring ratio is too large for the noise (see above), when the dark
        counts at the shortest exposure leave no count ``sigmas`` deviations below the rollover, and when the
        radiance (or counts, or the returned variance) is beyond the range of the moduli's dtype (it is then
        ``inf``); without, when the counts are beyond the integers the dtype holds exactly.

    Example:
        >>> from torch_modulo import capture_modulo
        >>> radiance = torch.tensor([[[[0.25, 2.75, 70.5]]]])            # (B, C, H, W) = (1, 1, 1, 3)
        >>> taus = [1.0, 100.0, 10000.0]
        >>> stack = torch.stack([capture_modulo(radiance, t, bits=8) for t in taus], dim=1)
        >>> unwrap_multi(stack, taus, bits=8, return_counts=True)
        tensor([[[[  2500.,  27500., 705000.]]]])
        >>> unwrap_multi(stack, taus, bits=8, method="paper", return_counts=True)
        tensor([[[[  2500.,   1900., 705000.]]]])
    """
    check_choice(method, "method", METHODS)
    noise = as_noise_model(noise)
    check_flag(return_counts, "return_counts")
    check_flag(return_variance, "return_variance")
    check_flag(spatial, "spatial")
    if noise is not None and method == "paper":
        raise ValueError(f"method='paper' decodes Eqs. 6-7 as printed and takes no noise model; got noise={noise}")
    if return_variance and noise is None:
        raise ValueError("return_variance=True needs a noise model (noise=...)")
    sigmas = check_real(sigmas, "sigmas", positive=True)
    stack, tau, unbatched = stack_exposures(moduli, exposures, "moduli")
    if cfa is not None:
        cfa = check_cfa(cfa)
        if stack.shape[2] != 1 or stack.shape[3] % 2 or stack.shape[4] % 2:
            raise ValueError(
                f"moduli of a colour filter array (cfa={cfa!r}) must be mosaics with one channel and an even height "
                f"and width, (B, M, 1, H, W); got shape {tuple(moduli.shape)}"
            )
        if spatial and noise is not None:
            mosaics = _by_colour_plane(stack, tau, bits, method, noise, sigmas, return_counts, return_variance)
            mosaics = tuple(o[0] for o in mosaics) if unbatched else mosaics
            return cast(tuple[torch.Tensor, torch.Tensor], mosaics) if return_variance else mosaics[0]
    check_has_values(stack, "moduli")  # the decoder reads values, with the checks on or off
    if tau.requires_grad:
        tau = tau.detach()
    bits = check_bits(bits, moduli.dtype)
    if noise is None and torch.compiler.is_compiling():
        out = _count_traced(stack, tau, bits, method, return_counts)
        return out[0] if unbatched else out
    stack, tau = sort_stack(stack, tau)
    ratios = neighbour_ratios(tau, bits) if validation_enabled() else tau[:, 1:] / tau[:, :-1]
    b, m = stack.shape[:2]
    pixel_shape = stack.shape[2:]
    n = math.prod(pixel_shape)
    frames = stack.detach().reshape(b, m, n)
    if noise is None:
        out = torch.empty((b, n), dtype=moduli.dtype, device=moduli.device)
        if out.numel():
            count_rollovers(frames, tau, ratios, bits, method, return_counts, out)
            _warn_inexact_counts(out, tau, return_counts)
        out = out.view(b, *pixel_shape)
        return out[0] if unbatched else out

    checking = validation_enabled()  # the checks and warnings below read values: off while torch.compile traces
    if checking:
        _check_dark_counts(tau, bits, noise, sigmas)
        # The spatial plan's ratios count on a 2-D neighbourhood: narrower images are held to the per-pixel limit.
        _warn_unsafe(tau, ratios, bits, noise, sigmas, spatial, narrow=min(pixel_shape[-2:]) < 3)
        check_modulus(frames, bits, "moduli")
    shape = (pixel_shape[-2], pixel_shape[-1]) if spatial and pixel_shape[-2] * pixel_shape[-1] > 1 else None
    radiance, variance, _ = decode_noisy(frames, tau, bits, noise, sigmas, return_counts, shape)
    if checking:
        _warn_overflow(radiance, moduli.dtype, "counts" if return_counts else "radiance")
        if return_variance:
            _warn_overflow(variance, moduli.dtype, "variance")
    radiance = radiance.to(moduli.dtype).view(b, *pixel_shape)
    variance = variance.to(moduli.dtype).view(b, *pixel_shape)
    if unbatched:
        radiance, variance = radiance[0], variance[0]
    return (radiance, variance) if return_variance else radiance


def _by_colour_plane(
    stack: torch.Tensor,
    tau: torch.Tensor,
    bits: int,
    method: str,
    noise: NoiseModel,
    sigmas: float,
    return_counts: bool,
    return_variance: bool,
) -> tuple[torch.Tensor, ...]:
    """The spatial decode of (B, M, 1, H, W) mosaics, its four colour planes as the channels of (B, M, 4, H/2, W/2)
    images, put back into (B, 1, H, W) mosaics: ``(radiance,)`` or ``(radiance, variance)``."""
    out = unwrap_multi(
        split_planes(stack),
        tau,
        bits,
        method,
        noise=noise,
        sigmas=sigmas,
        spatial=True,
        return_counts=return_counts,
        return_variance=return_variance,
    )
    return tuple(merge_planes(o) for o in (out if isinstance(out, tuple) else (out,)))


class _FrameStackLike(Protocol):
    """What :class:`MultiExposureUnwrap` reads of a :class:`~torch_modulo.sensors.FrameStack` (or a look-alike)."""

    @property
    def moduli(self) -> torch.Tensor: ...

    @property
    def exposures(self) -> Sequence[float] | torch.Tensor: ...


def _split_stack(stack: object) -> tuple[torch.Tensor, Sequence[float] | torch.Tensor]:
    """Moduli and exposures from an ExposureStack, a (moduli, exposures) pair or a FrameStack-like object."""
    if isinstance(stack, tuple) and len(stack) == 2:
        return stack[0], stack[1]
    if hasattr(stack, "moduli") and hasattr(stack, "exposures"):
        kind = getattr(stack, "kind", "modulo")
        if kind != "modulo":
            raise ValueError(f"MultiExposureUnwrap decodes modulo frames; got a stack of kind={kind!r}")
        frames = cast(_FrameStackLike, stack)  # it has both attributes
        return frames.moduli, frames.exposures
    raise TypeError(
        "MultiExposureUnwrap needs the exposures: call it with (moduli, exposures), or with the ExposureStack that "
        f"MultiExposureCapture returns or a FrameStack; got {type(stack).__name__} alone"
    )


class MultiExposureUnwrap(nn.Module):
    """Module twin of :func:`unwrap_multi` (Eqs. 6-7, and noise-aware decoding with ``noise``).

    Call it with the moduli and their exposures, ``layer(moduli, exposures)``, or with one object that carries
    both: the :class:`~torch_modulo.ExposureStack` that :class:`~torch_modulo.MultiExposureCapture` returns (so
    the two chain in ``nn.Sequential``), any ``(moduli, exposures)`` tuple, or a
    :class:`~torch_modulo.sensors.FrameStack` of modulo frames.

    Args:
        bits: the sensor's bit depth.
        method: ``"robust"`` (default) or ``"paper"``.
        return_counts: return counts at the longest exposure instead of radiance.
        noise: the sensor's noise model (or a preset name), or None.
        sigmas: the decoding gate with ``noise`` (see :func:`unwrap_multi`).
        spatial: with ``noise``, use the neighbours' evidence (the default; see :func:`unwrap_multi`); a
            :class:`~torch_modulo.sensors.FrameStack` of mosaics passes its ``cfa``, so that its colour planes are
            decoded apart.

    Shape:
        - Input: moduli (B, M, C, H, W) or (M, C, H, W); exposures (M,) or (B, M).
        - Output: (B, C, H, W) or (C, H, W).

    Example:
        >>> layer = MultiExposureUnwrap(bits=4)
        >>> layer(torch.tensor([[[[3.0]]], [[[4.0]]]]), torch.tensor([1.0, 16.0]))   # (M, C, H, W)
        tensor([[[3.2500]]])
        >>> from torch_modulo import MultiExposureCapture
        >>> chain = nn.Sequential(MultiExposureCapture([1.0, 16.0], bits=4), layer)
        >>> chain(torch.tensor([[[[3.25]]]]))
        tensor([[[[3.2500]]]])
    """

    def __init__(
        self,
        bits: int = 8,
        method: str = "robust",
        return_counts: bool = False,
        *,
        noise: NoiseModel | str | None = None,
        sigmas: float = 3.0,
        spatial: bool = True,
    ) -> None:
        super().__init__()
        self.method = check_choice(method, "method", METHODS)
        self.bits = check_bits(bits, torch.float64)
        self.return_counts = check_flag(return_counts, "return_counts")
        self.noise = as_noise_model(noise)
        self.sigmas = check_real(sigmas, "sigmas", positive=True)
        self.spatial = check_flag(spatial, "spatial")
        if self.noise is not None and method == "paper":
            raise ValueError("method='paper' takes no noise model")

    def forward(
        self,
        moduli: torch.Tensor | tuple[torch.Tensor, torch.Tensor] | _FrameStackLike,
        exposures: Sequence[float] | torch.Tensor | None = None,
    ) -> torch.Tensor:
        cfa = None
        if exposures is None:
            bits = getattr(moduli, "bits", self.bits)  # a FrameStack knows its bit depth
            if bits != self.bits:
                raise ValueError(f"the stack holds bits={bits} frames but this layer decodes bits={self.bits}")
            cfa = getattr(moduli, "cfa", None)  # and its mosaic's pattern
            frames, exposures = _split_stack(moduli)
        else:
            frames = check_floating(moduli, "moduli")
        out = unwrap_multi(
            frames,
            exposures,
            self.bits,
            self.method,
            noise=self.noise,
            sigmas=self.sigmas,
            spatial=self.spatial,
            cfa=cfa,
            return_counts=self.return_counts,
        )
        # Keep the frames' memory format: channels-last frames (MultiExposureCapture of channels-last radiance) give
        # a channels-last image.
        return like_memory_format(out, frames[:, 0]) if frames.dim() == 5 and out.numel() else out

    def extra_repr(self) -> str:
        return (
            f"bits={self.bits}, method={self.method!r}, return_counts={self.return_counts}, noise={self.noise}, "
            f"spatial={self.spatial}"
        )
