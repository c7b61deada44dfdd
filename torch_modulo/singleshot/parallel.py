"""Solvers by name, and running many planes (images x channels) in worker processes.

Each (H, W) plane of a batch is an independent problem. PyMaxflow holds the GIL during the max-flow, so
threads do not help (measured 1.0x with two threads, 1.96x with two processes, ../shared/DESIGN.md); planes
go to a process pool instead. The design is spawn- and forkserver-safe: the task is a top-level function
that takes numpy arrays and a frozen, picklable :class:`SolverSpec`, and returns numpy arrays and plain
Python data. One worker, one plane or a small total runs in-process with no pool.

Methods are registered in :data:`METHODS` (name -> solver); new methods add an entry and, if they take
options, an entry in :data:`METHOD_OPTIONS`. A solver takes a group of planes: one plane for the methods that
solve every channel alone, all channels of an image for the methods in :data:`JOINT_CHANNELS`.
"""

from __future__ import annotations

import atexit
import multiprocessing
import os
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from itertools import repeat
from typing import Any

import numpy as np

from torch_modulo.singleshot.energy import EnergyParams, pair_offsets
from torch_modulo.singleshot.graphcut import (
    MoveStats,
    anchor_k,
    plane_energy,
    solve_contracted,
    solve_pixels,
    solve_tiles,
)
from torch_modulo.singleshot.init import quality_guided_colour_k, quality_guided_k, residue_density

__all__ = [
    "JOINT_CHANNELS",
    "METHODS",
    "METHOD_OPTIONS",
    "SolverSpec",
    "default_workers",
    "run_planes",
    "shutdown_workers",
    "solve_group",
    "solve_plane",
]

#: Below this many pixels in all, ``workers=None`` solves in-process (starting a pool costs more).
POOL_MIN_PIXELS = 1 << 18

#: ``init="auto"`` starts from path following when fewer than this share of 2 x 2 loops hold a residue.
AUTO_RESIDUES = 1e-3


@dataclass(frozen=True)
class SolverSpec:
    """Everything a worker needs to solve one plane (picklable).

    Attributes:
        method: a key of :data:`METHODS`.
        params: the potential of Eq. 5.
        neighborhood: 8 or 4.
        sigma: the paper's larger step (1 disables it).
        max_iter: the most global cuts.
        options: method-specific options as sorted ``(name, value)`` pairs.
        anchor_fraction: the smallest region (share of the pixels) that may anchor ``k = 0`` (see
            :func:`~torch_modulo.singleshot.graphcut.anchor_k`: regions under 3% anchor only with mostly smooth
            borders).
    """

    method: str
    params: EnergyParams
    neighborhood: int = 8
    sigma: int = 2
    max_iter: int = 1000
    options: tuple[tuple[str, Any], ...] = field(default_factory=tuple)
    anchor_fraction: float = 1e-3

    def option(self, name: str) -> Any:
        return dict(self.options).get(name, METHOD_OPTIONS[self.method][name])


def _solve_paper(modulus: np.ndarray, spec: SolverSpec, stats: MoveStats) -> np.ndarray:
    """The paper (Sec. 4.2): from ``k = 0``, step-1 moves, then step ``sigma``, until the energy stops dropping."""
    offsets = pair_offsets(spec.neighborhood)
    return solve_pixels(modulus, spec.params, offsets, sigma=spec.sigma, max_iter=spec.max_iter, stats=stats)


def _solve_fast(modulus: np.ndarray, spec: SolverSpec, stats: MoveStats) -> np.ndarray:
    """The paper's energy and moves on a cheaper schedule (see docs/singleshot.md).

    1. start from ``init``: ``"zeros"`` (``k = 0``, as the paper), ``"quality"`` (reliability-guided path following)
       or ``"auto"``: path following when the wrapped image has (almost) no residues, i.e. it is smooth enough for
       path following to be right, else ``k = 0``;
    2. optionally (``contract``) run the moves on region graphs first;
    3. global pixel moves as in the paper, but stop once a move gains less than ``rel_tol`` of the energy;
    4. if that stopped early, finish with local moves in ``tile`` x ``tile`` tiles (up and down) until none helps.
    """
    p = spec.params
    offsets = pair_offsets(spec.neighborhood)
    restored = modulus.astype(np.int64)
    init = spec.option("init")
    if init == "auto":
        init = "quality" if residue_density(modulus, p.bits) < AUTO_RESIDUES else "zeros"
    if init == "quality":
        restored = restored + p.period * quality_guided_k(modulus, p.bits)
    if spec.option("contract"):
        restored = solve_contracted(
            restored, p, offsets, link=p.period // 2, band=1, block=32, sigma=spec.sigma, stats=stats
        )
    rel_tol = float(spec.option("rel_tol"))
    restored = solve_pixels(
        restored, p, offsets, sigma=spec.sigma, max_iter=spec.max_iter, rel_tol=rel_tol, stats=stats
    )
    tile = int(spec.option("tile"))
    if tile > 0 and stats.stop != "converged":
        restored = solve_tiles(restored, p, offsets, tile=tile, sigma=spec.sigma, stats=stats)
    return restored


