"""Protocol N: multi-shot recovery under sensor noise, modulo decoder against the oracle and the intensity merge.

Every dev scene, RGB (a grey scene as its one channel), longer side <= 512. The radiance is scaled so that the 0.1th
percentile of its positive values reads 16 counts at the longest exposure (1); the scene needs
``ceil(log2(max / that percentile) + 4)`` stops; 8 bits. For each noise model (q = 1 e-/count with 1 e- read
noise, q = 16 with 16 e-):

- modulo: exposures from ``plan_exposures(stops, 8, noise=noise)`` (the longest normalised to 1), captured by
  ``SimulatedModuloSensor`` and decoded by ``unwrap_multi(..., noise=noise)``, the defaults (the plan and the
  decoder with spatial evidence); with ``--no-spatial`` both for each pixel decoded alone (``spatial=False``);
- blind: the noise-free plan (ratios near 2^N) decoded by the noise-free robust rule, as before noise-aware decoding;
- oracle: the longest frame's noisy count with its rollover count known (the same noise draws: the simulated
  intensity sensor with bits=53 on float64 input and the same seed), divided by its exposure;
- intensity: a conventional 8-bit sensor with the same noise, exposures spread from the same shortest exposure to 1
  with neighbouring ratios of at most R, merged by ``merge_intensity(..., noise=noise)`` (inverse-variance
  weights: the noise-optimal merge), for several R.

Scores over the values whose true radiance is positive: median and 99th percentile of the relative error, and the
share of values more than 50% off (gross); the median in each third of the scene's radiance (dark, mid, bright);
frames used; for the modulo decoder, the share of values more than 3 of its reported standard deviations off
(``return_variance``: 0.27% if it is calibrated and Gaussian). Prints a table and a JSON summary.

    python benchmarks/bench_noise.py                 # all dev scenes, both noise models
    python benchmarks/bench_noise.py --limit 3       # a quick look
    python benchmarks/bench_noise.py --no-spatial    # the plan and decoder for each pixel alone
    python benchmarks/bench_noise.py --frames 6 --modulo-only   # plans of at most 6 frames: frames against error
    python benchmarks/bench_noise.py --longest-frames 2 --modulo-only   # the longest exposure twice
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
import warnings
from pathlib import Path

import torch

import torch_modulo as tm
from torch_modulo import protocols
from torch_modulo._argtypes import nonnegative_int, positive_int
from torch_modulo.sensors import NoiseModel, SimulatedIntensitySensor, SimulatedModuloSensor

NOISES = {"q1": NoiseModel(electrons_per_count=1.0, read_noise=1.0), "q16": NoiseModel(16.0, 16.0)}
INTENSITY_RATIOS = (16.0, 4.0, 2.0, 1.25)
INTENSITY_KEYS = [f"intensity_r{r:g}" for r in INTENSITY_RATIOS]
BANDS = protocols.RADIANCE_BANDS
scores = protocols.protocol_n_scores


def calibration(estimate: torch.Tensor, variance: torch.Tensor, truth: torch.Tensor) -> float:
    """The share of values more than 3 reported standard deviations off (0.27% for a calibrated Gaussian)."""
    mask = truth > 0
    off = (estimate[mask] - truth[mask]).abs() > 3.0 * variance[mask].sqrt()
    return float(off.double().mean())


def geometric(first: float, ratio: float) -> list[float]:
    """Exposures from ``first`` to 1 with neighbouring ratios of at most ``ratio``, evenly spread."""
    if first >= 1:
        return [1.0]
    count = 1 + math.ceil(math.log(1 / first) / math.log(ratio) - 1e-12)
    step = (1 / first) ** (1 / (count - 1))
    return [first * step**i for i in range(count - 1)] + [1.0]


def blind_scores(batch: torch.Tensor, radiance: torch.Tensor, stops: int, noise: NoiseModel, seed: int) -> dict:
    """The noise-blind way: the noise-free plan (ratios near 2^N) decoded by the noise-free robust rule."""
    plan = tm.plan_exposures(stops, 8)
    taus = [t / plan[-1] for t in plan]
    moduli = SimulatedModuloSensor(8, noise, seed=seed)(batch, taus).moduli
    return {**scores(tm.unwrap_multi(moduli, taus, 8)[0], radiance), "frames": len(taus)}


def modulo_plan(stops: int, noise: NoiseModel, args: argparse.Namespace) -> list[float]:
    """The noise-aware plan, the longest exposure normalised to 1: ``plan_exposures``, for the decoder with spatial
    evidence unless ``--no-spatial``; with ``--frames K``, the best plan of at most ``K`` exposures (``frames=``) where
    that is fewer than the default plan's (a scene whose largest ratios need more than ``K`` takes the fewest they
    need), else the default plan; with ``--longest-frames L``, the longest exposure taken ``L`` times."""
    options = {
        "tolerance": args.tolerance,
        "min_ratio": args.min_ratio,
        "spatial": args.spatial,
        "longest_frames": args.longest_frames,
    }
    plan = tm.plan_exposures(stops, 8, noise=noise, **options)
    for budget in range(min(args.frames, len(plan)), len(plan)) if args.frames else ():
        try:
            plan = tm.plan_exposures(stops, 8, noise=noise, frames=budget, **options)
            break
        except ValueError:  # even the largest ratios need more frames: one more
            continue
    return [t / plan[-1] for t in plan]


def run_scene(path: Path, noise_name: str, seed: int, args: argparse.Namespace) -> dict[str, object]:
    noise = NOISES[noise_name]
    image = protocols.load_scene(path, 512)
    scale, stops = protocols.protocol_n(image)
    radiance = image * scale
    batch = radiance.unsqueeze(0)  # float64 (1, 3, H, W)
    taus = modulo_plan(stops, noise, args)
    start = time.perf_counter()
    moduli = SimulatedModuloSensor(8, noise, seed=seed)(batch, taus).moduli
    truth_counts = SimulatedIntensitySensor(53, noise, seed=seed)(batch, taus).frames
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        decoded, variance = tm.unwrap_multi(moduli, taus, 8, noise=noise, spatial=args.spatial, return_variance=True)
    seconds = time.perf_counter() - start
    row: dict[str, object] = {
        "scene": str(path.relative_to(args.scenes)),
        "noise": noise_name,
        "stops": stops,
        "frames": len(taus),
        "spatial": args.spatial,
        "seconds": seconds,
        "modulo": {**scores(decoded[0], radiance), "beyond_3sd": calibration(decoded[0], variance[0], radiance)},
        "oracle": scores(truth_counts[0, -1] / taus[-1], radiance),
        "robust": scores(tm.unwrap_multi(moduli, taus, 8)[0], radiance),
    }
    if args.modulo_only:
        return row
    row["blind"] = blind_scores(batch, radiance, stops, noise, seed)
    for ratio in INTENSITY_RATIOS:
        taus_i = geometric(taus[0], ratio)
        frames = SimulatedIntensitySensor(8, noise, seed=seed)(batch, taus_i).frames
        merged = tm.merge_intensity(frames, taus_i, 8, noise=noise)
        row[f"intensity_r{ratio:g}"] = {**scores(merged[0], radiance), "frames": len(taus_i)}
    return row


def summarise(rows: list[dict[str, object]], noise_name: str) -> dict[str, object]:
    part = [r for r in rows if r["noise"] == noise_name]
    keys = [k for k in ["modulo", "oracle", "robust", "blind", *INTENSITY_KEYS] if k in part[0]]
    out: dict[str, object] = {
        "scenes": len(part),
        "spatial": part[0]["spatial"],
        "frames_modulo": statistics.mean(r["frames"] for r in part),
    }
    for key in keys:
        out[key] = {s: statistics.mean(r[key][s] for r in part) for s in ("median", "p99", "gross", *BANDS)}
        if key.startswith("intensity") or key == "blind":
            out[key]["frames"] = statistics.mean(r[key]["frames"] for r in part)
    out["modulo"]["beyond_3sd"] = statistics.mean(r["modulo"]["beyond_3sd"] for r in part)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=Path, default=protocols.DEV_SCENES)
    parser.add_argument("--limit", type=nonnegative_int, default=0, help="only the first N scenes (0: all)")
    parser.add_argument("--noise", nargs="+", default=list(NOISES), choices=list(NOISES))
    parser.add_argument("--tolerance", type=float, default=1.2, help="plan_exposures tolerance")
    parser.add_argument("--min-ratio", type=float, default=1.5, help="plan_exposures min_ratio")
    parser.add_argument(
        "--spatial",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the plan and decoder with spatial evidence (the default), or for each pixel alone (--no-spatial)",
    )
    parser.add_argument(
        "--longest-frames", type=positive_int, default=1, help="frames at the longest exposure (plan_exposures)"
    )
    parser.add_argument("--frames", type=nonnegative_int, default=0, help="a frame budget per scene (0: none)")
    parser.add_argument("--modulo-only", action="store_true", help="skip the blind and intensity rows (faster)")
    parser.add_argument("--json", type=Path, help="also write the rows and summary here")
    args = parser.parse_args(argv)
    scenes = protocols.list_scenes(args.scenes)
    if args.limit:
        scenes = scenes[: args.limit]
    if not scenes:
        print(f"no scenes under {args.scenes}", file=sys.stderr)
        return 1
    rows = []
    for noise_name in args.noise:
        for i, path in enumerate(scenes):
            row = run_scene(path, noise_name, seed=1000 + i, args=args)
            rows.append(row)
            m, o = row["modulo"], row["oracle"]
            print(
                f"{noise_name:4s} {row['scene'][:40]:40s} stops {row['stops']:2d} frames {row['frames']:2d} "
                f"gross {m['gross']:.4f} (oracle {o['gross']:.4f}) median {m['median']:.4f} "
                f"(oracle {o['median']:.4f}) {row['seconds']:.1f}s",
                flush=True,
            )
    summary = {name: summarise(rows, name) for name in args.noise}
    print("\n| noise | decoder | frames | median rel. error | p99 | gross (>50%) | median: dark / mid / bright |")
    print("|---|---|---|---|---|---|---|")
    for name, s in summary.items():
        for key in [k for k in ["modulo", "oracle", "robust", "blind", *INTENSITY_KEYS] if k in s]:
            frames = s["frames_modulo"] if key in ("modulo", "robust", "oracle") else s[key]["frames"]
            v = s[key]
            bands = " / ".join(f"{v[band]:.4f}" for band in BANDS)
            print(
                f"| {name} | {key} | {frames:.1f} | {v['median']:.4f} | {v['p99']:.4f} | {v['gross']:.4%} | {bands} |"
            )
        print(f"calibration ({name}): {s['modulo']['beyond_3sd']:.4%} of values more than 3 reported sd off")
    print(json.dumps(summary))
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
