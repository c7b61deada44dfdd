"""The single-shot methods by name: one registry entry per method, and the task that solves a group of planes.

A method is a :class:`~torch_modulo.singleshot.spec.Method`: its solver, its options (each with a default and a
check) and whether it solves the channels of an image together. :data:`REGISTRY` maps names to methods, and
everything else (the option checks of :func:`~torch_modulo.singleshot.unwrap_single`, the grouping of planes into
worker tasks, :data:`METHODS`) is derived from it, so a new method is one entry here.

A solver takes a group of planes: ``(moduli (G, H, W) int64, spec, one MoveStats per plane) -> restored
(G, H, W) int64``, where the group is one plane for the methods that solve every channel alone and all channels
of an image for the methods with ``joint_channels``. It may leave ``k`` with any global constant:
:func:`solve_group` anchors every plane afterwards (:func:`~torch_modulo.singleshot.anchor.anchor_k`) and records
the energy of every plane whose solver made no moves, so that every plane's info holds its energy.

A method may also have a tensor solver, ``(moduli (B, C, H, W) floating tensor, spec) -> (k (B, C, H, W) int64,
confidence (B, C, H, W) or None)`` on the input's device (``solve_tensor``):
:func:`~torch_modulo.singleshot.unwrap_single` then hands it the whole batch where it lies, with no worker pool, and
:func:`solve_on_device` anchors the result on the CPU.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Mapping
from types import MappingProxyType
from typing import Any

import numpy as np
import torch

from torch_modulo._checks import check_choice, check_flag, check_int, check_real
from torch_modulo.singleshot.anchor import anchor_k
from torch_modulo.singleshot.energy import EnergyParams
from torch_modulo.singleshot.graphcut import plane_energy, solve_fast, solve_pixels
from torch_modulo.singleshot.grid import pair_offsets
from torch_modulo.singleshot.learned.solver import LEARNED_OPTIONS, solve_learned, solve_learned_tensor
from torch_modulo.singleshot.lsq import LSQ_OPTIONS, solve_lsq, solve_lsq_tensor
from torch_modulo.singleshot.pathfollow import quality_guided_colour_k, quality_guided_k, residue_density
from torch_modulo.singleshot.spec import GroupSolver, Method, MoveStats, Option, SolverSpec, TensorSolver
from torch_modulo.singleshot.tiles import TILE_PIXELS, check_tile_pixels, tiled

__all__ = [
    "AUTO_RESIDUES",
    "METHODS",
    "REGISTRY",
    "RENAMED",
    "GroupSolver",
    "Method",
    "MoveStats",
    "Option",
    "SolverSpec",
    "TensorSolver",
    "fast_start",
    "make_spec",
    "solve_group",
    "solve_on_device",
    "solve_plane",
]

#: ``init="auto"`` of ``"fast"`` starts from path following when fewer than this share of 2 x 2 loops hold a
#: residue.
AUTO_RESIDUES = 1e-3


def _per_plane(solver: Callable[[np.ndarray, SolverSpec, MoveStats], np.ndarray]) -> GroupSolver:
    """Turn a one-plane solver into a group solver (each plane alone)."""

    def solve(moduli: np.ndarray, spec: SolverSpec, stats: list[MoveStats]) -> np.ndarray:
        return np.stack([solver(m, spec, st) for m, st in zip(moduli, stats, strict=True)])

    solve.__doc__ = solver.__doc__
    return solve


def _solve_paper(modulus: np.ndarray, spec: SolverSpec, stats: MoveStats) -> np.ndarray:
    """The paper (Sec. 4.2): from ``k = 0``, step-1 moves, then step ``sigma``, until the energy stops dropping."""
    offsets = pair_offsets(spec.neighborhood)
    return solve_pixels(modulus, spec.params, offsets, sigma=spec.sigma, max_iter=spec.max_iter, stats=stats)


def fast_start(modulus: np.ndarray, bits: int, init: str = "auto") -> np.ndarray:
    """The starting point of ``"fast"``: int64 ``modulus + k 2**bits`` for the ``init`` option.

    ``"zeros"``: ``k = 0`` (as the paper); ``"quality"``: path following
    (:func:`~torch_modulo.singleshot.pathfollow.quality_guided_k`); ``"auto"``: path following when the wrapped
    image has (almost) no residues (fewer than :data:`AUTO_RESIDUES` of its 2 x 2 loops), i.e. when it is smooth
    enough for path following to be right, else ``k = 0``.

    Example:
        >>> fast_start(np.array([[200, 10, 60]]), 8).tolist()  # smooth: path following
        [[200, 266, 316]]
    """
    restored = modulus.astype(np.int64)
    if init == "auto":
        init = "quality" if residue_density(modulus, bits) < AUTO_RESIDUES else "zeros"
    if init == "quality":
        restored = restored + (1 << bits) * quality_guided_k(modulus, bits)
    return restored


def _solve_fast(modulus: np.ndarray, spec: SolverSpec, stats: MoveStats) -> np.ndarray:
    """The paper's energy and moves on a cheaper schedule: :func:`fast_start`, then
    :func:`~torch_modulo.singleshot.graphcut.solve_fast` (global moves to ``rel_tol``, then tiles)."""
    p = spec.params
    return solve_fast(
        fast_start(modulus, p.bits, spec.option("init")),
        p,
        pair_offsets(spec.neighborhood),
        sigma=spec.sigma,
        max_iter=spec.max_iter,
        rel_tol=float(spec.option("rel_tol")),
        window=int(spec.option("window")),
        stats=stats,
    )


def _solve_guided(moduli: np.ndarray, spec: SolverSpec, stats: list[MoveStats]) -> np.ndarray:
    """Reliability-guided path following (Herraez et al. 2002), no graph cut; with ``colour`` the channels of an
    image share one tree whose reliabilities sum the second differences of all channels; ``denoise`` smooths the
    wrapped images first (:func:`~torch_modulo.singleshot.pathfollow.smooth_wrapped`)."""
    p = spec.params
    start = time.perf_counter()
    denoise = float(spec.option("denoise"))
    tile_pixels = int(spec.option("tile_pixels"))  # larger images build the tree in blocks (less memory)
    if spec.option("colour"):
        k = quality_guided_colour_k(moduli, p.bits, denoise, tile_pixels)
    else:
        k = np.empty(moduli.shape, dtype=np.int64)
        for ci, m in enumerate(moduli):
            k[ci] = quality_guided_colour_k(m[None], p.bits, denoise, tile_pixels)[0]
    restored = k  # moduli + k 2**bits, in place
    restored *= p.period
    restored += moduli
    for st in stats:
        st.tick("guided", start)
    return restored


def _check_window(value: object, name: str) -> int:
    window = check_int(value, name, 0)
    if window == 1:
        raise ValueError(f"{name} must be 0 (no local moves) or >= 2; got 1")
    return window


def _check_init(value: object, name: str) -> str:
    return check_choice(value, name, ("auto", "zeros", "quality"))


def _check_nonnegative(value: object, name: str) -> float:
    return check_real(value, name, 0)


#: The methods by name; :data:`METHODS` and every option check derive from it.
REGISTRY: Mapping[str, Method] = MappingProxyType(
    {
        "learned": Method(
            solve=solve_learned,
            solve_tensor=solve_learned_tensor,
            options={name: Option(default, check) for name, (default, check) in LEARNED_OPTIONS.items()},
            joint_channels=True,
        ),
        "guided": Method(
            solve=_solve_guided,
            options={
                "colour": Option(True, check_flag),
                "denoise": Option(0.0, _check_nonnegative),
                "tile_pixels": Option(TILE_PIXELS, check_tile_pixels),
            },
            joint_channels=True,
        ),
        "fast": Method(
            solve=tiled(_per_plane(_solve_fast)),  # in overlapping tiles above tile_pixels
            options={
                "init": Option("auto", _check_init),
                "rel_tol": Option(3e-4, _check_nonnegative),
                "window": Option(64, _check_window),
                "tile_pixels": Option(TILE_PIXELS, check_tile_pixels),
            },
        ),
        "paper": Method(solve=_per_plane(_solve_paper)),
        "lsq": Method(
            solve=solve_lsq,
            options={name: Option(default, check) for name, (default, check) in LSQ_OPTIONS.items()},
            solve_tensor=solve_lsq_tensor,
        ),
    }
)

#: The names of the methods, the default first.
METHODS: tuple[str, ...] = tuple(REGISTRY)


#: Options that were renamed, per method: old name -> new name (the old name still works, with a warning).
RENAMED: Mapping[str, Mapping[str, str]] = MappingProxyType({"fast": {"tile": "window"}})


def _check_options(method: str, options: Mapping[str, Any]) -> tuple[tuple[str, Any], ...]:
    allowed = REGISTRY[method].options
    renamed = RENAMED.get(method, {})
    if any(old in options for old in renamed):
        options = dict(options)
        for old, new in renamed.items():
            if old in options:
                warnings.warn(
                    f"option {old!r} of method {method!r} is deprecated; use {new!r}", DeprecationWarning, stacklevel=4
                )
                if new in options:
                    raise TypeError(f"method {method!r} got both {old!r} and its new name {new!r}")
                options[new] = options.pop(old)
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        known = ", ".join(sorted(allowed)) or "none"
        raise TypeError(f"method {method!r} does not take option(s) {', '.join(unknown)}; it takes: {known}")
    return tuple(sorted((name, allowed[name].check(value, name)) for name, value in options.items()))


def make_spec(
    bits: int,
    method: str,
    neighborhood: int,
    a1: float,
    a2: float,
    x0: float | None,
    sigma: int,
    max_iter: int,
    options: Mapping[str, Any],
) -> SolverSpec:
    """Check the settings of :func:`~torch_modulo.singleshot.unwrap_single` once and bundle them.

    Raises:
        TypeError: a setting of the wrong type, or an option the method does not take.
        ValueError: an unknown method or a value out of range.

    Example:
        >>> make_spec(8, "fast", 8, 0.1, 1e-5, None, 2, 1000, {"window": 32}).options
        (('window', 32),)
    """
    check_choice(method, "method", METHODS)
    params = EnergyParams.make(bits, a1, a2, x0)
    pair_offsets(neighborhood)
    return SolverSpec(
        method=method,
        params=params,
        neighborhood=int(neighborhood),
        sigma=check_int(sigma, "sigma", 1),
        max_iter=check_int(max_iter, "max_iter", 0),
        options=_check_options(method, options),
        defaults=tuple(sorted((name, option.default) for name, option in REGISTRY[method].options.items())),
    )


def solve_group(moduli: np.ndarray, spec: SolverSpec) -> list[tuple[np.ndarray, dict[str, Any]]]:
    """Solve a group of planes (one plane, or the channels of one image) and anchor each: the worker task.

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
    solved = REGISTRY[spec.method].solve(moduli, spec, stats)
    offsets = pair_offsets(spec.neighborhood)
    for plane, st in zip(solved, stats, strict=True):  # the energy of a solver that made no moves, once here
        if not st.energies:
            st.energies.append(plane_energy(plane, spec.params, offsets))
    return _anchor_and_report(moduli, solved, stats, spec, start)


