"""Benchmark a colour modulo camera: protocol B mosaicked with a Bayer pattern, unwrapped three ways, demosaiced.

For every scene under ``--data`` (``.exr`` and ``.hdr``, sorted by path), downsampled until its longer side is at
most ``--scale`` (512) and cropped to an even height and width, the true counts ``I`` of protocol B (RGB min-max
scaled, the exposure that makes 20% of the pixels roll over, ``floor(clip(x e, 0, 1) * 4095)`` per channel;
:func:`torch_modulo.protocols.protocol_b`) are mosaicked with ``--cfa`` (RGGB) and wrapped to 8 bits. Then:

- ``rgb``: the full RGB planes unwrapped (``unwrap_single`` on (3, H, W)): what a camera with three full colour
  planes would get, the upper reference;
- ``mosaic``: the mosaic unwrapped with ``cfa=`` (its wrapped colours interpolated on the circle to full
  resolution, :func:`torch_modulo.cfa.interpolate_wrapped`, unwrapped as one RGB image, the photosites kept);
- ``planes``: the mosaic's four colour planes (:func:`torch_modulo.cfa.split_planes`, each a quarter of the
  photosites) unwrapped jointly as one 4-channel image;
- ``grey``: the mosaic unwrapped as one grey image, the naive way.

Scores per scene (:func:`torch_modulo.protocols.score_scene`): exact-k, rolled-over right and PSNR (peak 4095) of
the restored values after aligning each plane's global rollover offset with the truth: the three RGB channels for
``rgb``, the four colour planes of the mosaic (:func:`torch_modulo.cfa.split_planes`) for the others.
``rgb@sites`` scores the ``rgb`` result at the photosites the mosaic keeps only. ``dB rgb`` is the PSNR of the
colour image against the RGB truth: the restored RGB for ``rgb``, and for the mosaics the aligned restored mosaic
demosaiced (:func:`torch_modulo.demosaic`, ``--demosaic``). ``truth`` demosaics the true mosaic with every method of
:data:`torch_modulo.cfa.DEMOSAIC_METHODS`: the loss of demosaicing alone.

Summary, for all scenes and for the training and the validation scenes apart (``--split`` runs one side only):
means over scenes, scenes recovered perfectly, and the gaps in exact-k between ``rgb`` and ``mosaic`` (and
``planes``), and between ``rgb@sites`` and ``mosaic`` (the same photosites, scored alike).
A JSON line with the summary ends the output.

Examples:
    python benchmarks/bench_cfa.py                                              # every scene, default method, RGGB
    python benchmarks/bench_cfa.py --scenes qt-preview/landscape.hdr --scale 128   # a smoke run
    python benchmarks/bench_cfa.py --method lsq --cfa GRBG
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from pathlib import Path
from typing import Any

import torch
from bench_single import GROUPS, select_scenes  # the sibling script: the same scene choice and summary groups

import torch_modulo as tm
from torch_modulo import protocols
from torch_modulo._argtypes import nonnegative_int, positive_int
from torch_modulo.cfa import CFA_PATTERNS, DEMOSAIC_METHODS, merge_planes, split_planes
from torch_modulo.singleshot import METHODS

BITS = 8
PERIOD = 2**BITS
PEAK = protocols.PROTOCOL_PEAKS["B"]
WAYS = ("rgb", "rgb@sites", "mosaic", "planes", "grey")


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float((a.double() - b.double()).square().mean())
    return math.inf if mse == 0 else 10.0 * math.log10(PEAK * PEAK / mse)


def unwrap(modulus: torch.Tensor, args: argparse.Namespace, cfa: str | None = None) -> tuple[torch.Tensor, float]:
    """Restored counts of one (C, H, W) modulus, and seconds."""
    name, options = protocols.parse_method(args.method)
    start = time.perf_counter()
    out = tm.unwrap_single(modulus[None], BITS, method=name, workers=args.workers, cfa=cfa, **options)[0]
    return out, time.perf_counter() - start


def score_mosaic(restored: torch.Tensor, truth: torch.Tensor, truth_rgb: torch.Tensor, args: argparse.Namespace):
    """Scores of a restored mosaic on its four colour planes, and the PSNR of its demosaiced colour image."""
    planes, true_planes = split_planes(restored), split_planes(truth)
    score = protocols.score_scene(planes, true_planes, BITS, PEAK)
    aligned = merge_planes(protocols.align_offsets(planes, true_planes, BITS))
    colour = tm.demosaic(aligned[None], args.cfa, args.demosaic)[0]
    return {**score._asdict(), "psnr_rgb": psnr(colour, truth_rgb)}


def run_scene(path: Path, args: argparse.Namespace) -> dict[str, Any]:
    image = protocols.load_scene(path, args.scale)
    image = image.expand(3, -1, -1) if image.shape[0] == 1 else image
    h, w = image.shape[-2:]
    truth_rgb = protocols.protocol_b(image[:, : h - h % 2, : w - w % 2].contiguous())
    truth = tm.mosaic(truth_rgb, args.cfa)
    row: dict[str, Any] = {
        "scene": path.relative_to(args.data).as_posix(),
        "split": protocols.scene_split(path, args.data),
        "shape": list(truth_rgb.shape),
    }

    restored_rgb, seconds = unwrap(torch.remainder(truth_rgb, PERIOD), args)
    score = protocols.score_scene(restored_rgb, truth_rgb, BITS, PEAK)
    row["rgb"] = {**score._asdict(), "psnr_rgb": score.psnr, "seconds": seconds}
    at_sites = split_planes(tm.mosaic(restored_rgb, args.cfa))
    row["rgb@sites"] = {**protocols.score_scene(at_sites, split_planes(truth), BITS, PEAK)._asdict()}
    row["rgb@sites"]["psnr_rgb"] = math.nan

    modulus = torch.remainder(truth, PERIOD)
    for way, cfa in (("mosaic", args.cfa), ("grey", None)):
        restored, seconds = unwrap(modulus, args, cfa)
        row[way] = {**score_mosaic(restored, truth, truth_rgb, args), "seconds": seconds}
    restored, seconds = unwrap(split_planes(modulus), args)
    row["planes"] = {**score_mosaic(merge_planes(restored), truth, truth_rgb, args), "seconds": seconds}
    row["truth"] = {m: psnr(tm.demosaic(truth[None], args.cfa, m)[0], truth_rgb) for m in DEMOSAIC_METHODS}
    return row


def header() -> str:
    head = f"{'scene':36s} {'CxHxW':>12s}"
    for way in WAYS:
        head += f" | {way[:9] + ' k%':>12s} {'roll%':>6s} {'dB rgb':>6s}"
    return head + " | " + " ".join(f"{'dB ' + m[:6]:>9s}" for m in DEMOSAIC_METHODS)


def scene_line(row: dict[str, Any]) -> str:
    line = f"{row['scene'][-36:]:36s} {'x'.join(map(str, row['shape'])):>12s}"
    for way in WAYS:
        r = row[way]
        line += f" | {100 * r['exact_k']:12.2f} {100 * r['rolled_over_right']:6.2f} {min(r['psnr_rgb'], 99.99):6.2f}"
    return line + " | " + " ".join(f"{min(row['truth'][m], 99.99):9.2f}" for m in DEMOSAIC_METHODS)


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {"scenes": len(rows)}
    for way in WAYS:
        rolled = [r[way]["rolled_over_right"] for r in rows if not math.isnan(r[way]["rolled_over_right"])]
        out[way] = {
            "mean_exact_k": statistics.mean(r[way]["exact_k"] for r in rows),
            "mean_rolled_over_right": statistics.mean(rolled) if rolled else math.nan,
            "mean_psnr_db": statistics.mean(min(r[way]["psnr"], 100.0) for r in rows),  # a perfect scene: 100 dB
            "mean_psnr_rgb_db": statistics.mean(min(r[way]["psnr_rgb"], 100.0) for r in rows),
            "perfect_scenes": sum(r[way]["exact_k"] == 1.0 for r in rows),
        }
        if "seconds" in rows[0][way]:
            out[way]["seconds"] = sum(r[way]["seconds"] for r in rows)
    out["truth_demosaic_psnr_db"] = {
        m: statistics.mean(min(r["truth"][m], 100.0) for r in rows) for m in DEMOSAIC_METHODS
    }
    out["gap_exact_k_points"] = 100 * (out["rgb"]["mean_exact_k"] - out["mosaic"]["mean_exact_k"])
    out["gap_exact_k_points_planes"] = 100 * (out["rgb"]["mean_exact_k"] - out["planes"]["mean_exact_k"])
    out["gap_exact_k_points_at_sites"] = 100 * (out["rgb@sites"]["mean_exact_k"] - out["mosaic"]["mean_exact_k"])
    return out


def print_summary(group: str, summary: dict[str, Any]) -> None:
    print(f"\nmeans over {summary['scenes']} scenes ({group}):")
    for way in WAYS:
        e = summary[way]
        rgb_db = "" if math.isnan(e["mean_psnr_rgb_db"]) else f", colour PSNR {e['mean_psnr_rgb_db']:.2f} dB"
        seconds = f", {e['seconds']:.1f} s" if "seconds" in e else ""
        print(
            f"  {way:10s} exact-k {100 * e['mean_exact_k']:.2f}%, "
            f"rolled-over right {100 * e['mean_rolled_over_right']:.2f}%, "
            f"PSNR {e['mean_psnr_db']:.2f} dB{rgb_db}, perfect {e['perfect_scenes']}/{summary['scenes']}{seconds}"
        )
    demosaic = ", ".join(f"{m} {v:.2f} dB" for m, v in summary["truth_demosaic_psnr_db"].items())
    print(f"  demosaicing the true mosaic: {demosaic}")
    print(
        f"  exact-k gap rgb - mosaic: {summary['gap_exact_k_points']:.2f} points "
        f"(rgb - planes: {summary['gap_exact_k_points_planes']:.2f}; rgb@sites - mosaic, the same photosites "
        f"scored alike: {summary['gap_exact_k_points_at_sites']:.2f})"
    )


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=protocols.DEV_SCENES, help="scenes folder (default: %(default)s)")
    ap.add_argument("--scenes", nargs="+", default=None, help="only these scenes (paths relative to --data)")
    ap.add_argument("--split", default="all", choices=protocols.SPLITS, help="only one side of the split")
    ap.add_argument("--max-scenes", type=nonnegative_int, default=0, help="only the first N scenes (0: all)")
    ap.add_argument("--scale", type=positive_int, default=512, help="longest side after downsampling")
    ap.add_argument("--cfa", default="RGGB", choices=CFA_PATTERNS)
    ap.add_argument(
        "--method",
        default=METHODS[0],
        help="unwrap_single method with options (name:key=value,...; default: unwrap_single's, %(default)s)",
    )
    ap.add_argument("--demosaic", default=DEMOSAIC_METHODS[0], choices=DEMOSAIC_METHODS)
    ap.add_argument("--workers", type=positive_int, default=1)
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    scenes = select_scenes(args.data, args.scenes, args.split, args.max_scenes)
    print(f"protocol B mosaicked {args.cfa}: {len(scenes)} scenes, longest side {args.scale}, method {args.method}")
    print(header(), flush=True)
    unwrap(torch.zeros(3, 16, 16), args)  # warm-up: the first call's start-up is not the first scene's time
    unwrap(torch.zeros(1, 16, 16), args, cfa=args.cfa)
    rows = []
    for path in scenes:
        rows.append(run_scene(path, args))
        print(scene_line(rows[-1]), flush=True)
    groups = {}
    for group in GROUPS:
        chosen = [r for r in rows if group == "all" or r["split"] == group]
        if chosen:
            groups[group] = summarize(chosen)
            print_summary(group, groups[group])
    print(json.dumps({"cfa": args.cfa, "method": args.method, "demosaic": args.demosaic, "summary": groups}))
    return groups


if __name__ == "__main__":
    main()
