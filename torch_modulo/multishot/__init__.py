"""Multi-shot UHDR (paper Sec. 5): rollover counting over an exposure stack, noise-free (Eqs. 6-7) and under a
sensor noise model, exposure planning, and the conventional merge of clipped frames that the paper compares against.

Rooms:

- :mod:`~torch_modulo.multishot.counting`: Eqs. 6-7 as printed and the robust noise-free rule.
- :mod:`~torch_modulo.multishot.noisy`: the noise-aware decoder (each frame used only while its count is determined).
- :mod:`~torch_modulo.multishot.spatial`: the neighbours' evidence of the spatial decoder (``spatial=True``, the
  default under noise).
- :mod:`~torch_modulo.multishot.planning`: :func:`plan_exposures`, noise-free and noise-aware (within a frame budget,
  for either decoder).
- :mod:`~torch_modulo.multishot.prediction`: the predicted error of a plan, for modulo and conventional sensors, and
  the conventional plan for a target error.
- :mod:`~torch_modulo.multishot.unwrap`: :func:`unwrap_multi` and :class:`MultiExposureUnwrap`, which choose between
  them.
- :mod:`~torch_modulo.multishot.merge`: :func:`merge_intensity`, the conventional-sensor baseline.
- :mod:`~torch_modulo.multishot.stack`: stack shapes, exposures, sorting and ratios, shared by all of them.
"""

from __future__ import annotations

from torch_modulo.multishot.merge import IntensityMerge, merge_intensity
from torch_modulo.multishot.planning import brightest_unwrapped, plan_exposures, safe_ratio, unsafe_ratio_message
from torch_modulo.multishot.unwrap import MultiExposureUnwrap, unwrap_multi

__all__ = [
    "IntensityMerge",
    "MultiExposureUnwrap",
    "brightest_unwrapped",
    "merge_intensity",
    "plan_exposures",
    "safe_ratio",
    "unsafe_ratio_message",
    "unwrap_multi",
]
