"""CPU chunks shared by the element-wise kernels (capture, multi-shot counting, tone mapping).

On the CPU, a kernel that chains several in-place operations over a large tensor is faster when it runs them on
one cache-sized chunk at a time: each chunk and its scratch buffers stay in cache, so the data crosses main memory
once, and no full-size temporaries are allocated and faulted in. Each operation on a chunk still runs on
PyTorch's intra-op threads, because a chunk is several times PyTorch's grain size.

The kernels view their input as ``(rows, n)`` (one row per batch item, exposure or channel) and walk over column
slices of it, the chunks. (A "tile", elsewhere in the package, is a block of an image, as in CLAHE's grid.)
"""

from __future__ import annotations

import torch

__all__ = ["CPU_CHUNK", "chunk_on_cpu", "column_chunks"]

#: Elements per chunk for a kernel that keeps one output chunk and one scratch chunk: small enough that both stay
#: in cache, large enough that each operation on a chunk is split over PyTorch's threads. Kernels that keep more
#: buffers per chunk pass a fraction of it to :func:`column_chunks`.
CPU_CHUNK = 1 << 19


def column_chunks(n: int, rows: int, *, chunk: int = CPU_CHUNK, min_width: int = 1024) -> list[slice]:
    """Column slices of a ``(rows, n)`` array, each holding about ``chunk`` elements and at least ``min_width``
    columns.

    Args:
        n: number of columns.
        rows: number of rows (at least 1 is assumed).
        chunk: elements per chunk.
        min_width: fewest columns per chunk (keeps very tall arrays from being cut into slivers).

    Returns:
        Consecutive slices covering ``range(n)``; empty when ``n == 0``.

    Example:
        >>> column_chunks(10, 2, chunk=8, min_width=1)
        [slice(0, 4, None), slice(4, 8, None), slice(8, 10, None)]
    """
    width = max(min_width, chunk // max(rows, 1), 1)
    return [slice(start, min(start + width, n)) for start in range(0, n, width)]


def chunk_on_cpu(*tensors: torch.Tensor) -> bool:
    """Whether to take a chunked, in-place CPU path: every tensor is on the CPU and autograd does not track them."""
    if not all(t.device.type == "cpu" for t in tensors):
        return False
    return not (torch.is_grad_enabled() and any(t.requires_grad for t in tensors))
