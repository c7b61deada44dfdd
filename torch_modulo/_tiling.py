"""CPU tiling shared by the element-wise kernels (capture, multi-shot merge, tone mapping).

On the CPU, a kernel that chains several in-place operations over a large tensor is faster when it runs them on
one cache-sized tile at a time: each tile and its scratch buffers stay in cache, so the data crosses main memory
once, and no full-size temporaries are allocated and faulted in. Each operation on a tile still runs on
PyTorch's intra-op threads, because a tile is several times PyTorch's grain size.

The kernels view their input as ``(rows, n)`` (one row per batch item, exposure or channel) and walk over column
slices of it.
"""

from __future__ import annotations

import torch

__all__ = ["CPU_TILE", "column_tiles", "tile_on_cpu"]

#: Elements per tile for a kernel that keeps one output tile and one scratch tile: small enough that both stay in
#: cache, large enough that each operation on a tile is split over PyTorch's threads. Kernels that keep more
#: buffers per tile pass a fraction of it to :func:`column_tiles`.
CPU_TILE = 1 << 19


def column_tiles(n: int, rows: int, *, tile: int = CPU_TILE, min_width: int = 1024) -> list[slice]:
    """Column slices of a ``(rows, n)`` array, each holding about ``tile`` elements and at least ``min_width`` columns.

    Args:
        n: number of columns.
        rows: number of rows (at least 1 is assumed).
        tile: elements per tile.
        min_width: fewest columns per tile (keeps very tall arrays from being cut into slivers).

    Returns:
        Consecutive slices covering ``range(n)``; empty when ``n == 0``.

    Example:
        >>> column_tiles(10, 2, tile=8, min_width=1)
        [slice(0, 4, None), slice(4, 8, None), slice(8, 10, None)]
    """
    width = max(min_width, tile // max(rows, 1), 1)
    return [slice(start, min(start + width, n)) for start in range(0, n, width)]


def tile_on_cpu(*tensors: torch.Tensor) -> bool:
    """Whether to take a tiled, in-place CPU path: every tensor is on the CPU and autograd does not track them."""
    if not all(t.device.type == "cpu" for t in tensors):
        return False
    return not (torch.is_grad_enabled() and any(t.requires_grad for t in tensors))
