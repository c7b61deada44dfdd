"""Learned single-shot unwrapping: a small network predicts every neighbour step, an exact integer decoder picks ``k``.

``method="learned"`` of :func:`~torch_modulo.singleshot.unwrap_single`. Smoothness alone cannot tell a step of
``d`` counts from one of ``d + 2^N``; what can is knowledge of natural HDR scenes (a lamp is brighter than the wall
around it, a sky brighter than the ground). The package holds one role per module, each importing only those
before it:

- :mod:`~torch_modulo.singleshot.learned.network`: the networks (:class:`EdgeJumpNet`, predicting for every
  horizontal and vertical pair a distribution over the integer *jump* ``n`` in
  ``I_j - I_i = w(I_m,j - I_m,i) + n 2^N``; :class:`LevelNet`, a level head on its encoder) and their shipped
  weights, loaded offline (:func:`load_model`, :func:`load_levels`; record in ``weights/MODEL_CARD.md``);
- :mod:`~torch_modulo.singleshot.learned.decoding`: the exact integer decoders: the maximum-likelihood spanning
  tree (:func:`decode_jumps`), its confidence, the cost of every pair's jump (:func:`pair_costs`) and min-cut moves
  that lower it (:func:`refine_band`);
- :mod:`~torch_modulo.singleshot.learned.inference`: the networks run tile by tile on images of any size
  (:func:`predict_jumps`, :func:`predict_levels`);
- :mod:`~torch_modulo.singleshot.learned.levels`: region moves by the level head's costs (:class:`RegionMoves`);
- :mod:`~torch_modulo.singleshot.learned.solver`: the method's options and the registry's solvers
  (:func:`learned_k`, :func:`solve_learned`), and a mosaic's photosites refined after its guide
  (:func:`refine_photosites`);
- :mod:`~torch_modulo.singleshot.learned.confidence`: :func:`learned_confidence` and :class:`LearnedConfidence`;
- :mod:`~torch_modulo.singleshot.learned.loss`: the training loss (:func:`edge_loss`, :func:`edge_targets`); the
  recipe that made the shipped weights is ``references/learned_single``.

Every output is ``I_m + k 2^N`` with integer ``k``; the caller anchors ``k``
(:func:`~torch_modulo.singleshot.anchor.anchor_k`).
"""

from __future__ import annotations

from torch_modulo.singleshot.learned.confidence import LearnedConfidence, learned_confidence
from torch_modulo.singleshot.learned.decoding import (
    DIRECTIONS,
    MAX_COST,
    TREE_PIXELS,
    decode_edges,
    decode_jumps,
    pair_costs,
    refine_band,
    refine_cut,
)
from torch_modulo.singleshot.learned.inference import (
    STRIP,
    TILE,
    block_slices,
    level_margin,
    predict_edges,
    predict_jumps,
    predict_levels,
    tile_margin,
    window_costs,
    window_grid,
)
from torch_modulo.singleshot.learned.levels import RegionMoves, region_moves
from torch_modulo.singleshot.learned.loss import edge_loss, edge_targets
from torch_modulo.singleshot.learned.network import (
    LEVEL_WEIGHTS,
    LEVELS,
    SLOTS,
    WEIGHTS,
    EdgeJumpNet,
    LevelHead,
    LevelNet,
    edge_features,
    load_levels,
    load_model,
    weights_path,
)
from torch_modulo.singleshot.learned.solver import (
    BAND,
    LEARNED_OPTIONS,
    MIN_LEVEL_SIDE,
    MOSAIC_CUTS,
    NETWORK_THREADS,
    check_levels,
    check_tile,
    check_weights,
    learned_k,
    mosaic_spec,
    network_threads,
    refine_photosites,
    refines_photosites,
    solve_learned,
    solve_learned_tensor,
    solves_cells,
)

__all__ = [
    "BAND",
    "DIRECTIONS",
    "LEARNED_OPTIONS",
    "LEVELS",
    "LEVEL_WEIGHTS",
    "MAX_COST",
    "MIN_LEVEL_SIDE",
    "MOSAIC_CUTS",
    "NETWORK_THREADS",
    "SLOTS",
    "STRIP",
    "TILE",
    "TREE_PIXELS",
    "WEIGHTS",
    "EdgeJumpNet",
    "LearnedConfidence",
    "LevelHead",
    "LevelNet",
    "RegionMoves",
    "block_slices",
    "check_levels",
    "check_tile",
    "check_weights",
    "decode_edges",
    "decode_jumps",
    "edge_features",
    "edge_loss",
    "edge_targets",
    "learned_confidence",
    "learned_k",
    "level_margin",
    "load_levels",
    "load_model",
    "mosaic_spec",
    "network_threads",
    "pair_costs",
    "predict_edges",
    "predict_jumps",
    "predict_levels",
    "refine_band",
    "refine_cut",
    "refine_photosites",
    "refines_photosites",
    "region_moves",
    "solve_learned",
    "solve_learned_tensor",
    "solves_cells",
    "tile_margin",
    "weights_path",
    "window_costs",
    "window_grid",
]
