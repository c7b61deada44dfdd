"""Where the paper's graph cut spends its time: one global min cut near the optimum vs at ``k = 0``, and local windows.

For each named scene under protocol A (same scenes and downsampling as benchmarks/bench_single.py), 8 bits:

1. the paper's loop (``solve_pixels`` from ``k = 0``): seconds per megapixel, cuts, final energy;
2. one global step-1 cut timed at the state the loop converged to, and one at ``k = 0`` (s/MP);
3. a tile-only schedule from ``k = 0`` (tiles of 32, 64, 128 and 256 pixels, no global cut): s/MP and its energy
   relative to the loop's.

This is the measurement behind "Limits" in docs/singleshot.md: one confirming global cut on a textured scene
costs more than the whole <= 5 s/MP budget.

Example (from the repository root):
    python -m research.bench_cuts --scenes CS_Warwick CadesCove Flowers_rgb park
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from research.common import DATA, PERIOD, load, protocol_a, select_scenes
from torch_modulo.singleshot.energy import EnergyParams
from torch_modulo.singleshot.graphcut import pixel_move, plane_energy, solve_pixels, solve_windows
from torch_modulo.singleshot.grid import pair_offsets
from torch_modulo.singleshot.spec import MoveStats

TILES = (32, 64, 128, 256)


def measure(modulus: np.ndarray, tiles: tuple[int, ...] = TILES) -> dict:
    """Seconds per megapixel of the paper's loop, of one global cut (converged and at k = 0) and of tiles."""
    p = EnergyParams.make(8)
    offsets = pair_offsets(8)
    mp = modulus.size / 1e6
    start = time.perf_counter()
    stats = MoveStats()
    converged = solve_pixels(modulus, p, offsets, stats=stats)
    loop_s = time.perf_counter() - start
    energy = plane_energy(converged, p, offsets)
    start = time.perf_counter()
    pixel_move(converged, p, offsets, 1)
    cut_converged_s = time.perf_counter() - start
    start = time.perf_counter()
    pixel_move(modulus, p, offsets, 1)
    cut_zero_s = time.perf_counter() - start
    start = time.perf_counter()
    tiled = modulus.copy()
    for tile in tiles:
        tiled = solve_windows(tiled, p, offsets, window=tile)
    tiles_s = time.perf_counter() - start
    return {
        "mp": mp,
        "paper_s_per_mp": loop_s / mp,
        "paper_cuts": stats.cuts,
        "cut_at_converged_s_per_mp": cut_converged_s / mp,
        "cut_at_zero_s_per_mp": cut_zero_s / mp,
        "tiles_s_per_mp": tiles_s / mp,
        "tiles_energy_ratio": plane_energy(tiled, p, offsets) / energy,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--scenes", nargs="+", default=["CS_Warwick", "CadesCove", "Flowers_rgb", "park"])
    args = ap.parse_args()
    paths = [p for p in select_scenes(args.data) if p.stem in args.scenes]
    if not paths:
        raise SystemExit(f"none of {args.scenes} under {args.data}")
    rows = {}
    print("scene, MP | paper loop s/MP, cuts | one global cut at the converged state, at k = 0 (s/MP)", end="")
    print(" | tiles s/MP, E/E_paper")
    for path in paths:
        modulus = np.mod(protocol_a(load(path, 512))[0], PERIOD).astype(np.int64)
        row = rows[path.stem] = measure(modulus)
        print(
            f"{path.stem[:20]:20s} {row['mp']:.3f} | {row['paper_s_per_mp']:6.1f} {row['paper_cuts']:3d} | "
            f"{row['cut_at_converged_s_per_mp']:5.1f} {row['cut_at_zero_s_per_mp']:5.1f} | "
            f"{row['tiles_s_per_mp']:6.1f} {row['tiles_energy_ratio']:.4f}",
            flush=True,
        )
    print(json.dumps({"bench_cuts": rows}))


if __name__ == "__main__":
    main()
