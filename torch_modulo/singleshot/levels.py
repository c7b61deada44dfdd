"""Deprecated alias of :mod:`torch_modulo.singleshot.learned` for the level head and the region moves.

The level network, its weights and the region moves moved into the learned method's package
(:mod:`torch_modulo.singleshot.learned`: ``network``, ``inference``, ``levels``); import them from there. Every name
this module had still resolves here, with a :class:`DeprecationWarning`.
"""

from __future__ import annotations

import warnings
from typing import Any

from torch_modulo.singleshot import learned

#: The names of the former module, all public in :mod:`torch_modulo.singleshot.learned` now.
_MOVED = (
    "LEVELS",
    "LEVEL_WEIGHTS",
    "LevelHead",
    "LevelNet",
    "level_margin",
    "load_levels",
    "predict_levels",
    "region_moves",
    "window_costs",
)

__all__: list[str] = []


def __getattr__(name: str) -> Any:
    if name in _MOVED:
        warnings.warn(
            f"torch_modulo.singleshot.levels.{name} is deprecated; import it from torch_modulo.singleshot.learned",
            DeprecationWarning,
            stacklevel=2,
        )
        return getattr(learned, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
