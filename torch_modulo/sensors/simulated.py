r"""Simulated sensors: a digital-pixel (DFPA) modulo sensor with a physical noise model, and a conventional sensor
that shares the model but clips, for fair comparisons.

The pixel of a digital-pixel focal plane array (paper Sec. 3, Fig. 3) integrates photo-current on a small
capacitor; each time the capacitor reaches its threshold charge ``q`` (electrons per count) it is discharged and a
pulse increments an ``N``-bit counter, which rolls over at ``2^N``. Per pixel and exposure ``tau``, in that order:

1. expected charge (electrons): :math:`\lambda = q\,(\tau E g) + D \tau`, with ``E`` the radiance in counts per
   unit exposure (DESIGN.md: a noise-free sensor reads ``floor(tau E)``), ``g`` the pixel's fixed-pattern gain
   (photo-response non-uniformity, :math:`g \sim 1 + \sigma_g \mathcal N(0, 1)`, drawn once per sensor) and ``D``
   the dark current in electrons per unit exposure;
2. photon shot noise: the collected charge is :math:`e \sim \mathrm{Poisson}(\lambda)`;
3. read/reset noise: :math:`e \mathrel{+}= \sigma_r \mathcal N(0, 1)` electrons;
4. the pulse counter counts whole threshold charges: :math:`I = \max(\lfloor e / q \rfloor, 0)`;
5. the counter keeps the low ``N`` bits (modulo sensor, Eq. 1: :math:`I_m = \mathrm{mod}(I, 2^N)`) or, for a
   conventional sensor, the ADC clips: :math:`\min(I, 2^N - 1)`.

With no noise (``noise=None``, or a :class:`NoiseModel` whose terms are all off) the result is exactly
:func:`torch_modulo.capture_modulo` (or :func:`~torch_modulo.capture_intensity`).

A colour sensor (``cfa="RGGB"``, ... : :data:`torch_modulo.cfa.CFA_PATTERNS`) has a colour filter over every pixel:
the RGB radiance is mosaicked first (:func:`torch_modulo.cfa.mosaic`, each photosite keeps the colour its filter
passes), and steps 1-5 then run per photosite, fixed-pattern gain included. The frames are mosaics,
(B, M, 1, H, W).

Statistics (for choosing parameters): in counts, the mean is about :math:`\lambda/q - 1/2` and the variance
about :math:`(\lambda + \sigma_r^2)/q^2 + 1/12` (the ``1/2`` and ``1/12`` come from the counter's floor) once the
charge spreads over a few thresholds (:math:`\sqrt{\lambda + \sigma_r^2} \gtrsim q`); with ``q = 1`` and no read
noise the counts are exactly Poisson. A modulo sensor's low bits are therefore noisy where ``sqrt(tau E / q)``
approaches ``2^N``: single-shot unwrapping needs the noise between neighbours to stay well below ``2^(N-1)``.

Randomness: each sensor draws from its own ``torch.Generator`` (one per device) seeded with ``seed``, so the same
seed gives the same frames on every run on the same device (CPU and CUDA streams differ). In a DataLoader worker the
generator is seeded from ``seed`` and the worker's seed (``torch.utils.data.get_worker_info().seed``, which differs
per worker and per epoch and follows ``torch.manual_seed`` in the main process): workers do not repeat each other's
noise, and a run is still repeatable for a given seed and number of workers. The fixed-pattern gain
comes from a separate generator seeded with ``fpn_seed``, so it is the same for every capture of a sensor instance
and for every instance with the same ``fpn_seed``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from torch import nn

from torch_modulo._checks import (
    check_bits,
    check_floating,
    check_image_shape,
    check_nonnegative,
    check_real,
    exposure_tensor,
)
from torch_modulo.capture import capture_intensity, capture_modulo
from torch_modulo.cfa import check_cfa, mosaic
from torch_modulo.noise import NoiseModel, as_noise_model
from torch_modulo.sensors.frames import FrameStack

__all__ = [
    "NoiseModel",
    "SimulatedIntensitySensor",
    "SimulatedModuloSensor",
    "fixed_pattern_gain",
    "simulate_capture",
]


def fixed_pattern_gain(
    shape: Sequence[int],
    prnu: float,
    *,
    seed: int = 0,
    device: torch.device | str | None = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """The fixed-pattern (PRNU) gain map ``g = max(1 + prnu * N(0, 1), 0)`` of a sensor, for pixels of ``shape``.

    Drawn on the CPU in float64 from ``seed`` and then moved, so the pattern is the same on every device.

    Example:
        >>> g = fixed_pattern_gain((1, 64, 64), prnu=0.01, seed=3)
        >>> torch.equal(g, fixed_pattern_gain((1, 64, 64), prnu=0.01, seed=3)), round(float(g.std()), 2)
        (True, 0.01)
    """
    prnu = check_real(prnu, "prnu", 0.0)
    generator = torch.Generator().manual_seed(int(seed))
    gain = 1.0 + prnu * torch.randn(tuple(shape), generator=generator, dtype=torch.float64)
    return gain.clamp_(min=0.0).to(device=device, dtype=dtype)


def _stack_exposures(exposures: float | Sequence[float] | torch.Tensor, radiance: torch.Tensor, b: int) -> torch.Tensor:
    """Exposures as a (1, M) or (B, M) tensor on the radiance's device and dtype."""
    tau = exposure_tensor(exposures, radiance, "exposures")
    if tau.dim() == 0:
        tau = tau.reshape(1)
    if tau.dim() == 1:
        tau = tau.unsqueeze(0)
    if tau.dim() != 2 or tau.shape[0] not in (1, b) or tau.shape[1] < 1:
        raise ValueError(f"exposures must have shape (M,) or (B, M) with B = {b} and M >= 1; got {tuple(tau.shape)}")
    return tau


