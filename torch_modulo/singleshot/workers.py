"""Running many planes (images x channels) in worker processes.

Each (H, W) plane of a batch, or each image for the methods that solve its channels together, is an independent
problem. PyMaxflow holds the GIL during the max-flow, so threads do not help; tasks go to a process pool
instead. The design is spawn- and forkserver-safe: the task is the top-level
:func:`~torch_modulo.singleshot.methods.solve_group`, which takes numpy arrays and a frozen, picklable
:class:`~torch_modulo.singleshot.methods.SolverSpec` and returns numpy arrays and plain Python data. One worker,
one task, a small total, or a caller that may not start processes (a daemonic process such as a DataLoader
worker) runs in-process with no pool.
"""

from __future__ import annotations

import atexit
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from itertools import repeat
from typing import Any

import numpy as np

from torch_modulo._checks import check_int
from torch_modulo.singleshot.methods import SolverSpec, solve_group

__all__ = ["POOL_MIN_PIXELS", "check_workers", "default_workers", "run_planes", "shutdown_workers"]

#: Below this many pixels in all, ``workers=None`` solves in-process (starting a pool costs more).
POOL_MIN_PIXELS = 1 << 18


def check_workers(workers: object) -> int | None:
    """``None`` (choose by job size) or an integer >= 1; raises naming the value otherwise."""
    if workers is None:
        return None
    return check_int(workers, "workers", 1)


def default_workers(problems: int, pixels: int) -> int:
    """``min(problems, os.cpu_count())``, or 1 when the whole job is too small to pay for a pool.

    Example:
        >>> default_workers(8, 100)
        1
    """
    if problems <= 1 or pixels < POOL_MIN_PIXELS:
        return 1
    return max(1, min(problems, os.cpu_count() or 1))


_POOL: ProcessPoolExecutor | None = None
_POOL_SIZE = 0


def _pool(workers: int) -> ProcessPoolExecutor:
    """A process pool reused across calls (forkserver where available, else spawn)."""
    global _POOL, _POOL_SIZE
    if _POOL is None or _POOL_SIZE != workers:
        shutdown_workers()
        methods = multiprocessing.get_all_start_methods()
        context = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
        _POOL = ProcessPoolExecutor(max_workers=workers, mp_context=context)
        _POOL_SIZE = workers
    return _POOL


def shutdown_workers() -> None:
    """Stop the worker processes kept for later calls (they are stopped at exit anyway)."""
    global _POOL, _POOL_SIZE
    if _POOL is not None:
        _POOL.shutdown(wait=True, cancel_futures=True)
    _POOL, _POOL_SIZE = None, 0


atexit.register(shutdown_workers)


def run_planes(
    planes: list[np.ndarray] | np.ndarray, spec: SolverSpec, workers: int | None = None, group: int = 1
) -> list[tuple[np.ndarray, dict[str, Any]]]:
    """Solve independent planes, in worker processes when that pays.

    Args:
        planes: (H, W) integer-valued arrays, or one (P, H, W) array (whose tasks are then views, not copies).
        spec: the solver.
        workers: number of processes; ``None`` picks :func:`default_workers`; 1 runs in-process, and so does
            any value inside a daemonic process (which may not have children).
        group: planes per task, in order (the channels of an image for the methods with ``joint_channels``).

    Returns:
        One ``(restored, info)`` per plane, in order.
    """
    if len(planes) == 0:
        return []
    group = max(1, int(group))
    tasks = [np.asarray(planes[i : i + group]) for i in range(0, len(planes), group)]
    if workers is None:
        workers = default_workers(len(tasks), sum(int(p.size) for p in planes))
    workers = max(1, min(int(workers), len(tasks)))
    if workers == 1 or multiprocessing.current_process().daemon:
        return [r for task in tasks for r in solve_group(task, spec)]
    try:
        return [r for out in _pool(workers).map(solve_group, tasks, repeat(spec)) for r in out]
    except Exception:
        # A broken pool (a worker was killed) is not reused.
        shutdown_workers()
        raise
