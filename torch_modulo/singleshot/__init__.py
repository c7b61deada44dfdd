"""Single-shot unwrapping (paper Sec. 4): recover the counts ``I = I_m + k 2^N`` from one modulus image.

:func:`unwrap_single` (and its module twin :class:`SingleShotUnwrap`) chooses the rollover counts ``k`` with one of
the methods of :data:`METHODS`:

- ``"learned"`` (default): a small network (weights shipped in the package) predicts the rollover jump of every
  neighbour pair, the channels of a colour image seen together; an exact integer decoder (most likely spanning
  tree, optionally min-cut moves) turns it into ``k`` (:mod:`torch_modulo.singleshot.learned`); a small head's
  level costs (per 2 x 2 block) then move whole regions by whole periods (option ``levels``,
  :mod:`torch_modulo.singleshot.learned.levels`). The network runs on the input's device, the decoding on the CPU.
- ``"guided"``: reliability-guided path following (Herraez et al. 2002) without a graph cut, the channels of a
  colour image on one shared tree, so that a step that is steep in one channel is avoided in all
  (:mod:`torch_modulo.singleshot.pathfollow`); several times faster than ``"learned"`` on the CPU. Under strong
  noise in the low bits pass ``denoise=0.7`` (or use ``"fast"``).
- ``"fast"``: the paper's energy (Eqs. 3-5, :mod:`torch_modulo.singleshot.energy`) and binary graph-cut moves
  (:mod:`torch_modulo.singleshot.graphcut`) on a cheaper schedule: start from path following when the wrapped
  image is smooth (no residues), else from ``k = 0``; global moves until one gains less than ``rel_tol`` of the
  energy; then local moves in small windows.
- ``"paper"``: the paper's algorithm as published: from ``k = 0``, moves ``k <- k + delta`` while the energy
  drops, then step ``sigma``; non-representable pair terms lose their pairwise edge (PUMA).
- ``"lsq"``: least-squares integration of the wrapped differences with the DCT (Ghiglia and Romero 1994), a few
  rounds of reweighting, then snapped to ``I_m + k 2^N``; in torch on the input's device, the whole batch at once
  (:mod:`torch_modulo.singleshot.lsq`).

:func:`unwrap_single` and :class:`SingleShotUnwrap` live in :mod:`torch_modulo.singleshot.unwrap`. Methods are
entries of :data:`torch_modulo.singleshot.methods.REGISTRY` (solver, options, whether the channels of an image are
solved together; the shared types in :mod:`torch_modulo.singleshot.spec`). The images and channels of a batch are
solved in worker processes (:mod:`torch_modulo.singleshot.workers`), except by the methods with a tensor solver
(``"lsq"``, ``"learned"``), which solve the batch on its device. docs/singleshot.md has the measurements.

Unwrapping fixes ``k`` up to one constant per image and channel; the output puts the darkest large connected
region at ``k = 0`` and no pixel below it (``k >= 0``, :mod:`torch_modulo.singleshot.anchor`).
:func:`unwrap_confidence` tells, per pixel, whether the level of a result is determined by the data or guessed
(:mod:`torch_modulo.singleshot.confidence`).
"""

from __future__ import annotations

from torch_modulo.singleshot.confidence import UnwrapConfidence, unwrap_confidence
from torch_modulo.singleshot.energy import Potential, UnwrapEnergy, is_representable, potential, unwrap_energy
from torch_modulo.singleshot.learned import LearnedConfidence, learned_confidence
from torch_modulo.singleshot.methods import METHODS
from torch_modulo.singleshot.unwrap import SingleShotInfo, SingleShotUnwrap, unwrap_single
from torch_modulo.singleshot.workers import shutdown_workers

__all__ = [
    "METHODS",
    "LearnedConfidence",
    "Potential",
    "SingleShotInfo",
    "SingleShotUnwrap",
    "UnwrapConfidence",
    "UnwrapEnergy",
    "is_representable",
    "learned_confidence",
    "potential",
    "shutdown_workers",
    "unwrap_confidence",
    "unwrap_energy",
    "unwrap_single",
]
