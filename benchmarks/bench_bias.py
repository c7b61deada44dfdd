#!/usr/bin/env python
"""Flat fields through the noise-aware multi-shot decoder: its bias and the calibration of its variance.

For each noise preset, the exposures are ``plan_exposures(15, 8, noise=preset, longest=1.0)``; flat fields of
``--size`` x ``--size`` pixels at each radiance level (counts per unit exposure, so counts at the longest exposure)
are captured by ``SimulatedModuloSensor`` and decoded by ``unwrap_multi(..., noise=preset, return_variance=True)``
(the defaults: the plan and the decoder with spatial evidence; ``--no-spatial``: both for each pixel alone)
over ``--seeds`` seeds. The reference is the longest frame alone with its rollover known, ``(c + 1/2) / tau``
(``SimulatedIntensitySensor`` with 53 bits), whose mean is biased near zero by the clip at zero. The target at each
level: ``|decoded mean - truth| <= |reference mean - truth| + 0.1 + 0.005 truth``.

Also printed: the share of values more than 3 reported standard deviations off (0.27% for a calibrated Gaussian;
at a few counts the counts are far from Gaussian).

    python benchmarks/bench_bias.py
    python benchmarks/bench_bias.py --presets q16 --size 32 --seeds 2     # a quick look
    python benchmarks/bench_bias.py --no-spatial                           # each pixel decoded alone
"""

from __future__ import annotations

import argparse
import json

import torch

import torch_modulo as tm
from torch_modulo._argtypes import positive_int
from torch_modulo.sensors import NoiseModel, SimulatedIntensitySensor, SimulatedModuloSensor

LEVELS = (0.0, 0.25, 1.0, 4.0, 16.0, 100.0, 1000.0)


def flat_fields(preset: str, size: int, seeds: int, stops: int = 15, spatial: bool = True) -> dict[str, object]:
    """Decoded and reference means, the allowed bias and the calibration, per level."""
    noise = NoiseModel.preset(preset)
    taus = tm.plan_exposures(stops, 8, noise=noise, longest=1.0, spatial=spatial)
    levels = torch.tensor(LEVELS, dtype=torch.float64)
    radiance = levels.view(-1, 1, 1, 1).expand(-1, 1, size, size)
    decoded = torch.zeros_like(levels)
    reference = torch.zeros_like(levels)
    beyond = torch.zeros_like(levels)
    for seed in range(seeds):
        moduli = SimulatedModuloSensor(8, noise, seed=seed)(radiance, taus).moduli
        estimate, variance = tm.unwrap_multi(moduli, taus, 8, noise=noise, spatial=spatial, return_variance=True)
        decoded += estimate.mean(dim=(1, 2, 3)) / seeds
        beyond += ((estimate - radiance).abs() > 3 * variance.sqrt()).double().mean(dim=(1, 2, 3)) / seeds
        alone = SimulatedIntensitySensor(53, noise, seed=seed + 1000)(radiance, [1.0]).frames[:, 0]
        reference += (alone + 0.5).mean(dim=(1, 2, 3)) / seeds
    allowed = (reference - levels).abs() + 0.1 + 0.005 * levels
    return {
        "preset": preset,
        "spatial": spatial,
        "frames": len(taus),
        "levels": list(LEVELS),
        "decoded": decoded.tolist(),
        "reference": reference.tolist(),
        "allowed": allowed.tolist(),
        "ok": bool(((decoded - levels).abs() <= allowed).all()),
        "beyond_3sd": beyond.tolist(),
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--presets", nargs="+", default=["photon-counting", "q16"], choices=list(NoiseModel.presets))
    parser.add_argument("--size", type=positive_int, default=64)
    parser.add_argument("--seeds", type=positive_int, default=5)
    parser.add_argument(
        "--spatial",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the plan and decoder with spatial evidence (the default), or for each pixel alone",
    )
    args = parser.parse_args(argv)
    rows = [flat_fields(preset, args.size, args.seeds, spatial=args.spatial) for preset in args.presets]
    print("| preset | row | " + " | ".join(f"{level:g}" for level in LEVELS) + " |")
    print("|---|---|" + "---|" * len(LEVELS))
    for row in rows:
        for key in ("decoded", "reference", "allowed", "beyond_3sd"):
            fmt = "{:.2%}" if key == "beyond_3sd" else "{:.3f}"
            cells = " | ".join(fmt.format(v) for v in row[key])
            print(f"| {row['preset']} ({row['frames']} frames) | {key} | {cells} |")
        print(f"| {row['preset']} | within the target | {'yes' if row['ok'] else 'NO'} |")
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