def simulate_capture(
    radiance: torch.Tensor,
    exposures: float | Sequence[float] | torch.Tensor,
    bits: int = 8,
    noise: NoiseModel | None = None,
    *,
    wrap: bool = True,
    generator: torch.Generator | None = None,
    gain: torch.Tensor | None = None,
    cfa: str | None = None,
) -> torch.Tensor:
    r"""Capture a radiance map at several exposures with a noisy modulo (or clipping) sensor.

    Args:
        radiance: ``E`` >= 0 in counts per unit exposure, (B, C, H, W) or (C, H, W).
        exposures: ``tau`` > 0: a float, (M,) shared by the batch, or (B, M).
        bits: counter bit depth ``N``.
        noise: the :class:`NoiseModel` (or a preset name), or None for a noise-free sensor (then this equals
            :func:`~torch_modulo.capture_modulo` exactly, unless a ``gain`` map is given).
        wrap: True for a modulo sensor (Eq. 1), False for a conventional sensor that clips at ``2**bits - 1``.
        generator: random source for shot and read noise (and for the gain map when ``gain`` is None); its device
            must be the radiance's. None uses torch's global generator.
        gain: fixed-pattern gain ``g``, broadcastable to (C, H, W) or (B, C, H, W) (with ``cfa``: to the mosaic,
            (1, H, W) or (B, 1, H, W)); None draws one from ``generator`` when ``noise.prnu > 0`` (a new pattern per
            call; sensors keep theirs fixed).
        cfa: None, or the colour filter array of a colour sensor (``"RGGB"``, ``"BGGR"``, ``"GRBG"``,
            ``"GBRG"``): the RGB radiance is mosaicked first (:func:`torch_modulo.cfa.mosaic`) and the noise drawn
            per photosite; the frames then have one channel.

    Returns:
        Frames of integers in ``[0, 2**bits)``, (B, M, C, H, W) (or (M, C, H, W) for unbatched radiance; C = 1
        with ``cfa``), same dtype and device as ``radiance``. No gradient (the counter is discrete).

    Raises:
        TypeError: ``radiance`` not a floating tensor, ``noise`` not a NoiseModel.
        ValueError: negative or non-finite radiance, bad exposures or shapes, bad gain; with ``cfa``, an unknown
            pattern, radiance that is not RGB, or an odd height or width.

    Example:
        >>> radiance = torch.tensor([[[[0.5, 30.0, 300.0]]]])
        >>> simulate_capture(radiance, [1.0, 4.0], bits=8)[0, :, 0, 0]              # noise-free: capture_modulo
        tensor([[  0.,  30.,  44.],
                [  2., 120., 176.]])
        >>> g = torch.Generator().manual_seed(0)
        >>> noisy = simulate_capture(radiance, [1.0, 4.0], bits=8, noise=NoiseModel(), generator=g)
        >>> noisy.shape
        torch.Size([1, 2, 1, 1, 3])
        >>> simulate_capture(torch.full((1, 3, 4, 6), 300.0), [1.0, 2.0], cfa="RGGB").shape   # a colour sensor
        torch.Size([1, 2, 1, 4, 6])
    """
    check_floating(radiance, "radiance")
    check_image_shape(radiance, "radiance", min_dims=3, max_dims=4)
    if cfa is not None:
        radiance = _mosaic_radiance(radiance, cfa)
    bits = check_bits(bits, radiance.dtype)
    noise = as_noise_model(noise)
    unbatched = radiance.dim() == 3
    x = radiance.detach().unsqueeze(0) if unbatched else radiance.detach()
    b = x.shape[0]
    tau = _stack_exposures(exposures, x, b)
    check_nonnegative(x, "radiance")

    if gain is None and (noise is None or noise.is_noiseless):
        # Exactly the noise-free capture models, one exposure at a time.
        capture = capture_modulo if wrap else capture_intensity
        cols = [capture(x, tau[:, i].expand(b) if b else tau[:, i].reshape(()), bits) for i in range(tau.shape[1])]
        out = torch.stack(cols, dim=1)
        return out[0] if unbatched else out

    if noise is None:  # a gain map alone: a noise-free sensor with fixed-pattern gain
        noise = NoiseModel(read_noise=0.0, shot_noise=False)
    # Noise path: work in float32 (float64 for float64 input, or where counts reach 2^24, above which float32
    # cannot hold every integer), then return the input's dtype.
    work = torch.float64 if x.dtype == torch.float64 else torch.float32
    x = x.to(work)
    tau = _stack_exposures(exposures, x, b)
    if gain is None and noise.prnu > 0:
        gain = 1.0 + noise.prnu * torch.randn(x.shape[1:], generator=generator, device=x.device, dtype=work)
        gain = gain.clamp_(min=0.0)
    if gain is not None:
        check_floating(gain, "gain")
        check_nonnegative(gain, "gain")
        try:
            torch.broadcast_shapes(gain.shape, x.shape)
        except RuntimeError:
            raise ValueError(
                f"gain of shape {tuple(gain.shape)} does not broadcast against radiance of shape {tuple(x.shape)}"
            ) from None
        x = x * gain.to(device=x.device, dtype=work)
    q = noise.electrons_per_count
    if work == torch.float32 and x.numel() and x.device.type != "mps":
        peak = float(x.max()) * float(tau.max())
        if (peak + noise.dark_current * float(tau.max()) / q) * max(q, 1.0) >= 2**24:
            work = torch.float64
            x, tau = x.double(), _stack_exposures(exposures, x.double(), b)
    t = tau.view(tau.shape[0], tau.shape[1], 1, 1, 1)
    counts = x.unsqueeze(1) * t  # expected counts tau E g, (B, M, C, H, W)
    if noise.dark_current:
        counts = counts + t * (noise.dark_current / q)
    if noise.shot_noise:
        electrons = torch.poisson(counts * q, generator=generator)
    else:
        electrons = counts * q
    if noise.read_noise:
        electrons = electrons + noise.read_noise * torch.randn(
            electrons.shape, generator=generator, device=electrons.device, dtype=electrons.dtype
        )
    counts = torch.floor(electrons / q).clamp_(min=0.0)
    period = float(2**bits)
    if wrap:
        counts = counts - period * torch.floor(counts / period)
    else:
        counts = counts.clamp_(max=period - 1)
    counts = counts.to(radiance.dtype)
    return counts[0] if unbatched else counts


