#!/usr/bin/env python
"""Time the elementwise layers as a ratio to ``tensor.clone()`` of the same data, in the same run.

The goal, on a (8, 3, 1024, 1024) float32 batch: within 2x of clone() (the layers are memory-bandwidth bound).
For the multi-exposure capture and the multi-shot unwrap the data is the (B, M, C, H, W) stack of moduli (M = 3
exposures), so their reference is the clone of that stack; every other operation is compared with the clone of its
(B, C, H, W) input.

The noise-aware rows decode (and simulate) the stack of a ``plan_exposures(16, bits, noise="q16")`` plan (4 frames
at 8 bits) for ``--noise-batch`` items (default 2) of the shape's (C, H, W): ``unwrap_multi noise`` decodes it with
the defaults (spatial evidence), ``simulate noise`` is the noisy ``SimulatedModuloSensor`` that captures it;
``unwrap_multi noise per-pixel`` decodes the plan for each pixel alone (``spatial=False``, 7 frames) that way. Each
against the clone of its stack.

The rows marked "compiled" time the layers under ``torch.compile(layer, fullgraph=True)`` (Inductor), which skips
the value checks by itself; compilation happens in the warm-up call and is not timed. ``--no-compile`` skips them
(compiling takes a while on a small CPU).

Prints a table and a JSON summary (medians over ``--repeats`` runs, interleaved with the clone timings so that
both see the same machine load).

    python benchmarks/bench_elementwise.py                      # the full size
    python benchmarks/bench_elementwise.py --shape 2 3 256 256  # a quick run
    python benchmarks/bench_elementwise.py --no-compile         # eager rows only
    python benchmarks/bench_elementwise.py --noise-only         # the noise-aware rows only
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable

import torch

import torch_modulo as tm
from torch_modulo._argtypes import device as device_arg
from torch_modulo._argtypes import positive_int


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _time(fn: Callable[[], object], device: torch.device) -> float:
    _sync(device)
    start = time.perf_counter()
    fn()
    _sync(device)
    return time.perf_counter() - start


def bench(name: str, fn: Callable[[], object], reference: torch.Tensor, repeats: int) -> dict[str, float | str]:
    """Median time of ``fn`` and of ``reference.clone()``, measured alternately."""
    device = reference.device
    fn()
    reference.clone()  # warm up both
    op_times, clone_times = [], []
    for _ in range(repeats):
        clone_times.append(_time(reference.clone, device))
        op_times.append(_time(fn, device))
    op, ref = statistics.median(op_times), statistics.median(clone_times)
    return {"op": name, "ms": 1e3 * op, "clone_ms": 1e3 * ref, "ratio": op / ref}


def noisy_stack(
    radiance: torch.Tensor, bits: int, items: int, spatial: bool = True
) -> tuple[torch.Tensor, torch.Tensor, list[float]]:
    """The radiance of ``items`` batch items scaled to the q16 plan for 16 stops (with ``spatial``: for the decoder
    with spatial evidence; the radiance spans 16 stops), its noisy moduli and the plan."""
    plan = tm.plan_exposures(16, bits, noise="q16", spatial=spatial)
    scene = radiance[:items] * (2.0**15 / plan[-1])  # 1 to 2**16 counts at the longest exposure
    sensor = tm.sensors.SimulatedModuloSensor(bits, "q16", seed=0)
    return scene, sensor(scene, plan).moduli, plan


def noisy_rows(radiance: torch.Tensor, bits: int, items: int, repeats: int) -> list[dict[str, float | str]]:
    scene, moduli, plan = noisy_stack(radiance, bits, items)
    _, alone, alone_plan = noisy_stack(radiance, bits, items, spatial=False)
    sensor = tm.sensors.SimulatedModuloSensor(bits, "q16", seed=0)
    return [
        bench("unwrap_multi noise", lambda: tm.unwrap_multi(moduli, plan, bits, noise="q16"), moduli, repeats),
        bench(
            "unwrap_multi noise per-pixel",
            lambda: tm.unwrap_multi(alone, alone_plan, bits, noise="q16", spatial=False),
            alone,
            repeats,
        ),
        bench("simulate noise", lambda: sensor(scene, plan), moduli, repeats),
    ]


def compiled_rows(
    radiance: torch.Tensor,
    moduli: torch.Tensor,
    counts: torch.Tensor,
    taus: list[float],
    bits: int,
    repeats: int,
    items: int,
) -> list[dict[str, float | str]]:
    """The layers under ``torch.compile(fullgraph=True)`` with validation off, each against the same clone."""
    device = radiance.device
    stack = tm.ExposureStack(moduli, torch.tensor(taus, dtype=torch.float64, device=device))
    cases = [
        ("modulo_wrap", tm.ModuloWrap(bits), counts, counts),
        ("capture_modulo", tm.ModuloCapture(taus[-1], bits), radiance, radiance),
        ("capture_intensity", tm.IntensityCapture(taus[-1], bits), radiance, radiance),
        ("capture_stack", tm.MultiExposureCapture(taus, bits), radiance, moduli),
        ("unwrap_multi robust", tm.MultiExposureUnwrap(bits), stack, moduli),
    ]
    rows = []
    for name, layer, data, reference in cases:
        fn = torch.compile(layer.to(device), fullgraph=True, dynamic=False)
        rows.append(bench(f"{name} compiled", lambda fn=fn, data=data: fn(data), reference, repeats))
    return rows + noisy_compiled_rows(radiance, bits, repeats, items)


def noisy_compiled_rows(radiance: torch.Tensor, bits: int, repeats: int, items: int) -> list[dict[str, float | str]]:
    """The noise-aware decode under ``torch.compile(fullgraph=True)``, with spatial evidence (the default) and per
    pixel, each on its own plan."""
    rows = []
    for name, spatial in (("unwrap_multi noise compiled", True), ("unwrap_multi noise per-pixel compiled", False)):
        _, noisy, plan = noisy_stack(radiance, bits, items, spatial)
        exposures = torch.tensor(plan, dtype=torch.float64, device=radiance.device)
        fn = torch.compile(tm.MultiExposureUnwrap(bits, noise="q16", spatial=spatial), fullgraph=True, dynamic=False)
        rows.append(bench(name, lambda fn=fn, noisy=noisy, exposures=exposures: fn(noisy, exposures), noisy, repeats))
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shape", type=int, nargs=4, default=[8, 3, 1024, 1024], metavar=("B", "C", "H", "W"))
    parser.add_argument("--exposures", type=float, nargs="+", default=[1.0, 200.0, 40000.0])
    parser.add_argument("--bits", type=int, default=8)
    parser.add_argument("--repeats", type=positive_int, default=7)
    parser.add_argument("--device", type=device_arg, default=torch.device("cpu"))
    parser.add_argument("--dtype", default="float32", choices=["float32", "float64"])
    parser.add_argument("--noise-batch", type=positive_int, default=2, help="batch items of the noise-aware rows")
    parser.add_argument("--no-compile", action="store_true", help="skip the torch.compile rows")
    parser.add_argument("--noise-only", action="store_true", help="only the noise-aware rows")
    args = parser.parse_args(argv)

    where, dtype = args.device, getattr(torch, args.dtype)
    gen = torch.Generator().manual_seed(0)
    # Radiance spanning ~16 stops so that the longest exposure rolls over many times.
    radiance = torch.exp2(torch.rand(args.shape, generator=gen) * 16 - 15).to(where, dtype)
    taus = args.exposures
    moduli = torch.stack([tm.capture_modulo(radiance, t, args.bits) for t in taus], dim=1)
    frames = torch.stack([tm.capture_intensity(radiance, t, args.bits) for t in taus], dim=1)
    counts = torch.floor(radiance * taus[-1])

    rows = (
        []
        if args.noise_only
        else [
            bench("modulo_wrap", lambda: tm.modulo_wrap(counts, args.bits), counts, args.repeats),
            bench("capture_modulo", lambda: tm.capture_modulo(radiance, taus[-1], args.bits), radiance, args.repeats),
            bench(
                "capture_intensity", lambda: tm.capture_intensity(radiance, taus[-1], args.bits), radiance, args.repeats
            ),
            bench("capture_stack", lambda: tm.capture_stack(radiance, taus, args.bits), moduli, args.repeats),
            bench("unwrap_multi robust", lambda: tm.unwrap_multi(moduli, taus, args.bits), moduli, args.repeats),
            bench(
                "unwrap_multi paper",
                lambda: tm.unwrap_multi(moduli, taus, args.bits, method="paper"),
                moduli,
                args.repeats,
            ),
            bench("merge_intensity", lambda: tm.merge_intensity(frames, taus, args.bits), frames, args.repeats),
        ]
    )
    rows += noisy_rows(radiance, args.bits, args.noise_batch, args.repeats)
    if args.noise_only and not args.no_compile:
        rows += noisy_compiled_rows(radiance, args.bits, args.repeats, args.noise_batch)
    elif not args.no_compile:
        rows += compiled_rows(radiance, moduli, counts, taus, args.bits, args.repeats, args.noise_batch)
    print(f"shape {tuple(args.shape)} {args.dtype} on {where}, {torch.get_num_threads()} threads, M = {len(taus)}")
    print(f"{'operation':<37}{'ms':>10}{'clone ms':>10}{'x clone':>9}")
    for row in rows:
        print(f"{row['op']:<37}{row['ms']:>10.1f}{row['clone_ms']:>10.1f}{row['ratio']:>9.2f}")
    summary = {
        "shape": args.shape,
        "dtype": args.dtype,
        "device": str(where),
        "threads": torch.get_num_threads(),
        "exposures": taus,
        "ratios_to_clone": {row["op"]: round(float(row["ratio"]), 3) for row in rows},
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
