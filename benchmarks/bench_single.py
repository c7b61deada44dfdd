"""Benchmark single-shot unwrapping (paper Sec. 4) on real HDR scenes under protocols A, A10 and B.

For every scene under ``--data`` (``.exr`` and ``.hdr``, all folders, sorted by path), build the true counts ``I``
and the 8-bit modulus ``I_m = I mod 256`` of each protocol (:mod:`torch_modulo.protocols`), unwrap it with each
method, and print one row per scene, then per protocol and method a summary over all scenes, one over the training
scenes (``protocols.TRAIN_SOURCES``, the only ones a learned method may train on) and one over the validation
scenes (``protocols.VALIDATION_SOURCES``; a learned method must not train on them): mean exact-k, mean
rolled-over right (exact-k over the values whose true ``k > 0``), mean PSNR (peak 4095, 1023 under A10; after
aligning each channel's global rollover offset; a perfect scene's infinite PSNR enters the mean as 100 dB), scenes
recovered perfectly, seconds per megapixel per channel (total and median over scenes) and, where ``paper`` ran,
the energy reached relative to the faithful solver (plus the truth's energy). A JSON line with the same summary
ends the output.

- Protocol A (paper style): luminance scaled so that its 99.9th percentile is 4095, clipped, floored.
- Protocol A10: the same with the 99.9th percentile at 1023 (at most four rollovers).
- Protocol B (UnModNet style): RGB min-max scaled to [0, 1], exposure chosen by bisection so that 20% of the
  pixels roll over in at least one channel, ``I = floor(clip(x e, 0, 1) * 4095)`` per channel.

Methods: every method :func:`torch_modulo.singleshot.unwrap_single` accepts, with options as
``fast:init=quality,window=0`` or ``guided:denoise=0.7``, and ``skimage`` (scikit-image's ``unwrap_phase``, Herraez
et al. 2002, on ``I_m 2 pi / 256``, a baseline). Every scene is first downsampled by whole-pixel area averaging
(smallest integer factor) until its longer side is at most ``--scale`` (512).

``--memory`` instead measures seconds and peak memory per megapixel on synthetic smooth 12-bit grey scenes of
0.25, 1 and 4 MP (``--memory-sizes``): it runs ``benchmarks/bench_memory.py --channels 1``, each method in a fresh
process (peak RSS above the process's RSS before the call).

Examples:
    python benchmarks/bench_single.py                                     # every scene, A A10 B, five methods
    python benchmarks/bench_single.py --scenes qt-preview/landscape.hdr --methods guided fast   # a smoke run
    python benchmarks/bench_single.py --split validation --protocols A10 --methods guided skimage
    python benchmarks/bench_single.py --memory --methods paper fast

Timings are wall-clock on a possibly shared machine: repeat with ``--repeat`` (the median is kept) and compare
ratios measured in the same run. ``--workers`` (default 1) sets the worker processes per call; ``--device cuda``
hands the modulus to the methods on the GPU (``skimage`` stays on the CPU).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from torch_modulo import protocols
from torch_modulo._argtypes import device as device_arg
from torch_modulo._argtypes import nonnegative_int, positive_int
from torch_modulo.singleshot import unwrap_energy, unwrap_single

BITS = 8
PERIOD = 2**BITS
#: Summary groups: every scene, and each side of the split.
GROUPS = ("all", "train", "validation")


# ----------------------------------------------------------------------------------------------------------- scenes


def select_scenes(data: Path, names: list[str] | None, split: str, max_scenes: int) -> list[Path]:
    """The scenes under ``data``: those named (paths relative to ``data``), else the ``split``; exits if none."""
    if names:
        scenes = [data / name for name in names]
        missing = [str(p) for p in scenes if not p.is_file()]
        if missing:
            raise SystemExit(f"scenes not found: {', '.join(missing)}")
    else:
        scenes = protocols.list_scenes(data, split)
    if max_scenes:
        scenes = scenes[:max_scenes]
    if not scenes:
        raise SystemExit(f"no .exr/.hdr scenes under {data} (split {split!r})")
    return scenes


# ---------------------------------------------------------------------------------------------------------- methods


def skimage_unwrap(modulus: np.ndarray) -> np.ndarray:
    """scikit-image's ``unwrap_phase`` per channel, lifted to non-negative counts (the scores align offsets)."""
    from skimage.restoration import unwrap_phase

    out = np.empty_like(modulus)
    for c in range(modulus.shape[0]):
        out[c] = np.rint(unwrap_phase(modulus[c] * (2 * np.pi / PERIOD)) * (PERIOD / (2 * np.pi)))
    lows = np.floor(out.reshape(out.shape[0], -1).min(axis=1) / PERIOD)
    return out - PERIOD * lows[:, None, None]


