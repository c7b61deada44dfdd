"""torch_modulo: unbounded HDR photography with a modulo camera, on PyTorch and Kornia.

Implements Zhao, Shi, Fernandez-Cull, Yeung and Raskar, "Unbounded High Dynamic Range Photography using a
Modulo Camera" (ICCP 2015): capture models (Eq. 1), multi-exposure unwrapping (Eqs. 6-7), single-shot
unwrapping (Eqs. 3-5: the graph cut, path following, and a small trained network by default), tone mapping, sensor
adapters, data pipelines and a command line.
"""

from __future__ import annotations

from torch_modulo import cfa, data, io, sensors
from torch_modulo._checks import set_validation, validation, validation_enabled
from torch_modulo.capture import (
    ExposureStack,
    IntensityCapture,
    ModuloCapture,
    ModuloWrap,
    MultiExposureCapture,
    capture_intensity,
    capture_modulo,
    capture_stack,
    modulo_wrap,
)
from torch_modulo.cfa import Demosaic, Mosaic, demosaic, mosaic
from torch_modulo.metrics import (
    PSNR,
    PSNRPU21,
    ExactKShare,
    PSNRLog,
    PU21Encode,
    SSIMToneMapped,
    exact_k_map,
    exact_k_share,
    psnr,
    psnr_log,
    psnr_pu21,
    pu21_encode,
    ssim_tonemapped,
)
from torch_modulo.multishot import (
    IntensityMerge,
    MultiExposureUnwrap,
    merge_intensity,
    plan_exposures,
    unwrap_multi,
)
from torch_modulo.singleshot import (
    LearnedConfidence,
    Potential,
    SingleShotInfo,
    SingleShotUnwrap,
    UnwrapConfidence,
    UnwrapEnergy,
    is_representable,
    learned_confidence,
    potential,
    unwrap_confidence,
    unwrap_energy,
    unwrap_single,
)
from torch_modulo.tonemap import (
    ClaheToneMap,
    GammaToneMap,
    HistogramToneMap,
    LogToneMap,
    ReinhardToneMap,
    tonemap_clahe,
    tonemap_gamma,
    tonemap_histogram,
    tonemap_log,
    tonemap_reinhard,
)

__version__ = "0.1.0"

__all__ = [
    "Potential",
    "UnwrapEnergy",
    "UnwrapConfidence",
    "is_representable",
    "potential",
    "unwrap_energy",
    "unwrap_confidence",
    "learned_confidence",
    "LearnedConfidence",
    "SingleShotInfo",
    "SingleShotUnwrap",
    "unwrap_single",
    "Demosaic",
    "Mosaic",
    "demosaic",
    "mosaic",
    "ClaheToneMap",
    "GammaToneMap",
    "HistogramToneMap",
    "LogToneMap",
    "ReinhardToneMap",
    "tonemap_clahe",
    "tonemap_gamma",
    "tonemap_histogram",
    "tonemap_log",
    "tonemap_reinhard",
    "PSNR",
    "PSNRPU21",
    "ExactKShare",
    "PSNRLog",
    "PU21Encode",
    "SSIMToneMapped",
    "exact_k_map",
    "exact_k_share",
    "psnr",
    "psnr_log",
    "psnr_pu21",
    "pu21_encode",
    "ssim_tonemapped",
    "ExposureStack",
    "IntensityCapture",
    "IntensityMerge",
    "MultiExposureCapture",
    "MultiExposureUnwrap",
    "ModuloCapture",
    "ModuloWrap",
    "__version__",
    "cfa",
    "data",
    "io",
    "sensors",
    "capture_intensity",
    "capture_modulo",
    "capture_stack",
    "merge_intensity",
    "modulo_wrap",
    "plan_exposures",
    "set_validation",
    "unwrap_multi",
    "validation",
    "validation_enabled",
]