def _mosaic_radiance(radiance: torch.Tensor, cfa: str) -> torch.Tensor:
    """The RGB ``radiance`` (B, 3, H, W) or (3, H, W) mosaicked with the pattern ``cfa`` (checked first)."""
    cfa = check_cfa(cfa)
    if radiance.shape[-3] != 3:
        raise ValueError(
            f"radiance must be RGB, (B, 3, H, W) or (3, H, W), for a colour sensor (cfa={cfa!r}); "
            f"got shape {tuple(radiance.shape)}"
        )
    return mosaic(radiance.detach(), cfa)


def _seed(value: object, name: str) -> int:
    # Not _checks.check_int: the sensors have always said "an int", and their tests match that wording.
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name} must be an int; got {value!r}")
    if not -(2**63) <= value < 2**64:  # what torch.Generator.manual_seed takes
        raise ValueError(f"{name} must be in [-2**63, 2**64); got {value}")
    return int(value)


class _SimulatedSensor(nn.Module):
    _wrap: bool = True
    _kind: str = "modulo"

    def __init__(
        self,
        bits: int = 8,
        noise: NoiseModel | str | None = NoiseModel(),  # noqa: B008 (frozen, immutable default)
        *,
        seed: int = 0,
        fpn_seed: int | None = None,
        cfa: str | None = None,
    ) -> None:
        super().__init__()
        self.bits = check_bits(bits, torch.float64)
        self.noise = as_noise_model(noise)
        self.cfa = check_cfa(cfa) if cfa is not None else None
        self.seed = _seed(seed, "seed")
        self.fpn_seed = _seed(fpn_seed, "fpn_seed") if fpn_seed is not None else (self.seed + 1) % 2**64
        self._generators: dict[tuple[torch.device, int | None], torch.Generator] = {}
        self._gains: dict[tuple[Any, ...], torch.Tensor] = {}

    def manual_seed(self, seed: int) -> _SimulatedSensor:
        """Restart the shot/read noise streams from ``seed`` (the fixed pattern is kept). Returns the sensor."""
        self.seed = _seed(seed, "seed")
        self._generators.clear()
        return self

    def generator(self, device: torch.device | str) -> torch.Generator:
        """This sensor's random generator on ``device`` (created from ``seed`` on first use)."""
        device = torch.device(device)
        if device.type == "cuda" and device.index is None:
            device = torch.device("cuda", torch.cuda.current_device())
        # In a DataLoader worker the stream also follows the worker's seed (different for every worker and epoch,
        # and set by the main process's torch.manual_seed): copies of one sensor would otherwise repeat each
        # other's noise, and every epoch the last one's.
        worker = torch.utils.data.get_worker_info()
        key = (device, None if worker is None else worker.seed)
        if key not in self._generators:
            seed = self.seed if worker is None else (self.seed * 6364136223846793005 + worker.seed) % 2**64
            self._generators[key] = torch.Generator(device=device).manual_seed(seed)
        return self._generators[key]

    def gain_map(self, shape: Sequence[int], device: torch.device | str, dtype: torch.dtype) -> torch.Tensor | None:
        """The fixed-pattern gain for pixels of ``shape`` (C, H, W), or None without PRNU; same for every call."""
        if self.noise is None or self.noise.prnu == 0:
            return None
        key = (tuple(shape), str(device), dtype)
        if key not in self._gains:
            self._gains[key] = fixed_pattern_gain(
                shape, self.noise.prnu, seed=self.fpn_seed, device=device, dtype=dtype
            )
        return self._gains[key]

    def forward(self, radiance: torch.Tensor, exposures: float | Sequence[float] | torch.Tensor) -> FrameStack:
        """Capture ``radiance`` (B, C, H, W) or (C, H, W) at each exposure; returns a :class:`FrameStack`."""
        check_floating(radiance, "radiance")
        check_image_shape(radiance, "radiance", min_dims=3, max_dims=4)
        batched = radiance if radiance.dim() == 4 else radiance.unsqueeze(0)
        if self.cfa is not None:
            batched = _mosaic_radiance(batched, self.cfa)  # the noise and the gain are then per photosite
        gain = self.gain_map(batched.shape[1:], batched.device, torch.promote_types(batched.dtype, torch.float32))
        generator = self.generator(batched.device) if self.noise is not None else None
        frames = simulate_capture(
            batched, exposures, self.bits, self.noise, wrap=self._wrap, generator=generator, gain=gain
        )
        tau = exposure_tensor(exposures, torch.empty(0, dtype=torch.float64, device=batched.device), "exposures")
        if tau.dim() == 0:
            tau = tau.reshape(1)
        metadata = {
            "sensor": type(self).__name__,
            "noise": self.noise.to_dict() if self.noise is not None else None,
            "seed": self.seed,
            "fpn_seed": self.fpn_seed,
        }
        return FrameStack(frames, tau, self.bits, metadata, kind=self._kind, cfa=self.cfa)

    capture = forward

    def extra_repr(self) -> str:
        cfa = f", cfa={self.cfa!r}" if self.cfa is not None else ""
        return f"bits={self.bits}, noise={self.noise}, seed={self.seed}, fpn_seed={self.fpn_seed}{cfa}"