def solve_on_device(moduli: torch.Tensor, spec: SolverSpec) -> list[tuple[np.ndarray, dict[str, Any]]]:
    """Solve a (B, C, H, W) batch with the method's tensor solver on its device, then anchor every plane on the CPU.

    Returns:
        One ``(restored, info)`` per plane, in (B, C) order, as :func:`solve_group` (``energies`` holds the energy
        of the returned counts, ``steps`` is empty, ``cuts`` 0), plus ``confidence``: the plane's (H, W) float64
        confidence where the method gives one.
    """
    start = time.perf_counter()
    h, w = moduli.shape[-2:]
    solve_tensor = REGISTRY[spec.method].solve_tensor
    if solve_tensor is None:
        raise ValueError(f"method {spec.method!r} has no tensor solver")
    k, confidence = solve_tensor(moduli.detach(), spec)
    solved = k.to("cpu", torch.int64).numpy().reshape(-1, h, w)  # turned into the counts in place
    planes = moduli.detach().to("cpu", torch.int64).numpy().reshape(-1, h, w)
    solved *= spec.params.period
    solved += planes
    out = _anchor_and_report(planes, solved, [MoveStats() for _ in planes], spec, start)
    maps = [None] * len(out) if confidence is None else confidence.to("cpu", torch.float64).numpy().reshape(-1, h, w)
    for (_, info), plane in zip(out, maps, strict=True):
        info["energies"] = [info["energy"]]
        if plane is not None:
            info["confidence"] = plane
    return out


def _anchor_and_report(
    moduli: np.ndarray, solved: np.ndarray, stats: list[MoveStats], spec: SolverSpec, start: float
) -> list[tuple[np.ndarray, dict[str, Any]]]:
    """Anchor every solved plane and gather its info (the second half of :func:`solve_group`)."""
    offsets = pair_offsets(spec.neighborhood)
    solved = np.asarray(solved, dtype=np.int64)
    if np.may_share_memory(solved, moduli):
        solved = solved.copy()
    out = []
    for modulus, restored, st in zip(moduli, solved, stats, strict=True):
        k = restored - modulus
        k //= spec.params.period
        k = anchor_k(k, spec.anchor_fraction, modulus=modulus, bits=spec.params.bits)
        np.multiply(k, spec.params.period, out=restored)  # in place: the planes returned are views of ``solved``
        restored += modulus
        del k
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
