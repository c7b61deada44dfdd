"""What every tone-mapping operator shares: input validation, luminance, the sRGB encoding and the chunked CPU path.

The chunked CPU path (no autograd, CPU tensor) reads the batch once for its statistics, then maps it chunk by
chunk through cache-sized scratch buffers with in-place arithmetic and one write of the output; each operation on
a chunk runs on PyTorch's intra-op threads (see :mod:`torch_modulo._chunks`). Under ``torch.compile`` the operators
take their whole-tensor path instead, which the compiler fuses.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import kornia
import torch

from torch_modulo._checks import (
    check_floating,
    check_has_values,
    check_image_shape,
    check_nonnegative,
    check_real,
    like_memory_format,
    validation_enabled,
)
from torch_modulo._chunks import CPU_CHUNK, chunk_on_cpu, column_chunks

__all__ = ["REC709_LUMA", "luminance"]

#: Luminance weights of linear Rec.709 (sRGB) primaries: ``Y = 0.2126 R + 0.7152 G + 0.0722 B``.
REC709_LUMA: tuple[float, float, float] = (0.2126, 0.7152, 0.0722)

#: Elements per chunk: these kernels keep several (B, n) buffers per chunk, so they take half the shared chunk size.
CHUNK = CPU_CHUNK // 2


def as_batch(hdr: object, name: str = "hdr") -> tuple[torch.Tensor, torch.Size]:
    """Validate an HDR image and return it as (B, C, H, W), in the default (contiguous) memory format, with its
    original shape.

    The operators compute in that one layout, so their values do not depend on how the caller's images are stored
    (SIMD kernels round differently in another element order); :func:`restore` gives the result back in the input's
    format. The value check (finite, non-negative) is skipped with :func:`torch_modulo.validation` off.
    """
    x = check_floating(hdr, name)
    check_image_shape(x, name, 2, 4)
    check_has_values(x, name)  # every operator reads the image's statistics, with the checks on or off
    shape = x.shape
    if x.dim() == 2:
        x = x[None, None]
    elif x.dim() == 3:
        x = x[None]
    x = x.contiguous()  # a copy only for channels-last input; see the docstring
    if x.shape[1] not in (1, 3):
        raise ValueError(
            f"{name} must have 1 (grey) or 3 (linear Rec.709 RGB) channels; got {x.shape[1]} in shape {tuple(shape)}"
        )
    if validation_enabled() and x.numel():
        # One fused pass: NaN propagates through min/max, infinities show as extremes.
        lo, hi = torch.aminmax(x.detach())
        lo_f, hi_f = float(lo), float(hi)
        if not (math.isfinite(lo_f) and math.isfinite(hi_f)) or lo_f < 0:
            check_nonnegative(x.detach(), name)
    return x, shape


#: Dtypes too narrow for the operators' arithmetic: float16 overflows at 65504 and keeps 11 significant bits,
#: bfloat16 keeps 8. Input of these dtypes is mapped in float32 and the result cast back (:func:`widened`).
WIDEN: tuple[torch.dtype, ...] = (torch.float16, torch.bfloat16)


def widened(x: torch.Tensor) -> torch.Tensor:
    """``x`` in float32 if its dtype is in :data:`WIDEN` (a differentiable copy), else ``x`` itself.

    The operators that use it compute their statistics and mapping in the wider dtype and cast the display values
    back to the input's dtype: those are in ``[0, 1]``, so the cast loses only the last bits.
    """
    return x.float() if x.dtype in WIDEN else x


def needs_grad(x: torch.Tensor) -> bool:
    return torch.is_grad_enabled() and x.requires_grad


def chunked(x: torch.Tensor) -> bool:
    """Whether to take the in-place CPU path (no autograd, CPU tensor, not traced by ``torch.compile``)."""
    return chunk_on_cpu(x) and not torch.compiler.is_compiling()


def pixel_chunks(n: int, rows: int) -> list[slice]:
    """Slices of the ``n`` pixels of a (rows, n) view, each chunk holding about :data:`CHUNK` elements."""
    return column_chunks(n, rows, chunk=CHUNK, min_width=64)


def encode(out: torch.Tensor, srgb: bool) -> torch.Tensor:
    """Optionally apply the sRGB transfer function (values stay in [0, 1])."""
    if not srgb:
        return out
    if out.shape[1] == 1:
        return kornia.color.linear_rgb_to_rgb(out.expand(-1, 3, -1, -1))[:, :1].clamp(0.0, 1.0)
    return kornia.color.linear_rgb_to_rgb(out).clamp(0.0, 1.0)


def luminance(image: torch.Tensor) -> torch.Tensor:
    """Luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B`` of (B, 3, H, W) linear RGB, or the grey channel itself.

    Args:
        image: (B, C, H, W) with C = 1 or 3 (no value checks).

    Returns:
        (B, 1, H, W) luminance on the input's device and dtype.

    Example:
        >>> luminance(torch.ones(1, 3, 1, 2))
        tensor([[[[1., 1.]]]])
    """
    if image.dim() != 4 or image.shape[1] not in (1, 3):
        raise ValueError(f"image must have shape (B, 1, H, W) or (B, 3, H, W); got {tuple(image.shape)}")
    if image.shape[1] == 1:
        return image
    r, g, b = image[:, 0:1], image[:, 1:2], image[:, 2:3]
    return r * REC709_LUMA[0] + g * REC709_LUMA[1] + b * REC709_LUMA[2]


def _luminance_chunk(chunk: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """Luminance of a (B, C, n) chunk written into the (B, n) buffer ``out``."""
    if chunk.shape[1] == 1:
        return out.copy_(chunk[:, 0])
    torch.mul(chunk[:, 0], REC709_LUMA[0], out=out)
    out.add_(chunk[:, 1], alpha=REC709_LUMA[1])
    return out.add_(chunk[:, 2], alpha=REC709_LUMA[2])


#: A chunk kernel turns luminance (B, n) into the factor that scales R, G, B, using scratch buffers (B, n).
ChunkKernel = Callable[[torch.Tensor, list[torch.Tensor]], torch.Tensor]


def map_chunked(x: torch.Tensor, kernel: ChunkKernel, n_scratch: int, index_scratch: bool = False) -> torch.Tensor:
    """CPU path: ``out = clip(x * kernel(Y), 0, 1)`` chunk by chunk through cache-sized scratch buffers."""
    b, c, h, w = x.shape
    n = h * w
    x3 = x.reshape(b, c, n)
    out = torch.empty((b, c, h, w), dtype=x.dtype, device=x.device)
    o3 = out.view(b, c, n)
    chunks = pixel_chunks(n, b)
    step = chunks[0].stop if chunks else 0
    y = torch.empty((b, step), dtype=x.dtype, device=x.device)
    scratch = [torch.empty((b, step), dtype=x.dtype, device=x.device) for _ in range(n_scratch)]
    if index_scratch:
        scratch.append(torch.empty((b, step), dtype=torch.long, device=x.device))
    for cols in chunks:
        m = cols.stop - cols.start
        part = x3[:, :, cols]
        ratio = kernel(_luminance_chunk(part, y[:, :m]), [buf[:, :m] for buf in scratch])
        for ch in range(c):
            torch.mul(part[:, ch], ratio, out=o3[:, ch, cols]).clamp_(0.0, 1.0)
    return out


def luminance_stats_chunked(x: torch.Tensor, log_offset: float | None) -> tuple[torch.Tensor, torch.Tensor | None]:
    """One read of the batch: per-image max luminance and, if ``log_offset`` is given, sum of log(Y + offset).

    Partial results are kept per chunk and added in chunk order, so the result does not depend on threading.
    """
    b, c, h, w = x.shape
    n = h * w
    x3 = x.reshape(b, c, n)
    chunks = pixel_chunks(n, b)
    step = chunks[0].stop if chunks else 0
    maxima = torch.zeros((len(chunks), b), dtype=x.dtype, device=x.device)
    sums = None if log_offset is None else torch.zeros((len(chunks), b), dtype=torch.float64, device=x.device)
    y = torch.empty((b, step), dtype=x.dtype, device=x.device)
    for i, cols in enumerate(chunks):
        yt = _luminance_chunk(x3[:, :, cols], y[:, : cols.stop - cols.start])
        torch.amax(yt, dim=1, out=maxima[i])
        if sums is not None and log_offset is not None:
            torch.sum(yt.add_(log_offset).log_(), dim=1, dtype=torch.float64, out=sums[i])
    return maxima.amax(dim=0), None if sums is None else sums.sum(dim=0)


def col(v: torch.Tensor) -> torch.Tensor:
    """(B,) -> (B, 1) for broadcasting against (B, n) chunks."""
    return v.reshape(-1, 1)


def img(v: torch.Tensor) -> torch.Tensor:
    """(B,) -> (B, 1, 1, 1) for broadcasting against (B, C, H, W)."""
    return v.reshape(-1, 1, 1, 1)


def restore(out: torch.Tensor, shape: torch.Size, like: torch.Tensor | None = None) -> torch.Tensor:
    """Give a (B, C, H, W) result the caller's original shape, and the memory format of ``like`` (the input) when
    its images are stored channels last."""
    out = out.reshape(shape)
    return out if like is None else like_memory_format(out, like)


#: Range of ``exposure`` (in stops) for the gamma and logarithmic mappings: ``2**exposure`` is then a normal
#: float64, neither overflowing to infinity nor vanishing.
EXPOSURE_STOPS: tuple[int, int] = (-1022, 1023)


def check_exposure_stops(exposure: object) -> float:
    """Validate an exposure adjustment in stops (a finite real number within :data:`EXPOSURE_STOPS`)."""
    value = check_real(exposure, "exposure")
    low, high = EXPOSURE_STOPS
    return check_real(value, "exposure", low, high=high, what=f"within [{low}, {high}] stops")
