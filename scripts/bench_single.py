"""Benchmark single-shot unwrapping (paper Sec. 4) on real HDR scenes: protocols A and B of BENCHMARKS.md.

For every scene under ``--data`` (``.exr`` and ``.hdr``, all folders, sorted by path), build the 12-bit truth
``I`` and the 8-bit modulus ``I_m = I mod 256``, unwrap it with each method, and print one row per scene and a
JSON summary per protocol and method: mean exact-k, mean PSNR (peak 4095, after aligning each channel's global
rollover offset), scenes recovered perfectly, seconds per megapixel per channel (total and median over scenes)
and, where ``paper`` ran, the energy reached relative to the faithful solver (plus the truth's energy).

- Protocol A (paper style): luminance ``Y = 0.2126 R + 0.7152 G + 0.0722 B``, scaled so that its 99.9th
  percentile is 4095, clipped to [0, 4095], floored.
- Protocol B (UnModNet style): RGB min-max scaled to [0, 1], exposure chosen by bisection so that 20% of the
  pixels roll over in at least one channel, ``I = floor(clip(x e, 0, 1) * 4095)`` per channel.

Methods: ``guided``, ``paper`` and ``fast`` (torch_modulo.unwrap_single; options as ``fast:init=quality,tile=0``
or ``guided:denoise=0.7``),
``skimage`` (scikit-image's ``unwrap_phase``, Herraez et al. 2002, on ``I_m 2 pi / 256``, the baseline of
BENCHMARKS.md). Every scene is first downsampled by whole-pixel area averaging (smallest integer factor) until
its longer side is at most ``--scale`` (512).

``--memory`` instead measures seconds and peak memory per megapixel on synthetic smooth 12-bit scenes of
0.25, 1 and 4 MP (``--memory-sizes``), each method in a fresh process (peak RSS above the process's RSS after
imports and a warm-up).

Examples:
    python scripts/bench_single.py --max-scenes 4 --methods guided fast skimage
    python scripts/bench_single.py --protocols A B --methods paper fast skimage > /tmp/bench_single.txt
    python scripts/bench_single.py --memory --methods paper fast

Timings are wall-clock on a possibly shared machine: repeat with ``--repeat`` (the median is kept) and compare
ratios measured in the same run. ``--workers`` (default 1) sets the worker processes per call.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

from torch_modulo import protocols

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT.parent / "shared" / "data" / "hdr"
BITS_TRUE = 12
BITS = 8
PERIOD = 2**BITS
PEAK = 2**BITS_TRUE - 1


# ----------------------------------------------------------------------------------------------------- scenes


def load(path: Path, scale: int) -> np.ndarray:
    """(C, H, W) float64 radiance, area-downsampled (torch_modulo.protocols.load_scene)."""
    return protocols.load_scene(path, scale).numpy()


def select_scenes(data: Path, max_scenes: int = 0) -> list[Path]:
    """The .exr/.hdr files under ``data`` sorted by path (the first ``max_scenes`` when > 0); exits if none."""
    scenes = protocols.list_scenes(data)
    if max_scenes:
        scenes = scenes[:max_scenes]
    if not scenes:
        raise SystemExit(f"no .exr/.hdr scenes under {data}")
    return scenes


def protocol_a(rgb: np.ndarray) -> np.ndarray:
    return protocols.protocol_a(torch.from_numpy(rgb), peak=PEAK).numpy()


def protocol_b(rgb: np.ndarray) -> np.ndarray:
    return protocols.protocol_b(torch.from_numpy(rgb), peak=PEAK, period=PERIOD).numpy()


# ------------------------------------------------------------------------------------------------------ methods


def run_method(name: str, modulus: np.ndarray, workers: int) -> tuple[np.ndarray, float]:
    """Restored counts (C, H, W) and seconds."""
    if name == "skimage":
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
    import torch_modulo.singleshot as ss

    method, options = parse_method(name)
    t = torch.from_numpy(modulus).unsqueeze(0)
    start = time.perf_counter()
    out = ss.unwrap_single(t, bits=BITS, method=method, workers=workers, **options)
    return out[0].numpy(), time.perf_counter() - start


def parse_method(spec: str) -> tuple[str, dict]:
    """``"fast:init=quality,tile=0"`` -> ``("fast", {"init": "quality", "tile": 0})`` (numbers and bools parsed)."""
    name, _, rest = spec.partition(":")
    options: dict = {}
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        parsed: object = value
        if value in ("True", "False"):
            parsed = value == "True"
        else:
            for cast in (int, float):
                try:
                    parsed = cast(value)
                    break
                except ValueError:
                    continue
        options[key] = parsed
    return name, options


def aligned(restored: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Shift each channel by the most common rollover difference so that it lines up with the truth."""
    out = restored.copy()
    for c in range(out.shape[0]):
        d = (np.floor(out[c] / PERIOD) - np.floor(truth[c] / PERIOD)).ravel()
        values, counts = np.unique(d, return_counts=True)
        out[c] -= PERIOD * values[counts.argmax()]
    return out


