"""Frames against error on protocol N: a table and a figure from ``bench_noise.py --json`` files.

Each file is one run of ``python benchmarks/bench_noise.py --modulo-only [--no-spatial] [--frames K] --json FILE``;
its label is the file name's stem. For each noise model the table gives the run's mean frames, mean median relative
error (and as a multiple of the oracle's on the same frames), gross share and the median in each third of the
radiance; the figure plots the median error over the oracle's against frames, one marker per run, per pixel and with
spatial evidence apart (needs matplotlib).

    python benchmarks/plot_frames.py runs/*.json --plot docs/images/frames_against_error.png

A run is one with spatial evidence where its summary says so (runs written before it did: where the file name holds
"spatial").
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

BANDS = ("dark", "mid", "bright")


def rows(paths: list[Path]) -> list[dict[str, object]]:
    out = []
    for path in paths:
        data = json.loads(path.read_text())
        for noise, summary in data["summary"].items():
            spatial = summary.get("spatial", "spatial" in path.stem)
            modulo, oracle = summary["modulo"], summary["oracle"]
            out.append(
                {
                    "run": path.stem,
                    "noise": noise,
                    "spatial": spatial,
                    "frames": summary["frames_modulo"],
                    "median": modulo["median"],
                    "over_oracle": modulo["median"] / oracle["median"],
                    "gross": modulo["gross"],
                    "oracle_gross": oracle["gross"],
                    **{band: modulo[band] for band in BANDS},
                }
            )
    return sorted(out, key=lambda r: (r["noise"], r["spatial"], r["frames"]))


def plot(table: list[dict[str, object]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(1, 2, figsize=(9.0, 3.8), dpi=120, sharey=True)
    for axis, noise in zip(axes, ("q1", "q16"), strict=True):
        for spatial, marker, label in ((False, "o-", "per pixel"), (True, "s-", "spatial evidence")):
            part = [r for r in table if r["noise"] == noise and r["spatial"] == spatial]
            if part:
                axis.semilogy([r["frames"] for r in part], [r["over_oracle"] for r in part], marker, label=label)
        axis.axhline(1.5, color="grey", linestyle="--", linewidth=1, label="target: 1.5 x oracle")
        axis.set_title(f"{noise}: {'1' if noise == 'q1' else '16'} e- per count")
        axis.set_xlabel("mean frames per scene")
        axis.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("median relative error / oracle's")
    axes[0].legend(fontsize=8)
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", type=Path, nargs="+", help="bench_noise.py --json files")
    parser.add_argument("--plot", type=Path, help="write the figure here")
    args = parser.parse_args(argv)
    table = rows(args.runs)
    print("| noise | run | decoder | frames | median | x oracle | gross | oracle gross | dark / mid / bright |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in table:
        bands = " / ".join(f"{r[band]:.4f}" for band in BANDS)
        decoder = "spatial" if r["spatial"] else "per pixel"
        print(
            f"| {r['noise']} | {r['run']} | {decoder} | {r['frames']:.1f} | {r['median']:.4f} | {r['over_oracle']:.2f} "
            f"| {r['gross']:.3%} | {r['oracle_gross']:.3%} | {bands} |"
        )
    if args.plot:
        plot(table, args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