def check_methods(specs: list[str], device: torch.device) -> None:
    """Fail before the first scene if unwrap_single refuses a method or its options (its own message)."""
    for spec in specs:
        if spec == "skimage":
            continue
        name, options = protocols.parse_method(spec)
        try:
            probe = torch.zeros(1, 16, 16, dtype=torch.float64, device=device)
            unwrap_single(probe, bits=BITS, method=name, workers=1, **options)
        except (TypeError, ValueError) as error:
            raise SystemExit(f"method {spec!r}: {error}") from None


def run_method(spec: str, modulus: torch.Tensor, workers: int, device: torch.device) -> tuple[torch.Tensor, float]:
    """Restored counts (C, H, W) float64 on the CPU, and seconds."""
    if spec == "skimage":
        start = time.perf_counter()
        out = skimage_unwrap(modulus.numpy())
        return torch.from_numpy(out), time.perf_counter() - start
    name, options = protocols.parse_method(spec)
    x = modulus.to(device)[None]
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    start = time.perf_counter()
    out = unwrap_single(x, bits=BITS, method=name, workers=workers, **options)
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    seconds = time.perf_counter() - start
    return out[0].to("cpu", torch.float64), seconds


def energy(restored: torch.Tensor) -> float:
    return float(unwrap_energy(restored, BITS).sum())


# ----------------------------------------------------------------------------------------------------------- scenes


def score_scene(path: Path, proto: str, args: argparse.Namespace, with_energy: bool) -> dict[str, Any]:
    """Every method on one scene under one protocol: scores, seconds and (optionally) energies."""
    truth = protocols.protocol_counts(protocols.load_scene(path, args.scale), proto)
    modulus = torch.remainder(truth, PERIOD)
    row: dict[str, Any] = {
        "scene": path.relative_to(args.data).as_posix(),
        "split": protocols.scene_split(path, args.data),
        "shape": list(truth.shape),
    }
    mpch = truth.numel() / 1e6
    for spec in args.methods:
        times = []
        for _ in range(max(1, args.repeat)):
            restored, seconds = run_method(spec, modulus, args.workers, args.device)
            times.append(seconds)
        score = protocols.score_scene(restored, truth, BITS, protocols.PROTOCOL_PEAKS[proto])
        row[spec] = {**score._asdict(), "s_per_mp_ch": statistics.median(times) / mpch}
        if with_energy:
            row[spec]["energy"] = energy(restored)
    if with_energy:
        row["energy_truth"] = energy(truth)
    return row


def scene_line(row: dict[str, Any], methods: list[str], with_energy: bool) -> str:
    mark = "*" if row["split"] == "validation" else " "
    line = f"{mark}{row['scene'][-27:]:27s} {'x'.join(map(str, row['shape'])):>13s}"
    ref = row.get("paper", {}).get("energy")
    for m in methods:
        r = row[m]
        line += f" | {100 * r['exact_k']:7.2f} {100 * r['rolled_over_right']:7.2f} {r['psnr']:6.2f}"
        line += f" {r['s_per_mp_ch']:8.2f}"
        if with_energy:
            line += f" {r['energy'] / ref:7.4f}" if ref else f" {'-':>7s}"
    if with_energy:
        line += f" | {row['energy_truth'] / ref:8.4f}" if ref else " |"
    return line


def header(methods: list[str], with_energy: bool) -> str:
    head = f"{'scene (* validation)':28s} {'CxHxW':>13s}"
    for m in methods:
        head += f" | {m[:5] + ' k%':>7s} {'roll%':>7s} {'dB':>6s} {'s/MP/ch':>8s}" + (
            f" {'E/Ep':>7s}" if with_energy else ""
        )
    return head + (f" | {'Etrue/Ep':>8s}" if with_energy else "")


# ---------------------------------------------------------------------------------------------------------- summary


def summarize(rows: list[dict[str, Any]], methods: list[str]) -> dict[str, Any]:
    """Means over the scenes of ``rows`` per method (rolled-over right ignores scenes where nothing rolls over)."""
    total_mpch = sum(math.prod(r["shape"]) for r in rows) / 1e6
    out: dict[str, Any] = {"scenes": len(rows)}
    for m in methods:
        rolled = [r[m]["rolled_over_right"] for r in rows if not math.isnan(r[m]["rolled_over_right"])]
        total_s = sum(r[m]["s_per_mp_ch"] * math.prod(r["shape"]) / 1e6 for r in rows)
        entry = {
            "mean_exact_k": statistics.mean(r[m]["exact_k"] for r in rows),
            "mean_rolled_over_right": statistics.mean(rolled) if rolled else math.nan,
            "mean_psnr_db": statistics.mean(min(r[m]["psnr"], 100.0) for r in rows),
            "perfect_scenes": sum(r[m]["exact_k"] == 1.0 for r in rows),
            "s_per_mp_ch_total": total_s / total_mpch,
            "s_per_mp_ch_median": statistics.median(r[m]["s_per_mp_ch"] for r in rows),
        }
        if "paper" in methods:
            entry["mean_energy_vs_paper"] = statistics.mean(r[m]["energy"] / r["paper"]["energy"] for r in rows)
        out[m] = entry
    if "paper" in methods:
        out["truth"] = {
            "mean_energy_vs_paper": statistics.mean(r["energy_truth"] / r["paper"]["energy"] for r in rows),
            "scenes_truth_above_paper": sum(r["energy_truth"] > r["paper"]["energy"] for r in rows),
        }
    return out