def scores(restored: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """exact-k share and PSNR (peak 4095) of restored counts against the truth."""
    try:
        from torch_modulo.metrics import exact_k_share, psnr
    except ImportError:  # pragma: no cover - the metrics module is part of the package
        exact_k_share = psnr = None
    shifted = aligned(restored, truth)
    t = torch.from_numpy(truth)
    if exact_k_share is not None:
        # exact_k_share aligns the offset itself (and wants non-negative counts); PSNR needs it done here.
        k_ok = float(exact_k_share(torch.from_numpy(restored)[None], t[None], BITS)[0])
        return k_ok, float(psnr(torch.from_numpy(shifted)[None], t[None], PEAK)[0])
    k_ok = float((np.floor(shifted / PERIOD) == np.floor(truth / PERIOD)).mean())
    mse = float(((shifted - truth) ** 2).mean())
    return k_ok, (math.inf if mse == 0 else 10 * math.log10(PEAK**2 / mse))


def energy(restored: np.ndarray) -> float:
    from torch_modulo.singleshot import unwrap_energy

    return float(unwrap_energy(torch.from_numpy(restored), BITS).sum())


# ------------------------------------------------------------------------------------------------------- memory


def synthetic(mp: float, seed: int = 0) -> np.ndarray:
    """A smooth 12-bit scene of ``mp`` megapixels (Gaussian bumps on a ramp), as an (H, W) modulus."""
    side = int(round(math.sqrt(mp * 1e6)))
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:side, 0:side] / side
    img = 200 + 600 * x
    for _ in range(6):
        cy, cx, s, a = rng.uniform(0.1, 0.9), rng.uniform(0.1, 0.9), rng.uniform(0.05, 0.2), rng.uniform(500, 3000)
        img += a * np.exp(-((y - cy) ** 2 + (x - cx) ** 2) / (2 * s * s))
    return np.floor(np.clip(img, 0, PEAK))


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def memory_probe(method: str, mp: float) -> dict:
    """Run in a fresh process: seconds and peak RSS above the post-import baseline."""
    import torch_modulo.singleshot as ss

    truth = synthetic(mp)
    modulus = torch.from_numpy(np.mod(truth, PERIOD))
    if method == "skimage":
        from skimage.restoration import unwrap_phase

        unwrap_phase(np.zeros((8, 8)))
    else:
        ss.unwrap_single(modulus[:16, :16], bits=BITS, method=method, workers=1)
    base = _rss_mb()
    start = time.perf_counter()
    if method == "skimage":
        restored = np.rint(unwrap_phase(modulus.numpy() * (2 * np.pi / PERIOD)) * PERIOD / (2 * np.pi))
        restored -= PERIOD * np.floor(restored.min() / PERIOD)
    else:
        restored = ss.unwrap_single(modulus, bits=BITS, method=method, workers=1).numpy()
    seconds = time.perf_counter() - start
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    ok, _ = scores(restored[None], truth[None])
    return {"method": method, "mp": truth.size / 1e6, "seconds": seconds, "peak_mb": peak - base, "exact_k": ok}


def run_memory(methods: list[str], sizes: list[float]) -> None:
    rows = []
    print(f"{'method':8s} {'MP':>6s} {'s':>8s} {'s/MP':>8s} {'peak MB':>9s} {'MB/MP':>8s} {'exact-k':>8s}")
    for mp in sizes:
        for method in methods:
            cmd = [sys.executable, __file__, "--memory-probe", method, str(mp)]
            res = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if res.returncode != 0:
                print(f"{method:8s} {mp:6.2f} failed: {res.stderr.strip().splitlines()[-1:]}")
                continue
            row = json.loads(res.stdout.strip().splitlines()[-1])
            rows.append(row)
            print(
                f"{method:8s} {row['mp']:6.2f} {row['seconds']:8.2f} {row['seconds'] / row['mp']:8.2f} "
                f"{row['peak_mb']:9.1f} {row['peak_mb'] / row['mp']:8.1f} {row['exact_k']:8.4f}",
                flush=True,
            )
    print(json.dumps({"memory": rows}))