class SimulatedModuloSensor(_SimulatedSensor):
    """A simulated digital-pixel modulo sensor (paper Sec. 3): radiance and exposures in, a FrameStack out.

    Args:
        bits: counter bit depth ``N``.
        noise: a :class:`NoiseModel` (default: the photon-counting pixel, shot noise with one electron per count
            and 1 e- read noise, as the command line's ``simulate``), a preset name (``"photon-counting"``,
            ``"q16"``, ``"dfpa"``: :meth:`NoiseModel.preset`), or None for the noise-free sensor of Eq. 1 (exactly
            :func:`~torch_modulo.capture_modulo`).
        seed: seed of the shot/read noise generator; the same seed gives the same frames on every run.
        fpn_seed: seed of the fixed-pattern gain (default ``seed + 1``); fixed for the sensor's lifetime.
        cfa: None, or the colour filter array of a colour sensor (``"RGGB"``, ``"BGGR"``, ``"GRBG"``, ``"GBRG"``):
            RGB radiance is mosaicked first, the noise is drawn per photosite, and the stack holds mosaics with
            the pattern in its metadata (:attr:`FrameStack.cfa`). Demosaic after unwrapping
            (:func:`torch_modulo.cfa.demosaic`).

    Shape:
        - Input: radiance (B, C, H, W) or (C, H, W) (C = 3 with ``cfa``); exposures (M,) or (B, M).
        - Output: :class:`FrameStack` of modulus images, (B, M, C, H, W) (C = 1 with ``cfa``); ``stack.moduli``
          and ``stack.frames`` name the same tensor.

    Example:
        >>> sensor = SimulatedModuloSensor(bits=8, noise=None)
        >>> stack = sensor(torch.tensor([[[[3.0, 40.0]]]]), [1.0, 8.0])
        >>> stack.moduli[0, :, 0, 0]
        tensor([[ 3., 40.],
                [24., 64.]])
        >>> stack.kind, stack.bits
        ('modulo', 8)
        >>> colour = SimulatedModuloSensor(bits=8, cfa="RGGB")(torch.full((1, 3, 4, 4), 300.0), [1.0, 16.0])
        >>> colour.moduli.shape, colour.cfa
        (torch.Size([1, 2, 1, 4, 4]), 'RGGB')
    """

    _wrap = True
    _kind = "modulo"


class SimulatedIntensitySensor(_SimulatedSensor):
    """A conventional sensor with the same noise model as :class:`SimulatedModuloSensor` that clips at
    ``2**bits - 1`` instead of wrapping; with the same seeds both see the same noise, so the only difference
    between their frames is the wrap versus the clip.

    Example:
        >>> stack = SimulatedIntensitySensor(bits=8, noise=None)(torch.tensor([[[[3.0, 40.0]]]]), [1.0, 8.0])
        >>> stack.frames[0, :, 0, 0]
        tensor([[  3.,  40.],
                [ 24., 255.]])
        >>> stack.kind
        'intensity'
    """

    _wrap = False
    _kind = "intensity"