def print_summary(proto: str, group: str, summary: dict[str, Any], methods: list[str]) -> None:
    for m in methods:
        e = summary[m]
        extra = f", E/E_paper {e['mean_energy_vs_paper']:.4f}" if "mean_energy_vs_paper" in e else ""
        print(
            f"{proto:3s} {group:10s} {m:12s}: exact-k {100 * e['mean_exact_k']:.2f}%, rolled-over right "
            f"{100 * e['mean_rolled_over_right']:.2f}%, PSNR {e['mean_psnr_db']:.2f} dB, perfect "
            f"{e['perfect_scenes']}/{summary['scenes']}, s/MP/ch {e['s_per_mp_ch_total']:.2f} total, "
            f"{e['s_per_mp_ch_median']:.2f} median{extra}"
        )


def run_protocol(proto: str, scenes: list[Path], args: argparse.Namespace) -> dict[str, Any]:
    """One protocol over every scene: a row per scene, then the summaries of all, the training and the validation
    scenes."""
    with_energy = args.energy or "paper" in args.methods
    print(f"\n== protocol {proto}: {len(scenes)} scenes, longest side {args.scale}, methods {args.methods}")
    print(header(args.methods, with_energy), flush=True)
    rows = []
    for path in scenes:
        rows.append(score_scene(path, proto, args, with_energy))
        print(scene_line(rows[-1], args.methods, with_energy), flush=True)
    out = {}
    for group in GROUPS:
        chosen = [r for r in rows if group == "all" or r["split"] == group]
        if chosen:
            out[group] = summarize(chosen, args.methods)
            print_summary(proto, group, out[group], args.methods)
    return out


# ------------------------------------------------------------------------------------------------------------- main


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=protocols.DEV_SCENES, help="scenes folder (default: %(default)s)")
    ap.add_argument("--protocols", nargs="+", default=["A", "A10", "B"], choices=list(protocols.PROTOCOL_PEAKS))
    ap.add_argument(
        "--methods",
        nargs="+",
        default=["learned", "guided", "fast", "paper", "skimage"],
        help="unwrap_single methods with options (name:key=value,...) and 'skimage' (default: %(default)s)",
    )
    ap.add_argument("--scenes", nargs="+", default=None, help="only these scenes (paths relative to --data)")
    ap.add_argument("--split", default="all", choices=protocols.SPLITS, help="only one side of the split")
    ap.add_argument("--max-scenes", type=nonnegative_int, default=0, help="only the first N scenes (0: all)")
    ap.add_argument("--scale", type=positive_int, default=512, help="longest side after downsampling")
    ap.add_argument("--workers", type=positive_int, default=1)
    ap.add_argument("--device", type=device_arg, default=torch.device("cpu"), help="cpu (default) or cuda")
    ap.add_argument("--repeat", type=positive_int, default=1, help="time each run this many times, keep the median")
    ap.add_argument("--energy", action="store_true", help="also report energies (always on when paper runs)")
    ap.add_argument("--memory", action="store_true", help="synthetic speed/memory scaling instead of scenes")
    ap.add_argument("--memory-sizes", nargs="+", type=float, default=[0.25, 1.0, 4.0])
    args = ap.parse_args(argv)
    if args.scenes and args.split != "all":
        ap.error("--scenes names the scenes: it does not combine with --split")
    if args.memory:  # bench_memory's own synthetic scenes, one worker on the CPU
        given = ["--scenes"] * bool(args.scenes) + ["--split"] * (args.split != "all")
        given += ["--max-scenes"] * bool(args.max_scenes) + ["--data"] * (args.data != protocols.DEV_SCENES)
        given += [
            f"--{k.replace('_', '-')}"
            for k in ("workers", "repeat", "scale", "protocols")
            if getattr(args, k) != ap.get_default(k)
        ]
        given += ["--device"] * (args.device.type != "cpu") + ["--energy"] * args.energy
        if given:
            ap.error(
                f"--memory runs bench_memory.py's scenes on the CPU with one worker: {' '.join(given)} would be ignored"
            )
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    check_methods(args.methods, args.device)
    if args.memory:
        import bench_memory  # beside this script

        sizes = [str(mp) for mp in args.memory_sizes]
        bench_memory.main(["--channels", "1", "--sizes", *sizes, "--methods", *args.methods])
        return
    scenes = select_scenes(args.data, args.scenes, args.split, args.max_scenes)
    summary = {proto: run_protocol(proto, scenes, args) for proto in args.protocols}
    print(
        json.dumps({"bench_single": summary, "scale": args.scale, "workers": args.workers, "device": str(args.device)})
    )


if __name__ == "__main__":
    main()
