"""FrameStack: what every sensor adapter hands downstream, whether the frames were simulated or read from disk.

Data flows one way: a sensor (simulated or file-backed) makes a :class:`FrameStack`, and the unwrapping functions
take its fields (``tm.unwrap_multi(stack.frames, stack.exposures, stack.bits)``). The stack has no unwrapping
methods of its own.

A stack of exposures takes one of three forms, one per level of the API:

- the functions take and return plain tensors: :func:`~torch_modulo.capture_stack` returns the (B, M, C, H, W)
  modulus images, and :func:`~torch_modulo.unwrap_multi` takes them with the exposures and the bit depth;
- the layers pass one :class:`~torch_modulo.ExposureStack`, a named tuple ``(moduli, exposures)``, so that
  ``nn.Sequential(MultiExposureCapture(...), MultiExposureUnwrap(...))`` chains;
- the sensors return a :class:`FrameStack`: the frames and exposures together with what a file of them records
  (bit depth, kind, colour filter array, metadata), validated on construction.

From one to another: ``FrameStack(*exposure_stack, bits=N)`` (or ``FrameStack(moduli, exposures, bits=N)`` with
the function's tensor) gives the sensors' form, :meth:`FrameStack.to_exposure_stack` gives the layers' form of a
modulo stack, and :class:`~torch_modulo.MultiExposureUnwrap` takes an :class:`~torch_modulo.ExposureStack` or a
:class:`FrameStack` as it is.
"""

from __future__ import annotations

import copy
import math
import operator
from collections.abc import Mapping, Sequence
from typing import Any

import torch

from torch_modulo._checks import check_bits, check_choice, check_floating, check_modulus, exposure_tensor
from torch_modulo.capture import ExposureStack
from torch_modulo.cfa import check_cfa

__all__ = ["KINDS", "FrameStack"]

#: ``"modulo"``: modulus images (Eq. 1); ``"intensity"``: frames of a conventional sensor, clipped at 2^bits - 1.
KINDS = ("modulo", "intensity")


