"""Spatial evidence in noise-aware multi-shot decoding (issue #34 item 1): plans x decoders on protocol N subsets.

Each row is one (plan, decoder) pair on the same scenes and noise draws: the per-pixel plan (``plan_exposures``) or
the spatial plan (``_noisy_plan(..., spatial=True)``, optionally with its smallest ratio forced), decoded alone
(``spatial=False``) or with the neighbours' evidence. Scores as benchmarks/bench_noise.py (means over scenes of
the median, p99, gross share and the median of each third of the scene's radiance).

    python -m research.spatial_noise --limit 4 --noise q1
    python -m research.spatial_noise --skip 4 --limit 4 --noise q16 --ratio 4   # a spatial plan with ratios >= 4
"""

from __future__ import annotations

import argparse
import statistics
import warnings

import torch_modulo as tm
from torch_modulo import protocols
from torch_modulo.multishot import planning
from torch_modulo.sensors import NoiseModel, SimulatedIntensitySensor, SimulatedModuloSensor

NOISES = {"q1": NoiseModel(electrons_per_count=1.0, read_noise=1.0), "q16": NoiseModel(16.0, 16.0)}
BANDS = protocols.RADIANCE_BANDS
scores = protocols.protocol_n_scores


def plan(stops: int, noise: NoiseModel, spatial: bool, ratio: float | None) -> list[float]:
    """A plan with its longest exposure 1: per pixel, or spatial (with ``ratio``: that smallest ratio instead of
    :func:`planning._spatial_min_ratio`'s)."""
    if not spatial:
        taus = tm.plan_exposures(stops, 8, noise=noise)
    else:
        original = planning._spatial_min_ratio
        if ratio is not None:
            planning._spatial_min_ratio = lambda min_ratio, limit: ratio  # type: ignore[assignment]
        try:
            found = planning._noisy_plan(stops, 8, 1.0, 255.0, noise, 3.0, 1.2, 1.5, noise, spatial=True)
        finally:
            planning._spatial_min_ratio = original  # type: ignore[assignment]
        assert found is not None
        taus = found
    return [t / taus[-1] for t in taus]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--limit", type=int, default=4)
    parser.add_argument("--skip", type=int, default=0)
    parser.add_argument("--noise", default="q1", choices=list(NOISES))
    parser.add_argument("--ratio", type=float, help="the spatial plan's smallest ratio (default: the planner's)")
    args = parser.parse_args()
    noise = NOISES[args.noise]
    scenes = protocols.list_scenes(protocols.DEV_SCENES)[args.skip : args.skip + args.limit]
    combos = [("pixel", False, False), ("pixel", True, True), ("spatial", False, False), ("spatial", True, True)]
    rows: dict[str, list[dict[str, float]]] = {}
    frames: dict[str, list[int]] = {"pixel": [], "spatial": []}
    for i, path in enumerate(scenes):
        seed = 1000 + args.skip + i
        image = protocols.load_scene(path, 512)
        scale, stops = protocols.protocol_n(image)
        radiance = image * scale
        batch = radiance.unsqueeze(0)
        for name, spatial_plan in (("pixel", False), ("spatial", True)):
            taus = plan(stops, noise, spatial_plan, args.ratio)
            frames[name].append(len(taus))
            moduli = SimulatedModuloSensor(8, noise, seed=seed)(batch, taus).moduli
            truth = SimulatedIntensitySensor(53, noise, seed=seed)(batch, taus).frames
            rows.setdefault(f"{name} plan, oracle", []).append(scores(truth[0, -1] / taus[-1], radiance))
            for plan_name, _, spatial in (c for c in combos if c[0] == name):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    estimate = tm.unwrap_multi(moduli, taus, 8, noise=noise, spatial=spatial)[0]
                key = f"{plan_name} plan, {'spatial' if spatial else 'per-pixel'} decode"
                rows.setdefault(key, []).append(scores(estimate, radiance))
        print(f"{path.name[:30]:30s} stops {stops:2d} frames {frames['pixel'][-1]:2d} / {frames['spatial'][-1]:2d}")
    pixel, spatial = statistics.mean(frames["pixel"]), statistics.mean(frames["spatial"])
    print(f"frames: per-pixel plan {pixel:.2f}, spatial {spatial:.2f}")
    for key, part in rows.items():
        mean = {k: statistics.mean(r[k] for r in part) for k in part[0]}
        bands = " / ".join(f"{mean[b]:.4f}" for b in BANDS)
        print(f"{key:36s} median {mean['median']:.4f} p99 {mean['p99']:.4f} gross {mean['gross']:.5%} bands {bands}")


if __name__ == "__main__":
    main()
