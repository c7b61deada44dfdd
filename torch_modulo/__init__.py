"""torch_modulo: unbounded HDR photography with a modulo camera, on PyTorch and Kornia.

Implements Zhao, Shi, Fernandez-Cull, Yeung and Raskar, "Unbounded High Dynamic Range Photography using a
Modulo Camera" (ICCP 2015): capture models (Eq. 1), multi-exposure unwrapping (Eqs. 6-7), single-shot
unwrapping by graph cuts (Eqs. 3-5), tone mapping, sensor adapters, data pipelines and a command line.
"""

from __future__ import annotations

from torch_modulo.capture import (
    IntensityCapture,
    ModuloCapture,
    ModuloWrap,
    capture_intensity,
    capture_modulo,
    modulo_wrap,
)

__version__ = "0.1.0"

__all__ = [
    "IntensityCapture",
    "ModuloCapture",
    "ModuloWrap",
    "__version__",
    "capture_intensity",
    "capture_modulo",
    "modulo_wrap",
]
