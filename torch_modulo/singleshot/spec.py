"""The shapes every single-shot method shares: its registry entry, the settings of a solve, what a solver reports.

A method is a :class:`Method`: its solver, its options (each an :class:`Option` with a default and a check) and
whether it solves the channels of an image together; :data:`~torch_modulo.singleshot.methods.REGISTRY` maps names to
methods. A :class:`SolverSpec` carries everything a worker needs to solve one group of planes, and a solver reports
what it did on each plane in a :class:`MoveStats`.

A group solver takes ``(moduli (G, H, W) int64, spec, one MoveStats per plane) -> restored (G, H, W) int64``; a
tensor solver ``(moduli (B, C, H, W) floating tensor, spec) -> (k (B, C, H, W) int64, confidence or None)`` on the
input's device (see :mod:`torch_modulo.singleshot.methods`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from torch_modulo.singleshot.energy import EnergyParams

__all__ = ["GroupSolver", "Method", "MoveStats", "Option", "SolverSpec", "TensorSolver"]


@dataclass
class MoveStats:
    """What a solver did on one plane: the data of the paper's Fig. 5b and 6.

    Attributes:
        energies: the energy before the first move and after every accepted move (a solver that makes no moves
            leaves it empty: the registry's solve step then records the energy of its result).
        steps: the step (1 or ``sigma``) of every accepted move.
        cuts: the number of minimum cuts solved (accepted or not).
        nodes: the number of graph nodes of every cut.
        seconds: wall time spent, per stage name.
        stop: why the last global phase stopped: ``"converged"`` (no move with step 1 or ``sigma`` lowers the
            energy: the paper's rule), ``"rel_tol"`` or ``"max_iter"``.
    """

    energies: list[float] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)
    cuts: int = 0
    nodes: list[int] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)
    stop: str = ""

    @property
    def iterations(self) -> int:
        """Accepted moves."""
        return len(self.steps)

    def tick(self, stage: str, start: float) -> float:
        """Add the time since ``start`` (a ``time.perf_counter()`` reading) to ``stage``; return the time now."""
        now = time.perf_counter()
        self.seconds[stage] = self.seconds.get(stage, 0.0) + now - start
        return now


@dataclass(frozen=True)
class Option:
    """One option of a method.

    Attributes:
        default: the value used when the caller does not give one.
        check: ``check(value, name)`` returns the value normalised (e.g. ``np.float32`` to ``float``) or raises
            ``TypeError`` / ``ValueError`` naming it (the checks of ``torch_modulo._checks``).
    """

    default: Any
    check: Callable[[Any, str], Any]


@dataclass(frozen=True)
class SolverSpec:
    """Everything a worker needs to solve one group of planes (picklable).

    Attributes:
        method: a key of :data:`~torch_modulo.singleshot.methods.REGISTRY`.
        params: the potential of Eq. 5.
        neighborhood: 8 or 4.
        sigma: the paper's larger step (1 disables it).
        max_iter: the most global cuts.
        options: method-specific options the caller chose, as sorted ``(name, value)`` pairs (checked by
            :func:`~torch_modulo.singleshot.methods.make_spec`).
        anchor_fraction: the smallest region (share of the pixels) that may anchor ``k = 0`` (see
            :func:`~torch_modulo.singleshot.anchor.anchor_k`: small regions anchor only with mostly smooth
            borders).
        defaults: the method's default of every option, as sorted ``(name, value)`` pairs.
    """

    method: str
    params: EnergyParams
    neighborhood: int = 8
    sigma: int = 2
    max_iter: int = 1000
    options: tuple[tuple[str, Any], ...] = field(default_factory=tuple)
    anchor_fraction: float = 1e-3
    defaults: tuple[tuple[str, Any], ...] = field(default_factory=tuple)

    def option(self, name: str) -> Any:
        """The value of option ``name``: the caller's, else the method's default.

        Raises:
            KeyError: the method has no option ``name``.
        """
        chosen = dict(self.options)
        return chosen[name] if name in chosen else dict(self.defaults)[name]


#: ``(moduli (G, H, W) int64, spec, one MoveStats per plane) -> restored (G, H, W) int64``.
GroupSolver = Callable[[np.ndarray, SolverSpec, list[MoveStats]], np.ndarray]

#: ``(moduli (B, C, H, W) floating tensor, spec) -> (k (B, C, H, W) int64, confidence or None)``, on the input's
#: device, not anchored; the confidence (B, C, H, W) in ``(0, 1]`` is the method's own, where it has one.
TensorSolver = Callable[[torch.Tensor, SolverSpec], tuple[torch.Tensor, torch.Tensor | None]]


@dataclass(frozen=True)
class Method:
    """A registry entry: how a method solves, and what it accepts.

    Attributes:
        solve: the group solver.
        options: the method's options by name.
        joint_channels: the solver takes all channels of an image at once (else one plane at a time).
        solve_tensor: a solver of whole batches on their device, used by ``unwrap_single`` instead of ``solve``
            (which then serves :func:`~torch_modulo.singleshot.methods.solve_group` alone).
    """

    solve: GroupSolver
    options: Mapping[str, Option] = field(default_factory=dict)
    joint_channels: bool = False
    solve_tensor: TensorSolver | None = None