class FrameStack:
    """Frames of one or more scenes, each taken at several exposures, with the sensor's bit depth.

    What sensors return (see the module's notes for the tensor and :class:`~torch_modulo.ExposureStack` forms).
    Validated on construction: the frames must be a floating tensor of integers in ``[0, 2**bits)``, the exposures
    positive and finite with one per frame. The tensors are stored as given (no copy); a (M, C, H, W) stack is
    stored as (1, M, C, H, W). Exposures are kept in float64 (float32 on MPS), so values read from metadata keep
    every digit. The frames are :attr:`frames` whatever the kind; :attr:`moduli` is the same tensor under the
    name that suits a modulo stack.

    Args:
        moduli: (B, M, C, H, W) frames (or (M, C, H, W) for one scene); the modulus images of a modulo sensor, or
            the clipped frames of a conventional one (``kind="intensity"``).
        exposures: ``tau`` > 0 per frame: (M,) shared by the batch, or (B, M); any sequence or tensor.
        bits: the sensor's bit depth ``N``.
        metadata: JSON-compatible facts about the capture (sensor, noise model, file names, ...); copied.
        kind: ``"modulo"`` (default) or ``"intensity"``.
        cfa: the colour filter array of a colour sensor's mosaicked frames (one of
            :data:`torch_modulo.cfa.CFA_PATTERNS`, e.g. ``"RGGB"``), or None; default the metadata's ``"cfa"``.
            The pattern is kept in the metadata under ``"cfa"`` (so files carry it) and read back by :attr:`cfa`.
            Mosaicked frames have one channel and an even height and width.

    Raises:
        TypeError: ``moduli`` is not a floating tensor, ``exposures`` not numbers, ``metadata`` not a dict.
        ValueError: wrong shapes, values outside ``[0, 2**bits)`` or not integers, non-positive exposures,
            unknown ``kind``, an unknown ``cfa`` or one that disagrees with the metadata's, frames that cannot be
            a mosaic (more than one channel, odd height or width).

    Example:
        >>> from torch_modulo import capture_modulo
        >>> radiance = torch.tensor([[[[3.0, 40.0]]]])                          # (B, C, H, W)
        >>> taus = [1.0, 8.0]
        >>> stack = FrameStack(torch.stack([capture_modulo(radiance, t, bits=8) for t in taus], 1), taus, bits=8)
        >>> stack
        FrameStack(frames=(1, 2, 1, 1, 2) float32 on cpu, exposures=[1.0, 8.0], bits=8, kind='modulo')
        >>> stack.frames[0, :, 0, 0]
        tensor([[ 3., 40.],
                [24., 64.]])
        >>> stack.moduli is stack.frames
        True
        >>> stack.to_exposure_stack().exposures
        tensor([1., 8.], dtype=torch.float64)
    """

    __slots__ = ("_bits", "_exposures", "_frames", "_kind", "_metadata")

    def __init__(
        self,
        moduli: torch.Tensor,
        exposures: Sequence[float] | torch.Tensor,
        bits: int = 8,
        metadata: Mapping[str, Any] | None = None,
        *,
        kind: str = "modulo",
        cfa: str | None = None,
    ) -> None:
        check_floating(moduli, "moduli")
        if moduli.dim() == 4:
            moduli = moduli.unsqueeze(0)
        if moduli.dim() != 5:
            raise ValueError(f"moduli must have shape (B, M, C, H, W) or (M, C, H, W); got {tuple(moduli.shape)}")
        b, m = moduli.shape[:2]
        if m < 1:
            raise ValueError(f"moduli must hold at least one exposure (M >= 1); got shape {tuple(moduli.shape)}")
        bits = check_bits(bits, moduli.dtype)
        check_modulus(moduli, bits, "moduli")
        tau = exposure_tensor(
            exposures, torch.empty(0, dtype=_exposure_dtype(moduli.device), device=moduli.device), "exposures"
        )
        if not (tau.shape == (m,) or tau.shape == (b, m)):
            raise ValueError(
                f"exposures must have shape (M,) = ({m},) or (B, M) = ({b}, {m}) for moduli of shape "
                f"{tuple(moduli.shape)}; got {tuple(tau.shape)}"
            )
        check_choice(kind, "kind", KINDS)
        if metadata is None:
            metadata = {}
        if not isinstance(metadata, Mapping):
            raise TypeError(f"metadata must be a dict; got {type(metadata).__name__}")
        metadata = copy.deepcopy(dict(metadata))
        cfa = _check_stack_cfa(cfa, metadata.get("cfa"), moduli.shape)
        if cfa is not None:
            metadata["cfa"] = cfa
        self._frames = moduli
        self._exposures = tau
        self._bits = bits
        self._metadata = metadata
        self._kind = kind

    # ------------------------------------------------------------------------------------------ fields

    @property
    def frames(self) -> torch.Tensor:
        """The frames, (B, M, C, H, W): modulus images for ``kind="modulo"``, clipped counts for ``"intensity"``."""
        return self._frames

    @property
    def moduli(self) -> torch.Tensor:
        """The same tensor as :attr:`frames`, under the name that suits a modulo stack; use :attr:`frames` for
        ``kind="intensity"`` stacks (their frames are not moduli) and in code that takes either kind."""
        return self._frames

    @property
    def exposures(self) -> torch.Tensor:
        """Exposure per frame, (M,) or (B, M), float64 (float32 on MPS), on the frames' device."""
        return self._exposures

    @property
    def bits(self) -> int:
        """The sensor's bit depth ``N``: frames hold integers in ``[0, 2**bits)``."""
        return self._bits

    @property
    def metadata(self) -> dict[str, Any]:
        """Facts about the capture (a dict; mutating it changes this stack's metadata only)."""
        return self._metadata

    @property
    def kind(self) -> str:
        """``"modulo"`` or ``"intensity"``."""
        return self._kind

    @property
    def cfa(self) -> str | None:
        """The colour filter array of mosaicked frames (``"RGGB"``, ...; the metadata's ``"cfa"``), or None."""
        return self._metadata.get("cfa")

    @property
    def batch_size(self) -> int:
        return int(self._frames.shape[0])

    @property
    def num_exposures(self) -> int:
        return int(self._frames.shape[1])

    @property
    def shape(self) -> torch.Size:
        return self._frames.shape

    @property
    def device(self) -> torch.device:
        return self._frames.device

    @property
    def dtype(self) -> torch.dtype:
        return self._frames.dtype

    def exposure_matrix(self) -> torch.Tensor:
        """Exposures as (B, M), whichever shape they were given in."""
        return self._exposures.expand(self.batch_size, self.num_exposures)

    def to_exposure_stack(self) -> ExposureStack:
        """The frames and exposures as the :class:`~torch_modulo.ExposureStack` the layers pass (no copy).

        The bit depth, kind, colour filter array and metadata stay behind: the layer that decodes the stack is
        built with its bit depth (``MultiExposureUnwrap(bits=stack.bits)``).

        Returns:
            ``ExposureStack(frames, exposures)``: (B, M, C, H, W) moduli and (M,) or (B, M) exposures.

        Raises:
            ValueError: the stack is of ``kind="intensity"``; an :class:`~torch_modulo.ExposureStack` holds
                modulus images (merge a conventional sensor's frames with :func:`~torch_modulo.merge_intensity`).
        """
        if self._kind != "modulo":
            raise ValueError(
                f"an ExposureStack holds modulus images; this stack is of kind={self._kind!r} (merge its frames "
                "with merge_intensity(stack.frames, stack.exposures, stack.bits))"
            )
        return ExposureStack(self._frames, self._exposures)

    # -------------------------------------------------------------------------------------- conversion

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> FrameStack:
        """A stack on another device and/or with another floating dtype for the frames (validated again)."""
        frames = self._frames.to(device=device, dtype=dtype)
        return FrameStack(
            frames,
            self._exposures.to(device=frames.device, dtype=_exposure_dtype(frames.device)),
            self._bits,
            self._metadata,
            kind=self._kind,
        )

    def __len__(self) -> int:
        return self.batch_size

    def __getitem__(self, index: int | slice) -> FrameStack:
        """Batch items: ``stack[i]`` is a stack of one scene (B = 1), ``stack[i:j]`` several (``i``: any integer,
        numpy's and 0-d tensors' included; slices step forward)."""
        if isinstance(index, slice):
            if index.step is not None and operator.index(index.step) <= 0:
                raise ValueError(f"FrameStack slices must step forward (step >= 1); got {index}")
            items = index
        else:
            position: int | None
            try:  # numpy integers and 0-d integer tensors too (what samplers and permutations give)
                position = None if isinstance(index, bool) else operator.index(index)
            except TypeError:
                position = None
            if position is None:
                raise TypeError(f"FrameStack index must be an int or a slice; got {type(index).__name__}")
            if not -self.batch_size <= position < self.batch_size:
                raise IndexError(f"batch index {position} out of range for a FrameStack of {self.batch_size} items")
            items = slice(position % self.batch_size, position % self.batch_size + 1)
        frames = self._frames[items]
        tau = self._exposures if self._exposures.dim() == 1 else self._exposures[items]
        return FrameStack(frames, tau, self._bits, self._metadata, kind=self._kind)

    # --------------------------------------------------------------------------------------- comparison

    def __eq__(self, other: object) -> bool:
        """Exact equality of frames (values, shape, dtype), exposures, bits, kind and metadata."""
        if not isinstance(other, FrameStack):
            return NotImplemented
        return (
            self._bits == other._bits
            and self._kind == other._kind
            and self._frames.dtype == other._frames.dtype
            and self._frames.shape == other._frames.shape
            and self._exposures.shape == other._exposures.shape
            and bool(torch.equal(self._frames.cpu(), other._frames.cpu()))
            and bool(torch.equal(self._exposures.cpu().double(), other._exposures.cpu().double()))
            and _metadata_equal(self._metadata, other._metadata)
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        shape = tuple(self._frames.shape)
        taus = self._exposures.tolist() if self._exposures.numel() <= 8 else f"{tuple(self._exposures.shape)}"
        dtype = str(self._frames.dtype).replace("torch.", "")
        cfa = f", cfa={self.cfa!r}" if self.cfa is not None else ""
        return (
            f"FrameStack(frames={shape} {dtype} on {self._frames.device}, exposures={taus}, bits={self._bits}, "
            f"kind={self._kind!r}{cfa})"
        )


def _check_stack_cfa(cfa: object, stored: object, shape: torch.Size) -> str | None:
    """The stack's pattern: ``cfa``, else the metadata's; checked against the frames' (B, M, C, H, W) shape."""
    if cfa is not None and stored is not None and cfa != stored:
        raise ValueError(f"cfa={cfa!r} disagrees with the metadata's cfa {stored!r}")
    pattern = cfa if cfa is not None else stored
    if pattern is None:
        return None
    pattern = check_cfa(pattern, "cfa" if cfa is not None else "metadata['cfa']")
    c, h, w = shape[-3:]
    if c != 1 or h % 2 or w % 2:
        raise ValueError(
            f"frames of a colour filter array (cfa={pattern!r}) must be mosaics with one channel and an even height "
            f"and width, (B, M, 1, H, W); got shape {tuple(shape)}"
        )
    return pattern


def _exposure_dtype(device: torch.device) -> torch.dtype:
    return torch.float32 if device.type == "mps" else torch.float64


def _metadata_equal(a: object, b: object) -> bool:
    """Equality that treats NaN as equal to NaN (metadata may hold NaN floats)."""
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_metadata_equal(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_metadata_equal(x, y) for x, y in zip(a, b, strict=True))
    return bool(a == b)
