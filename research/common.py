"""What the research scripts share: the development scenes, protocols A and B on numpy arrays, scores and methods.

A thin numpy layer over :mod:`torch_modulo.protocols` (the protocols and scores of the benchmarks), so that the
research numbers are measured exactly as the benchmarks' are: 12-bit true counts, an 8-bit modulus, each channel's
global rollover offset aligned before scoring.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from torch_modulo import protocols

__all__ = [
    "BITS",
    "DATA",
    "PEAK",
    "PERIOD",
    "aligned",
    "load",
    "protocol_a",
    "protocol_b",
    "run_method",
    "scores",
    "select_scenes",
]

#: The development scenes of a source checkout.
DATA = protocols.DEV_SCENES
#: Bit depth of the modulus, its period, and the largest true count (12 bits).
BITS = 8
PERIOD = 2**BITS
PEAK = 4095.0


def select_scenes(data: Path, max_scenes: int = 0, split: str = "all") -> list[Path]:
    """The .exr/.hdr files under ``data`` sorted by path, on one side of the ``split`` (``protocols.SPLITS``; the first
    ``max_scenes`` when > 0); exits if none."""
    scenes = protocols.list_scenes(data, split)
    if max_scenes:
        scenes = scenes[:max_scenes]
    if not scenes:
        raise SystemExit(f"no .exr/.hdr scenes under {data} (split {split!r})")
    return scenes


def load(path: Path, scale: int) -> np.ndarray:
    """(C, H, W) float64 radiance, area-downsampled to a longer side of at most ``scale``."""
    return protocols.load_scene(path, scale).numpy()


def protocol_a(rgb: np.ndarray) -> np.ndarray:
    """(1, H, W) true counts of protocol A (luminance, 99.9th percentile at 4095)."""
    return protocols.protocol_a(torch.from_numpy(rgb), peak=PEAK).numpy()


def protocol_b(rgb: np.ndarray) -> np.ndarray:
    """(C, H, W) true counts of protocol B (min-max scaled, 20% of the pixels rolled over)."""
    return protocols.protocol_b(torch.from_numpy(rgb), peak=PEAK, period=PERIOD).numpy()


def aligned(restored: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``restored`` with each channel shifted by whole periods to the truth's most common rollover count.

    Example:
        >>> truth = np.array([[[10.0, 300.0], [600.0, 20.0]]])
        >>> aligned(truth + 512.0, truth).tolist()
        [[[10.0, 300.0], [600.0, 20.0]]]
    """
    return protocols.align_offsets(torch.from_numpy(restored), torch.from_numpy(truth), BITS).numpy()


def scores(restored: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """Exact-k share and PSNR (peak 4095) of restored (C, H, W) counts, each channel's offset aligned first.

    Example:
        >>> truth = np.array([[[10.0, 300.0], [600.0, 20.0]]])
        >>> scores(truth + 256.0, truth)
        (1.0, inf)
    """
    score = protocols.score_scene(torch.from_numpy(restored), torch.from_numpy(truth), BITS, PEAK)
    return score.exact_k, score.psnr


def run_method(spec: str, modulus: np.ndarray, workers: int = 1) -> tuple[np.ndarray, float]:
    """Restore (C, H, W) modulus counts with a method: restored counts and seconds.

    Args:
        spec: ``"skimage"`` (scikit-image's ``unwrap_phase``, Herraez et al. 2002) or a method of
            :func:`torch_modulo.unwrap_single` with options, as ``"fast:init=quality,window=0"``.
        modulus: (C, H, W) integer-valued array in ``[0, 256)``.
        workers: worker processes for ``unwrap_single``.
    """
    if spec == "skimage":
        from skimage.restoration import unwrap_phase

        start = time.perf_counter()
        out = np.empty_like(modulus)
        for c in range(modulus.shape[0]):
            phase = unwrap_phase(modulus[c] * (2 * np.pi / PERIOD))
            out[c] = np.rint(phase * (PERIOD / (2 * np.pi)))
        seconds = time.perf_counter() - start
        # unwrap_phase fixes its own offset; lift it to non-negative counts (the scores align offsets anyway).
        lows = np.floor(out.reshape(out.shape[0], -1).min(axis=1) / PERIOD)
        return out - PERIOD * lows[:, None, None], seconds
    from torch_modulo.singleshot import unwrap_single

    method, options = protocols.parse_method(spec)
    start = time.perf_counter()
    out = unwrap_single(torch.from_numpy(modulus).unsqueeze(0), bits=BITS, method=method, workers=workers, **options)
    return out[0].numpy(), time.perf_counter() - start
