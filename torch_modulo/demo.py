"""The main job, end to end on one scene: simulate, unwrap (single and multi shot), tone-map, write files.

``torch-modulo demo`` runs :func:`run_demo` on the embedded CC0 scene (``torch_modulo/assets/apartment.exr``):

1. Scale the radiance so that the 99.9th percentile of luminance (the maximum, where that percentile is 0) reads
   4095 counts at exposure 1 (a 12-bit scene, as in the paper's single-shot experiments), and capture it with an
   8-bit modulo and an 8-bit intensity sensor.
2. Single shot: unwrap the one modulus image (by default with ``unwrap_single``'s default method, ``"learned"``;
   ``method="guided"`` for path following, ``"fast"`` or ``"paper"`` for the paper's graph cut, Eqs. 3-5).
3. Multi shot: three modulo captures (neighbouring ratio 64, the shortest without rollover), unwrapped by rollover
   counting (Eqs. 6-7), against the conventional merge of three clipped intensity captures with the same exposures.
4. Tone-map everything with Larson et al.'s histogram adjustment (sRGB-encoded) and write EXRs, PNGs, one
   labelled comparison image and ``summary.json``.

Files: ``single_shot.exr``, ``multi_shot.exr`` and ``intensity_merge.exr`` (radiance); ``modulus.png``, the 8-bit
modulus image itself with its bit depth and exposure in its metadata (already a display image, and a camera frame
that ``torch-modulo unwrap --single`` reads; a 16-bit PNG for 9 to 16 bits, ``modulus.exr`` above);
``<name>_tonemapped.png`` for the truth, the intensity image (its counts gamma-encoded) and the three recovered
radiance maps; ``comparison.png``; ``summary.json``.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from torch_modulo import io
from torch_modulo._atomic import write_json
from torch_modulo.assets import default_scene_path
from torch_modulo.capture import capture_intensity, capture_modulo
from torch_modulo.metrics import exact_k_map, exact_k_share, psnr
from torch_modulo.multishot import merge_intensity, unwrap_multi
from torch_modulo.protocols import align_offsets
from torch_modulo.radiance import load_radiance
from torch_modulo.singleshot import unwrap_confidence, unwrap_single
from torch_modulo.tonemap import REC709_LUMA, tonemap_histogram

__all__ = ["run_demo"]

#: Peak of the simulated 12-bit scene in counts at exposure 1.
SCENE_PEAK = 4095.0

#: Single-shot values with a confidence (:func:`~torch_modulo.unwrap_confidence`) below this are flagged as guessed.
LOW_CONFIDENCE = 0.25


def _relative_error(estimate: torch.Tensor, truth: torch.Tensor) -> float:
    """Median relative radiance error over pixels with signal."""
    mask = truth > 0
    return float(((estimate[mask] - truth[mask]).abs() / truth[mask]).median())


def _labelled_grid(panels: list[tuple[str, torch.Tensor]], columns: int = 2) -> np.ndarray:
    """Tile (3, H, W) display images in [0, 1] into one (H', W', 3) array with a caption above each."""
    import OpenImageIO as oiio

    _, h, w = panels[0][1].shape
    caption = 28
    rows = (len(panels) + columns - 1) // columns
    grid = np.ones((rows * (h + caption), columns * w, 3), dtype=np.float32)
    for index, (label, image) in enumerate(panels):
        r, c = divmod(index, columns)
        top, left = r * (h + caption), c * w
        grid[top + caption : top + caption + h, left : left + w] = image.permute(1, 2, 0).cpu().numpy()
        text = oiio.ImageBuf(oiio.ImageSpec(w, caption, 3, "float"))
        oiio.ImageBufAlgo.fill(text, (1.0, 1.0, 1.0))
        oiio.ImageBufAlgo.render_text(text, 6, caption - 8, label, 18, "", (0.0, 0.0, 0.0))
        grid[top : top + caption, left : left + w] = text.get_pixels(oiio.FLOAT)
    return grid


def _single_shot(
    radiance: torch.Tensor,
    truth: torch.Tensor,
    bits: int,
    method: str,
    workers: int | None,
    log: Callable[[str], None],
) -> tuple[dict[str, Any], dict[str, torch.Tensor]]:
    """One modulus image vs one intensity image: the scores and the tensors the figures need."""
    modulus = capture_modulo(radiance, 1.0, bits)
    intensity = capture_intensity(radiance, 1.0, bits)
    start = time.perf_counter()
    restored = unwrap_single(modulus, bits, method=method, workers=workers)
    seconds = time.perf_counter() - start
    wrong = ~exact_k_map(restored, truth, bits)  # offsets aligned as in exact_k
    low = unwrap_confidence(restored, bits) < LOW_CONFIDENCE
    single: dict[str, Any] = {
        "method": method,
        "exact_k": float(exact_k_share(restored, truth, bits)[0]),
        "psnr_db": float(psnr(align_offsets(restored, truth, bits), truth, peak=float(truth.max()))[0]),  # as exact_k
        "saturated_in_intensity_image": float((intensity >= 2**bits - 1).double().mean()),
        "low_confidence_share": float(low.double().mean()),
        "wrong_k_flagged_low_confidence": float((wrong & low).sum() / wrong.sum()) if bool(wrong.any()) else 1.0,
        "seconds": seconds,
    }
    log(
        f"single shot ({method}): exact rollover count on {100 * single['exact_k']:.2f}% of values, "
        f"PSNR {single['psnr_db']:.1f} dB, {single['seconds']:.1f} s "
        f"(the intensity image saturates {100 * single['saturated_in_intensity_image']:.1f}% of values); "
        f"unwrap_confidence flags {100 * single['low_confidence_share']:.1f}% of values as guessed, holding "
        f"{100 * single['wrong_k_flagged_low_confidence']:.1f}% of the wrong ones"
    )

    return single, {"modulus": modulus, "intensity": intensity, "restored": restored, "wrong": wrong, "low": low}


def _multi_shot(
    radiance: torch.Tensor, bits: int, ratio: float, log: Callable[[str], None]
) -> tuple[dict[str, Any], torch.Tensor, torch.Tensor]:
    """Three modulo exposures (the shortest without rollover) vs three clipped ones: scores and both results."""
    base = (2**bits - 1) / float(radiance.max())
    taus = [base, base * ratio, base * ratio * ratio]
    if 2**bits * ratio * ratio > 2**24:  # the longest exposure's counts pass what float32 holds exactly
        radiance = radiance.double()
    moduli = torch.stack([capture_modulo(radiance, t, bits) for t in taus], dim=1)
    frames = torch.stack([capture_intensity(radiance, t, bits) for t in taus], dim=1)
    start = time.perf_counter()
    multi_radiance = unwrap_multi(moduli, taus, bits)
    seconds = time.perf_counter() - start
    merged = merge_intensity(frames, taus, bits)
    exact_counts = torch.floor(radiance * taus[-1])
    multi: dict[str, Any] = {
        "exposures": taus,
        "exact_k": float((unwrap_multi(moduli, taus, bits, return_counts=True) == exact_counts).double().mean()),
        "median_relative_error_modulo": _relative_error(multi_radiance, radiance),
        "median_relative_error_intensity": _relative_error(merged, radiance),
        "seconds": seconds,
    }
    log(
        f"multi shot (exposure ratio {ratio:g}): exact counts on {100 * multi['exact_k']:.2f}% of values; "
        f"median relative error {multi['median_relative_error_modulo']:.2e} (modulo) vs "
        f"{multi['median_relative_error_intensity']:.2e} (intensity merge)"
    )

    return multi, multi_radiance, merged


#: The radiance files the demo writes (a scene read from ``--out`` may not be one of them), then the frame above
#: 16 bits.
RADIANCE_OUTPUTS = ("single_shot.exr", "multi_shot.exr", "intensity_merge.exr", "modulus.exr")


def _write_outputs(
    out: Path,
    path: Path,
    radiance: torch.Tensor,
    shot: dict[str, torch.Tensor],
    multi_radiance: torch.Tensor,
    merged: torch.Tensor,
    single: dict[str, Any],
    bits: int,
) -> list[Path]:
    """Tone-map the results and write the EXRs, the PNGs and the comparison figure; returns the written paths."""
    modulus, intensity, restored = shot["modulus"], shot["intensity"], shot["restored"]
    display = {
        "truth": tonemap_histogram(radiance, srgb=True),
        "intensity": (intensity / (2**bits - 1)) ** (1 / 2.2),  # linear counts, gamma-encoded for display
        "modulus": (modulus / (2**bits - 1)).clamp(0, 1),
        "single_shot": tonemap_histogram(restored, srgb=True),
        "multi_shot": tonemap_histogram(multi_radiance, srgb=True),
        "intensity_merge": tonemap_histogram(merged, srgb=True),
    }
    written = []
    metadata = {"bits": bits, "exposure": 1.0, "source": path.name}
    for name, image in zip(RADIANCE_OUTPUTS[:3], (restored[0], multi_radiance[0], merged[0]), strict=True):
        io.write_image(out / name, image, metadata=metadata)
        written.append(out / name)
    # The camera frame in the narrowest file that holds it exactly: 8-bit or 16-bit PNG, or a float32 EXR.
    frame = out / ("modulus.png" if bits <= 16 else "modulus.exr")
    sample = None if bits > 16 else "uint8" if bits <= 8 else "uint16"
    io.write_image(frame, modulus[0], metadata=metadata, dtype=sample)
    written.append(frame)
    for name, image in display.items():
        if name == "modulus":  # the modulus is its own display image: modulus.png holds it
            continue
        target = out / f"{name}_tonemapped.png"
        io.write_image(target, image[0], dtype="uint8", normalized=True)
        written.append(target)
    k_error = shot["wrong"].any(dim=1, keepdim=True)
    flagged = shot["low"].any(dim=1, keepdim=True)
    panels = [
        ("ground truth (tone-mapped)", display["truth"][0]),
        (f"{bits}-bit intensity camera", display["intensity"][0]),
        (f"{bits}-bit modulo camera", display["modulus"][0]),
        (f"single shot unwrapped: {100 * single['exact_k']:.1f}% exact k", display["single_shot"][0]),
        ("wrong rollover count (white)", k_error[0].expand(3, -1, -1).to(radiance.dtype)),
        (
            f"low confidence, k guessed (white): {100 * single['low_confidence_share']:.1f}%",
            flagged[0].expand(3, -1, -1).to(radiance.dtype),
        ),
        ("3 modulo captures unwrapped", display["multi_shot"][0]),
        ("3 intensity captures merged", display["intensity_merge"][0]),
    ]
    grid = torch.from_numpy(_labelled_grid(panels)).permute(2, 0, 1)
    io.write_image(out / "comparison.png", grid, dtype="uint8", normalized=True)
    written.append(out / "comparison.png")

    return written


def run_demo(
    out_dir: str | os.PathLike[str] = "demo_out",
    scene: str | os.PathLike[str] | None = None,
    *,
    bits: int = 8,
    ratio: float = 64.0,
    workers: int | None = None,
    method: str = "learned",
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Run the demo and return its summary (also written to ``out_dir/summary.json``).

    Args:
        out_dir: folder for the outputs (created if needed; existing demo files in it are replaced atomically).
        scene: an HDR file (EXR/HDR); default the embedded CC0 scene. It is read with
            :func:`~torch_modulo.radiance.load_radiance` as RGB (grey repeated); NaN and infinite values are
            replaced, negative values clamped to 0.
        bits: the simulated sensors' bit depth.
        ratio: neighbouring exposure ratio of the multi-shot captures (at most ``2**bits``).
        workers: worker processes for the single-shot unwrapping (default: one per core when it pays).
        method: the :func:`~torch_modulo.unwrap_single` method (``"learned"``, ``"guided"``, ``"fast"`` or ``"paper"``).
        log: where progress lines go.

    Returns:
        A dict of the error figures, timings and written paths.

    Raises:
        ValueError: ``ratio`` outside ``(1, 2**bits]``, a black scene, or a scene that is one of the radiance
            files the demo writes in ``out_dir`` (it would be replaced).
    """
    if not 1 < ratio <= 2**bits:  # checked before any work: the multi-shot stage comes last
        raise ValueError(f"ratio must be more than 1 and at most 2**bits = {2**bits} (bits={bits}); got {ratio}")
    out = Path(out_dir)
    path = Path(scene) if scene is not None else default_scene_path()
    if path.resolve().name in RADIANCE_OUTPUTS and path.resolve().parent == out.resolve():  # links too
        raise ValueError(f"the scene {path} is one of the files the demo writes in {out}: choose another output folder")
    out.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}

    hdr, counts = load_radiance(path, channels=3, with_counts=True)
    replaced = counts["nan"] + counts["posinf"] + counts["neginf"]
    if replaced:
        log(f"scene {path.name}: replaced {replaced} NaN or infinite values (NaN and -Inf by 0, +Inf by the maximum)")
    luma = torch.einsum("chw,c->hw", hdr, torch.tensor(REC709_LUMA, dtype=hdr.dtype))
    reference = float(torch.quantile(luma.flatten(), 0.999))
    if not reference > 0:  # most of the scene is black: its brightest pixel reads the peak instead
        reference = float(luma.max())
        if not reference > 0:
            raise ValueError(f"scene {path} is black (maximum luminance {reference}): there is nothing to capture")
    radiance = (hdr * (SCENE_PEAK / reference)).unsqueeze(0)  # (1, 3, H, W)
    truth = torch.floor(radiance)
    log(f"scene {path.name}: {tuple(hdr.shape)}, {float(truth.max()):.0f} counts at the brightest pixel")

    single, shot = _single_shot(radiance, truth, bits, method, workers, log)
    timings["single_shot_s"] = single["seconds"]
    multi, multi_radiance, merged = _multi_shot(radiance, bits, ratio, log)
    timings["multi_shot_s"] = multi["seconds"]
    start = time.perf_counter()
    written = _write_outputs(out, path, radiance, shot, multi_radiance, merged, single, bits)
    timings["tonemap_and_write_s"] = time.perf_counter() - start

    summary = {
        "scene": str(path),
        "bits": bits,
        "single_shot": single,
        "multi_shot": multi,
        "timings_s": timings,
        "files": [str(p) for p in written],
    }
    write_json(out / "summary.json", summary)
    log(f"wrote {len(written) + 1} files to {out}/ (comparison.png shows them side by side)")
    return summary