def _solve_guided(moduli: np.ndarray, spec: SolverSpec, stats: list[MoveStats]) -> np.ndarray:
    """Reliability-guided path following (Herraez et al. 2002), no graph cut; with ``colour`` the channels of an
    image share one tree whose reliabilities sum the second differences of all channels; ``denoise`` smooths the
    wrapped images first (:func:`~torch_modulo.singleshot.init.smooth_wrapped`)."""
    p = spec.params
    start = time.perf_counter()
    denoise = float(spec.option("denoise"))
    if spec.option("colour"):
        k = quality_guided_colour_k(moduli, p.bits, denoise)
    else:
        k = np.stack([quality_guided_colour_k(m[None], p.bits, denoise)[0] for m in moduli])
    restored = moduli + p.period * k
    for plane, st in zip(restored, stats, strict=True):
        st.energies.append(plane_energy(plane, p, pair_offsets(spec.neighborhood)))
        st.tick("guided", start)
    return restored


def _per_plane(
    solver: Callable[[np.ndarray, SolverSpec, MoveStats], np.ndarray],
) -> Callable[[np.ndarray, SolverSpec, list[MoveStats]], np.ndarray]:
    """Turn a one-plane solver into a group solver (each plane alone)."""

    def solve(moduli: np.ndarray, spec: SolverSpec, stats: list[MoveStats]) -> np.ndarray:
        return np.stack([solver(m, spec, st) for m, st in zip(moduli, stats, strict=True)])

    solve.__doc__ = solver.__doc__
    return solve


#: Solver functions by method name: ``(moduli (G, H, W) int64, spec, one MoveStats per plane) -> restored
#: (G, H, W) int64``.
METHODS: dict[str, Callable[[np.ndarray, SolverSpec, list[MoveStats]], np.ndarray]] = {
    "paper": _per_plane(_solve_paper),
    "fast": _per_plane(_solve_fast),
    "guided": _solve_guided,
}

#: Methods whose task is a whole image (all its channels together); the others get one plane per task.
JOINT_CHANNELS: frozenset[str] = frozenset({"guided"})

#: Options each method accepts, with their defaults.
METHOD_OPTIONS: dict[str, dict[str, Any]] = {
    "paper": {},
    "fast": {"init": "auto", "rel_tol": 3e-4, "tile": 64, "contract": False},
    "guided": {"colour": True, "denoise": 0.0},
}


def solve_group(moduli: np.ndarray, spec: SolverSpec) -> list[tuple[np.ndarray, dict[str, Any]]]:
    """Solve a group of planes (one plane, or the channels of one image): the worker task.

    Top-level, numpy in, numpy and plain data out.

    Args:
        moduli: (G, H, W) integer-valued array in ``[0, 2**bits)``.
        spec: what to solve and how.

    Returns:
        One ``(restored, info)`` per plane: the restored counts (int64, ``k >= 0``, darkest large region at
        ``k = 0``) and a dict with ``energies`` (before the first move and after each accepted one), ``steps``,
        ``cuts``, ``seconds`` (the group's wall time, split evenly over its planes) and ``energy`` (of the
        returned counts).
    """
    start = time.perf_counter()
    moduli = np.asarray(moduli, dtype=np.int64)
    stats = [MoveStats() for _ in moduli]
    solved = METHODS[spec.method](moduli, spec, stats)
    offsets = pair_offsets(spec.neighborhood)
    out = []
    for modulus, restored, st in zip(moduli, solved, stats, strict=True):
        k = anchor_k(
            (restored - modulus) // spec.params.period, spec.anchor_fraction, modulus=modulus, bits=spec.params.bits
        )
        restored = modulus + spec.params.period * k
        out.append(
            (
                restored,
                {
                    "energies": [float(e) for e in st.energies],
                    "steps": [int(s) for s in st.steps],
                    "cuts": int(st.cuts),
                    "energy": float(plane_energy(restored, spec.params, offsets)),
                },
            )
        )
    seconds = (time.perf_counter() - start) / max(1, len(out))
    for _, info in out:
        info["seconds"] = seconds
    return out


def solve_plane(modulus: np.ndarray, spec: SolverSpec) -> tuple[np.ndarray, dict[str, Any]]:
    """Solve one (H, W) plane (see :func:`solve_group`)."""
    return solve_group(np.asarray(modulus)[None], spec)[0]


def default_workers(problems: int, pixels: int) -> int:
    """``min(problems, os.cpu_count())``, or 1 when the whole job is too small to pay for a pool."""
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
    planes: list[np.ndarray], spec: SolverSpec, workers: int | None = None, group: int = 1
) -> list[tuple[np.ndarray, dict[str, Any]]]:
    """Solve independent planes, in worker processes when that pays.

    Args:
        planes: (H, W) integer-valued arrays.
        spec: the solver.
        workers: number of processes; ``None`` picks :func:`default_workers`; 1 runs in-process.
        group: planes per task, in order (the channels of an image for the methods in :data:`JOINT_CHANNELS`).

    Returns:
        One ``(restored, info)`` per plane, in order.
    """
    if not planes:
        return []
    group = max(1, int(group))
    tasks = [np.stack(planes[i : i + group]) for i in range(0, len(planes), group)]
    if workers is None:
        workers = default_workers(len(tasks), sum(int(p.size) for p in planes))
    workers = max(1, min(int(workers), len(tasks)))
    if workers == 1:
        return [r for task in tasks for r in solve_group(task, spec)]
    try:
        return [r for out in _pool(workers).map(solve_group, tasks, repeat(spec)) for r in out]
    except Exception:
        # A broken pool (a worker was killed) is not reused.
        shutdown_workers()
        raise
