"""Time the tone-mapping operators as a ratio to ``tensor.clone()`` of the same batch, measured in the same run.

Elementwise and global layers should stay close to the cost of a copy on a (8, 3, 1024, 1024) float32 batch (the
goal for global operators, BENCHMARKS.md's for elementwise and global layers: within 2x of clone; compiled variants
are not timed here). Each repeat times clone and then every operator once, in turn, so
machine noise hits them alike; the table gives medians, the median of the per-repeat ratios ("paired"), and the
process CPU time (all threads) as a steadier figure on a shared machine.

    python benchmarks/bench_tonemap.py                       # (8, 3, 1024, 1024) float32 on the CPU
    python benchmarks/bench_tonemap.py --size 2,3,256,256    # quick run
    python benchmarks/bench_tonemap.py --device cuda --clahe --json out/bench_tonemap.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import torch

import torch_modulo.tonemap as tmo
from torch_modulo._argtypes import device as device_arg
from torch_modulo._argtypes import positive_int

GLOBAL_OPERATORS: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "gamma": lambda x: tmo.tonemap_gamma(x),
    "log": lambda x: tmo.tonemap_log(x),
    "reinhard": lambda x: tmo.tonemap_reinhard(x),
    "histogram": lambda x: tmo.tonemap_histogram(x),
}
LOCAL_OPERATORS: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "clahe": lambda x: tmo.tonemap_clahe(x),
}
GOAL = 2.0


def _size(text: str) -> tuple[int, int, int, int]:
    try:
        dims = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size must be B,C,H,W integers; got {text!r}") from None
    if len(dims) != 4 or min(dims) < 1 or dims[1] not in (1, 3):
        raise argparse.ArgumentTypeError(f"--size must be B,C,H,W with C = 1 or 3; got {text!r}")
    return dims  # type: ignore[return-value]


def _timer(device: torch.device) -> Callable[[Callable[[], object]], tuple[float, float]]:
    """Wall-clock seconds and this process's CPU seconds (all threads) for one call."""

    def run(fn: Callable[[], object]) -> tuple[float, float]:
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        if device.type == "cuda":
            torch.cuda.synchronize(device)
        return time.perf_counter() - t0, time.process_time() - c0

    return run


def bench(
    size: tuple[int, int, int, int], device: torch.device, dtype: torch.dtype, repeats: int, clahe: bool
) -> dict[str, object]:
    gen = torch.Generator().manual_seed(0)
    # Log-normal radiance spanning about 17 stops (2 sigma either side), like a real HDR scene.
    x = torch.exp(torch.randn(size, generator=gen) * 2.0).to(device=device, dtype=dtype)
    ops = dict(GLOBAL_OPERATORS)
    if clahe:
        ops.update(LOCAL_OPERATORS)
    timed = _timer(device)
    with torch.no_grad():
        timed(lambda: x.clone())
        for fn in ops.values():  # warm-up (allocator, kernels, Kornia imports)
            timed(lambda fn=fn: fn(x))
        times: dict[str, list[tuple[float, float]]] = {name: [] for name in ["clone", *ops]}
        for _ in range(repeats):
            times["clone"].append(timed(lambda: x.clone()))
            for name, fn in ops.items():
                times[name].append(timed(lambda fn=fn: fn(x)))
    clone_ms = statistics.median(t for t, _ in times["clone"]) * 1e3
    clone_cpu_ms = statistics.median(c for _, c in times["clone"]) * 1e3
    rows = {}
    for name in ops:
        ms = statistics.median(t for t, _ in times[name]) * 1e3
        cpu_ms = statistics.median(c for _, c in times[name]) * 1e3
        paired = statistics.median(t / c[0] for (t, _), c in zip(times[name], times["clone"], strict=True))
        rows[name] = {
            "median_ms": round(ms, 3),
            "ratio_to_clone": round(ms / clone_ms, 3),
            "median_paired_ratio": round(paired, 3),
            "cpu_ms": round(cpu_ms, 3),
            "cpu_ratio_to_clone": round(cpu_ms / clone_cpu_ms, 3) if clone_cpu_ms > 0 else None,
            "kind": "global" if name in GLOBAL_OPERATORS else "local",
        }
    return {
        "size": list(size),
        "dtype": str(dtype).replace("torch.", ""),
        "device": str(device),
        "threads": torch.get_num_threads(),
        "repeats": repeats,
        "torch": torch.__version__,
        "machine": platform.processor() or platform.machine(),
        "clone_median_ms": round(clone_ms, 3),
        "clone_cpu_ms": round(clone_cpu_ms, 3),
        "load_average_1min": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None,
        "goal_ratio_global": GOAL,
        "operators": rows,
    }


def _print_table(summary: dict[str, object]) -> None:
    print(
        f"tone mapping on {tuple(summary['size'])} {summary['dtype']} ({summary['device']}, "
        f"{summary['threads']} threads, load {summary['load_average_1min']}), median of {summary['repeats']} repeats"
    )
    print(f"{'operator':<12}{'kind':<8}{'wall ms':>9}{'x clone':>9}{'paired':>9}{'cpu ms':>9}{'cpu x':>8}  goal (wall)")
    print(
        f"{'clone':<12}{'':<8}{summary['clone_median_ms']:>9.1f}{1.0:>9.2f}{1.0:>9.2f}"
        f"{summary['clone_cpu_ms']:>9.1f}{1.0:>8.2f}"
    )
    rows = summary["operators"]
    assert isinstance(rows, dict)
    for name, row in rows.items():
        goal = "" if row["kind"] != "global" else ("ok" if row["median_paired_ratio"] <= GOAL else f"> {GOAL:g}x")
        cpu_x = row["cpu_ratio_to_clone"]
        cpu_x = float("nan") if cpu_x is None else cpu_x
        print(
            f"{name:<12}{row['kind']:<8}{row['median_ms']:>9.1f}{row['ratio_to_clone']:>9.2f}"
            f"{row['median_paired_ratio']:>9.2f}{row['cpu_ms']:>9.1f}{cpu_x:>8.2f}  {goal}"
        )


def _write_json(path: Path, summary: dict[str, object]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as fh:
        json.dump(summary, fh, indent=2)
    os.replace(tmp, path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=_size, default=(8, 3, 1024, 1024), help="B,C,H,W (default 8,3,1024,1024)")
    parser.add_argument("--repeats", type=positive_int, default=7, help="timed repeats per operator (default 7)")
    parser.add_argument("--device", type=device_arg, default=torch.device("cpu"), help="cpu or cuda (default cpu)")
    parser.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    parser.add_argument("--clahe", action="store_true", help="also time CLAHE (a local operator, not in the goal)")
    parser.add_argument("--json", type=Path, default=None, help="also write the JSON summary to this file")
    args = parser.parse_args(argv)
    summary = bench(args.size, args.device, getattr(torch, args.dtype), args.repeats, args.clahe)
    _print_table(summary)
    print(json.dumps(summary))
    if args.json is not None:
        _write_json(args.json, summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
