"""Peak memory and time of single-shot unwrapping on large synthetic images (colour by default).

Every (method, size) runs in a fresh process: a smooth 12-bit scene of ``--channels`` channels (a ramp and
Gaussian bumps, no pair steeper than half a period) is built row block by row block (so building it costs little
memory), wrapped to 8 bits and unwrapped once with ``workers=1``. The peak is the process's peak RSS above its RSS
just before the call (after imports, the scene and a small warm-up), so it counts everything the call allocates,
torch and numpy alike, but not the input itself. Exact-k (each channel's offset aligned) checks the result.

Methods take options as in ``benchmarks/bench_single.py``: ``guided:tile_pixels=0`` solves the whole image at once;
``skimage`` is scikit-image's ``unwrap_phase`` (not on mosaics). ``bench_single.py --memory`` runs this script with
``--channels 1``.
With ``--cfa PATTERN`` the RGB scene is mosaicked (an even side) and unwrapped as a mosaic (``unwrap_single(...,
cfa=PATTERN)``); exact-k is then scored on its four colour planes.

Examples:
    python benchmarks/bench_memory.py                                   # guided, 1 and 4 MP, RGB
    python benchmarks/bench_memory.py --sizes 0.25 1 4 16 --methods guided guided:tile_pixels=0 fast
    python benchmarks/bench_memory.py --sizes 36 --methods guided        # a 6000 x 6000 RGB image (~3 GB)
    python benchmarks/bench_memory.py --cfa RGGB --methods learned learned:max_cuts=0   # Bayer mosaics
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from torch_modulo import protocols
from torch_modulo.cfa import CFA_PATTERNS, mosaic, split_planes
from torch_modulo.singleshot import unwrap_single

BITS = 8
PEAK = 4095.0


def synthetic(mp: float, channels: int, seed: int = 0) -> torch.Tensor:
    """(C, S, S) float32 counts of a smooth scene of ``mp`` megapixels, built 256 rows at a time."""
    side = int(round(math.sqrt(mp * 1e6)))
    rng = np.random.default_rng(seed)
    out = torch.empty(channels, side, side)
    x = np.arange(side) / side
    for c in range(channels):
        slope = rng.uniform(300, 900, 2)
        bumps = [(*rng.uniform(0.1, 0.9, 2), rng.uniform(0.05, 0.2), rng.uniform(300, 2500)) for _ in range(6)]
        for r0 in range(0, side, 256):
            y = (np.arange(r0, min(side, r0 + 256)) / side)[:, None]
            img = 20 + slope[0] * x[None, :] + slope[1] * y
            for cy, cx, s, a in bumps:
                img = img + a * np.exp(-((y - cy) ** 2 + (x[None, :] - cx) ** 2) / (2 * s * s))
            out[c, r0 : r0 + 256] = torch.from_numpy(np.floor(np.clip(img, 0, PEAK)))
    return out


def rss_mb() -> float:
    """The process's resident set size now, in MB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def probe(spec: str, mp: float, channels: int, cfa: str | None = None) -> dict[str, Any]:
    """Run in a fresh process: seconds, peak RSS above the RSS before the call, and exact-k."""
    truth = synthetic(mp, channels)
    if cfa is not None:  # one mosaicked frame of the RGB scene
        truth = mosaic(truth[:, : truth.shape[1] // 2 * 2, : truth.shape[2] // 2 * 2], cfa)
    modulus = torch.remainder(truth, 2**BITS)
    if spec == "skimage":
        if cfa is not None:
            raise SystemExit("skimage does not unwrap mosaics")
        from bench_single import skimage_unwrap  # beside this script

        def run(m: torch.Tensor) -> torch.Tensor:
            return torch.from_numpy(skimage_unwrap(m.numpy()))
    else:
        name, options = protocols.parse_method(spec)

        def run(m: torch.Tensor) -> torch.Tensor:
            return unwrap_single(m, BITS, method=name, workers=1, cfa=cfa, **options)

    run(modulus[:, :16, :16].contiguous())  # warm-up
    base = rss_mb()
    start = time.perf_counter()
    restored = run(modulus)
    seconds = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - base
    scored = (restored, truth) if cfa is None else (split_planes(restored), split_planes(truth))
    exact = protocols.score_scene(*scored, BITS, PEAK).exact_k
    return {
        "method": spec,
        "channels": channels,
        "cfa": cfa,
        "mp": truth[0].numel() / 1e6,
        "seconds": seconds,
        "peak_mb": peak,
        "exact_k": exact,
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--methods", nargs="+", default=["guided"])
    ap.add_argument("--sizes", nargs="+", type=float, default=[1.0, 4.0], help="megapixels per channel")
    ap.add_argument("--channels", type=int, default=3)
    ap.add_argument("--cfa", default=None, choices=CFA_PATTERNS, help="unwrap one Bayer mosaic of the RGB scene")
    ap.add_argument("--probe", nargs=2, metavar=("METHOD", "MP"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.probe:
        print(json.dumps(probe(args.probe[0], float(args.probe[1]), args.channels, args.cfa)))
        return
    rows = []
    print(f"{'method':24s} {'MP':>6s} {'s':>8s} {'s/MP':>7s} {'peak MB':>9s} {'MB/MP':>7s} {'exact-k':>8s}")
    for mp in args.sizes:
        for spec in args.methods:
            cmd = [sys.executable, __file__, "--probe", spec, str(mp), "--channels", str(args.channels)]
            cmd += ["--cfa", args.cfa] if args.cfa else []
            res = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if res.returncode != 0:
                print(f"{spec:24s} {mp:6.2f} failed: {res.stderr.strip().splitlines()[-1:]}", flush=True)
                continue
            row = json.loads(res.stdout.strip().splitlines()[-1])
            rows.append(row)
            print(
                f"{spec:24s} {row['mp']:6.2f} {row['seconds']:8.2f} {row['seconds'] / row['mp']:7.2f} "
                f"{row['peak_mb']:9.0f} {row['peak_mb'] / row['mp']:7.1f} {row['exact_k']:8.4f}",
                flush=True,
            )
    print(json.dumps({"memory": rows}))


if __name__ == "__main__":
    main()
