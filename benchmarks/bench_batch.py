"""Batch throughput: scenes per second of the folder commands with 1 and 2 worker processes.

    python benchmarks/bench_batch.py                       # every development scene, 3 repeats
    python benchmarks/bench_batch.py --limit 2 --repeat 1  # a quick look
    python benchmarks/bench_batch.py --json bench_batch.json

Each measurement runs the real command (``python -m torch_modulo.cli COMMAND IN OUT --workers W --force``) in a
fresh process, so the pool start-up is included as a user would see it, and reads two times:

- ``engine s``: the batch itself, from the report's ``seconds`` (planning, worker start-up, the jobs, markers);
- ``wall s``: the whole command, interpreter start-up and imports included.

Commands: ``tonemap`` (histogram operator) and ``simulate`` (8 bits, exposures 1,256,65536, noise-free) over the
scenes, ``unwrap`` (multi shot) over the stacks that ``simulate`` wrote, and ``unwrap --single`` with ``--method``
(default ``fast``) over 8-bit modulus images of the first ``--single-limit`` scenes (loaded by
``torch_modulo.protocols.load_scene``: downsampled to a longer side <= 512; RGB scaled so that the luminance's
99.9th percentile is 4095 counts, as in protocol A). The other commands read the scenes at full resolution. The
inputs are staged in a temporary folder (links to the scene files, never copies inside the project). Medians over
``--repeat`` runs; the machine may be shared, so compare ratios measured in the same run rather than absolute
figures across runs.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from torch_modulo import protocols
from torch_modulo._argtypes import positive_int

ROOT = Path(__file__).resolve().parent.parent


def _stage(data: Path, folder: Path, limit: int | None) -> list[Path]:
    """Symbolic links to the first ``limit`` scenes (sorted), flattened into one folder."""
    files = protocols.list_scenes(data)
    files = files[:limit] if limit else files
    folder.mkdir(parents=True)
    for path in files:
        (folder / f"{path.parent.name}__{path.name}").symlink_to(path)
    return files


def _modulus_images(scenes: Path, folder: Path, limit: int) -> int:
    """8-bit modulus images of the scenes (RGB scaled so that the luminance's 99.9th percentile is 4095 counts)."""
    import torch

    from torch_modulo import capture_modulo
    from torch_modulo.io import write_image
    from torch_modulo.tonemap import luminance

    folder.mkdir(parents=True)
    n = 0
    for path in sorted(scenes.iterdir())[:limit]:
        try:
            x = protocols.load_scene(path, 512)
        except OSError:
            continue
        y = luminance(x.unsqueeze(0)).flatten()
        scale = 4095.0 / max(float(torch.quantile(y[:: max(1, y.numel() // 1_000_000)], 0.999)), 1e-12)
        write_image(folder / f"{path.stem}.png", capture_modulo(x * scale, 1.0, bits=8), {"bits": 8, "exposure": 1.0})
        n += 1
    return n


def _run(command: list[str]) -> tuple[float, float, dict[str, Any]]:
    start = time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-m", "torch_modulo.cli", *command, "--force", "--no-progress"],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    wall = time.perf_counter() - start
    if result.returncode not in (0, 1):
        raise RuntimeError(f"{' '.join(command)} failed ({result.returncode}):\n{result.stderr[-2000:]}")
    report = json.loads((Path(command[2]) / f"{command[0]}-report.json").read_text())
    return report["seconds"], wall, report


def _parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "--data", type=Path, default=protocols.DEV_SCENES, help="folder of HDR scenes (default: %(default)s)"
    )
    parser.add_argument("--limit", type=positive_int, default=None, help="use the first N scenes only")
    parser.add_argument("--repeat", type=positive_int, default=3, help="runs per measurement; medians are reported")
    parser.add_argument("--workers", default="1,2", help="worker counts to compare (default: %(default)s)")
    parser.add_argument(
        "--single-limit",
        type=int,
        default=8,
        help="scenes for unwrap --single, which is much slower (default: %(default)s)",
    )
    parser.add_argument("--method", "--solver", default="fast", help="unwrap --single method (default: %(default)s)")
    parser.add_argument(
        "--commands",
        type=_commands,
        default="tonemap,simulate,unwrap,single",
        help="which commands to time, comma-separated, of tonemap, simulate, unwrap, single (default: %(default)s)",
    )
    parser.add_argument("--json", type=Path, default=None, help="also write the summary here")
    return parser.parse_args(argv)


def _commands(text: str) -> str:
    unknown = [c for c in text.split(",") if c not in ("tonemap", "simulate", "unwrap", "single")]
    if unknown or not text:
        raise argparse.ArgumentTypeError(f"expected some of tonemap, simulate, unwrap, single; got {text!r}")
    return text


def _plans(wanted: list[str], tmp_path: Path, args: argparse.Namespace) -> list[tuple[str, list[str]]]:
    """(label, command template) of each command to time; ``{out}`` stands for the output folder."""
    scenes = str(tmp_path / "scenes")
    plans: list[tuple[str, list[str]]] = []
    if "tonemap" in wanted:
        plans.append(("tonemap", ["tonemap", scenes, "{out}"]))
    if "simulate" in wanted or "unwrap" in wanted:
        simulate = ["simulate", scenes, str(tmp_path / "stacks"), "--exposures", "1,256,65536", "--noise", "none"]
        plans.append(("simulate", simulate))
    if "unwrap" in wanted:
        plans.append(("unwrap", ["unwrap", str(tmp_path / "stacks"), "{out}"]))
    if "single" in wanted:
        n = _modulus_images(tmp_path / "scenes", tmp_path / "moduli", args.single_limit)
        print(f"wrote {n} modulus images for unwrap --single", file=sys.stderr)
        single = ["unwrap", str(tmp_path / "moduli"), "{out}", "--single", "--method", args.method]
        plans.append(("unwrap --single", single))
    return plans


def _measure(label: str, template: list[str], w: int, tmp_path: Path, repeat: int) -> dict[str, Any]:
    """Medians of ``repeat`` runs of one command with ``w`` workers."""
    engine, wall = [], []
    report: dict[str, Any] = {}
    for r in range(repeat):
        command = [c.format(out=tmp_path / f"out_{label.replace(' ', '')}_{w}") for c in template]
        command += ["--workers", str(w)]
        e, t, report = _run(command)
        engine.append(e)
        wall.append(t)
        print(f"{label:16s} workers={w} run {r + 1}: engine {e:.2f} s, wall {t:.2f} s", file=sys.stderr)
    counts = report["counts"]
    processed = counts["done"]
    row = {
        "command": label,
        "workers": w,
        "scenes": processed,
        "failed": counts["failed"],
        "engine_s": statistics.median(engine),
        "wall_s": statistics.median(wall),
        "scenes_per_s": processed / statistics.median(engine) if processed else 0.0,
        "scenes_per_s_wall": processed / statistics.median(wall) if processed else 0.0,
        "runs": repeat,
    }
    if counts["failed"]:
        row["failures"] = {e["input"]: e["error"][:160] for e in report["failed"]}
    return row


def _print_table(rows: list[dict[str, Any]]) -> None:
    header = (
        f"{'command':16s} {'workers':>7s} {'scenes':>6s} {'failed':>6s} {'engine s':>9s} {'scenes/s':>9s} "
        f"{'speed-up':>8s} {'wall s':>7s} {'scenes/s (wall)':>15s}"
    )
    print(header)
    print("-" * len(header))
    for r in rows:
        print(
            f"{r['command']:16s} {r['workers']:7d} {r['scenes']:6d} {r['failed']:6d} {r['engine_s']:9.2f} "
            f"{r['scenes_per_s']:9.2f} {r.get('speedup_vs_1', float('nan')):8.2f} {r['wall_s']:7.2f} "
            f"{r['scenes_per_s_wall']:15.2f}"
        )
    for r in rows:
        for name, error in r.get("failures", {}).items():
            print(f"  {r['command']} (workers={r['workers']}) failed {name}: {error}")


def main(argv: list[str] | None = None) -> int:
    args = _parse_args(argv)
    if not args.data.is_dir():
        print(f"no scenes at {args.data}", file=sys.stderr)
        return 1
    workers = [int(w) for w in args.workers.split(",")]
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        tmp_path = Path(tmp)
        files = _stage(args.data, tmp_path / "scenes", args.limit)
        for label, template in _plans(args.commands.split(","), tmp_path, args):
            rows.extend(_measure(label, template, w, tmp_path, args.repeat) for w in workers)

    for label in dict.fromkeys(r["command"] for r in rows):
        mine = {r["workers"]: r for r in rows if r["command"] == label}
        if 1 in mine and mine[1]["scenes_per_s"]:
            for r in mine.values():
                r["speedup_vs_1"] = r["scenes_per_s"] / mine[1]["scenes_per_s"]

    print(f"\n{len(files)} scenes from {args.data} (medians of {args.repeat} runs; cores: {os.cpu_count()})")
    _print_table(rows)
    summary = {
        "data": str(args.data),
        "scenes": len(files),
        "repeat": args.repeat,
        "cpu_count": os.cpu_count(),
        "results": rows,
    }
    print(json.dumps(summary, indent=1))
    if args.json is not None:
        args.json.write_text(json.dumps(summary, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