# -------------------------------------------------------------------------------------------------------- main


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--protocols", nargs="+", default=["A", "B"], choices=["A", "B"])
    ap.add_argument("--methods", nargs="+", default=["guided", "fast", "paper", "skimage"])
    ap.add_argument("--max-scenes", type=int, default=0, help="only the first N scenes (0: all)")
    ap.add_argument("--scale", type=int, default=512, help="longest side after downsampling")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=1, help="time each run this many times, keep the median")
    ap.add_argument("--energy", action="store_true", help="also report energies (always on when paper runs)")
    ap.add_argument("--memory", action="store_true", help="synthetic speed/memory scaling instead of scenes")
    ap.add_argument("--memory-sizes", nargs="+", type=float, default=[0.25, 1.0, 4.0])
    ap.add_argument("--memory-probe", nargs=2, metavar=("METHOD", "MP"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)

    if args.memory_probe:
        print(json.dumps(memory_probe(args.memory_probe[0], float(args.memory_probe[1]))))
        return
    if args.memory:
        run_memory(args.methods, args.memory_sizes)
        return

    scenes = select_scenes(args.data, args.max_scenes)
    with_energy = args.energy or "paper" in args.methods
    summary: dict = {}
    for proto in args.protocols:
        rows = []
        print(f"\n== protocol {proto}: {len(scenes)} scenes, longest side {args.scale}, methods {args.methods}")
        head = f"{'scene':28s} {'CxHxW':>13s}"
        for m in args.methods:
            head += f" | {m + ' k%':>9s} {'dB':>6s} {'s/MP/ch':>8s}" + (f" {'E/Ep':>7s}" if with_energy else "")
        print(head + (f" | {'Etrue/Ep':>8s}" if with_energy else ""), flush=True)
        for path in scenes:
            rgb = load(path, args.scale)
            truth = protocol_a(rgb) if proto == "A" else protocol_b(rgb)
            modulus = np.mod(truth, PERIOD)
            row = {"scene": str(path.relative_to(args.data)), "shape": list(truth.shape)}
            mpch = truth.size / 1e6
            for m in args.methods:
                times = []
                for _ in range(max(1, args.repeat)):
                    restored, seconds = run_method(m, modulus, args.workers)
                    times.append(seconds)
                k_ok, db = scores(restored, truth)
                row[m] = {"exact_k": k_ok, "psnr": db, "s_per_mp_ch": statistics.median(times) / mpch}
                if with_energy:
                    row[m]["energy"] = energy(restored)
            if with_energy:
                row["energy_truth"] = energy(truth)
            rows.append(row)
            line = f"{row['scene'][-28:]:28s} {'x'.join(map(str, truth.shape)):>13s}"
            ref = row.get("paper", {}).get("energy")
            for m in args.methods:
                r = row[m]
                line += f" | {100 * r['exact_k']:9.2f} {r['psnr']:6.2f} {r['s_per_mp_ch']:8.2f}"
                if with_energy:
                    line += f" {r['energy'] / ref:7.4f}" if ref else f" {'-':>7s}"
            if with_energy:
                line += f" | {row['energy_truth'] / ref:8.4f}" if ref else " |"
            print(line, flush=True)
        total_mpch = sum(math.prod(r["shape"]) for r in rows) / 1e6
        proto_sum = {}
        for m in args.methods:
            ks = [r[m]["exact_k"] for r in rows]
            dbs = [min(r[m]["psnr"], 100.0) for r in rows]
            spm = [r[m]["s_per_mp_ch"] for r in rows]
            total_s = sum(r[m]["s_per_mp_ch"] * math.prod(r["shape"]) / 1e6 for r in rows)
            entry = {
                "mean_exact_k": statistics.mean(ks),
                "mean_psnr_db": statistics.mean(dbs),
                "perfect_scenes": sum(k == 1.0 for k in ks),
                "s_per_mp_ch_total": total_s / total_mpch,
                "s_per_mp_ch_median": statistics.median(spm),
            }
            if "paper" in args.methods:
                entry["mean_energy_vs_paper"] = statistics.mean(r[m]["energy"] / r["paper"]["energy"] for r in rows)
            proto_sum[m] = entry
        if "paper" in args.methods:
            proto_sum["truth"] = {
                "mean_energy_vs_paper": statistics.mean(r["energy_truth"] / r["paper"]["energy"] for r in rows),
                "scenes_truth_above_paper": sum(r["energy_truth"] > r["paper"]["energy"] for r in rows),
            }
        proto_sum["scenes"] = len(rows)
        summary[proto] = proto_sum
        for m in args.methods:
            e = proto_sum[m]
            extra = f", E/E_paper {e['mean_energy_vs_paper']:.4f}" if "mean_energy_vs_paper" in e else ""
            print(
                f"{proto} {m:8s}: exact-k {100 * e['mean_exact_k']:.2f}%, PSNR {e['mean_psnr_db']:.2f} dB, "
                f"perfect {e['perfect_scenes']}/{len(rows)}, s/MP/ch {e['s_per_mp_ch_total']:.2f} total, "
                f"{e['s_per_mp_ch_median']:.2f} median{extra}"
            )
    print(json.dumps({"bench_single": summary, "scale": args.scale, "workers": args.workers}))


if __name__ == "__main__":
    main()
