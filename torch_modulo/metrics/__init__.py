"""Quality metrics for recovered HDR images: rollover-count accuracy, PSNR (linear, log, PU21), tone-mapped SSIM.

Every metric reduces each batch item to one number and returns a tensor of shape ``(B,)`` on the input's device and
dtype. Images may be ``(B, C, H, W)``, ``(C, H, W)`` or ``(H, W)``; unbatched inputs count as a batch of one, so
the result then has shape ``(1,)``. Both images must have the same shape.

- :func:`exact_k_share` / :func:`exact_k_map`: is the rollover count ``k`` of Eq. 2 (``I = I_m + k 2^N``) right?
  Unwrapping fixes ``k`` only up to a global constant per image and channel, so that constant is aligned first.
- :func:`psnr`: PSNR on linear values with a given peak.
- :func:`psnr_log`: PSNR on ``log2`` radiance relative to the reference's peak.
- :func:`pu21_encode` / :func:`psnr_pu21`: PSNR on the PU21 perceptually uniform encoding (Mantiuk and Azimi, 2021).
- :func:`ssim_tonemapped`: SSIM (Kornia) on tone-mapped images.

Files: ``exact_k.py``, ``psnr.py`` (linear and log PSNR), ``pu21.py``, ``ssim.py``, and ``_common.py`` for what they
share; every public name is importable from ``torch_modulo.metrics``.
"""

from __future__ import annotations

from torch_modulo.metrics.exact_k import ExactKShare, exact_k_map, exact_k_share
from torch_modulo.metrics.psnr import PSNR, PSNRLog, psnr, psnr_log
from torch_modulo.metrics.pu21 import (
    PSNRPU21,
    PU21_LUMINANCE_RANGE,
    PU21_PARAMETERS,
    PU21Encode,
    psnr_pu21,
    pu21_encode,
)
from torch_modulo.metrics.ssim import SSIMToneMapped, log_relative_tonemap, ssim_tonemapped

__all__ = [
    "PSNR",
    "PU21_LUMINANCE_RANGE",
    "PU21_PARAMETERS",
    "PSNRLog",
    "PSNRPU21",
    "PU21Encode",
    "SSIMToneMapped",
    "ExactKShare",
    "exact_k_map",
    "exact_k_share",
    "log_relative_tonemap",
    "psnr",
    "psnr_log",
    "psnr_pu21",
    "pu21_encode",
    "ssim_tonemapped",
]
