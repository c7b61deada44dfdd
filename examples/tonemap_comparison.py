"""One real HDR scene through every tone-mapping operator of torch_modulo, side by side in one PNG.

    python examples/tonemap_comparison.py                               # memorial.hdr -> examples/out/
    python examples/tonemap_comparison.py --input scene.exr --out cmp.png

The panels: Larson, Rushmeier and Piatko's histogram adjustment (the operator the paper uses for its figures,
ref. [20]), CLAHE on log luminance, Reinhard et al. 2002, the logarithmic mapping and exposure + gamma; the last
panel plots each operator's display luminance against world luminance for a sample of the scene's pixels (a
global operator draws one curve; CLAHE, being local, a cloud). The luminance-based operators are shown with the
sRGB transfer function; the gamma panel is its own encoding. Scene: Greg Ward's Memorial Church radiance map
(the paper's Fig. 1 uses a radiance map courtesy of Greg Ward), from the hdr-samples folder of the development
scenes (:data:`torch_modulo.protocols.DEV_SCENES`); without it, name a scene with --input.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from _common import save_figure, stops  # noqa: E402

from torch_modulo import protocols  # noqa: E402
from torch_modulo.tonemap import (  # noqa: E402
    luminance,
    tonemap_clahe,
    tonemap_gamma,
    tonemap_histogram,
    tonemap_log,
    tonemap_reinhard,
)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_INPUT = protocols.DEV_SCENES / "hdr-samples" / "memorial.hdr"
DEFAULT_OUT = ROOT / "examples" / "out" / "tonemap_comparison.png"


def operators(hdr: torch.Tensor) -> dict[str, tuple[Callable[[torch.Tensor], torch.Tensor], bool]]:
    """Label -> (operator, whether it returns linear display values; if not, it returns gamma-2.2 values)."""
    y = luminance(hdr)
    log_avg = float(torch.exp(torch.log(y.clamp_min(1e-12)).mean()))
    ev = -math.log2(log_avg)  # the log mapping is not scale invariant: put the log-average luminance at 1
    return {
        "Larson et al. 1997 histogram\nadjustment (the paper's [20])": (lambda x: tonemap_histogram(x), True),
        "CLAHE on log luminance\n(clip 2, 8x8 tiles)": (lambda x: tonemap_clahe(x, 2.0, (8, 8)), True),
        "Reinhard et al. 2002\n(key 0.18, white = max)": (lambda x: tonemap_reinhard(x, key=0.18), True),
        f"logarithmic, q = k = 1\n(exposure {ev:+.1f} EV)": (lambda x: tonemap_log(x, exposure=ev), True),
        "gamma 2.2, 99th percentile\nof luminance at white": (lambda x: tonemap_gamma(x, 2.2, percentile=99.0), False),
    }


def render(hdr: torch.Tensor, title: str, out: Path, samples: int = 3000, seed: int = 0) -> dict[str, float]:
    """Tone-map ``hdr`` (1, 3, H, W) with every operator and write the comparison figure to ``out``."""
    panels = []
    timings = {}
    world = luminance(hdr).flatten()
    gen = torch.Generator().manual_seed(seed)
    pick = torch.randperm(world.numel(), generator=gen)[:samples]
    pick = pick[world[pick] > 0]
    for label, (fn, linear) in operators(hdr).items():
        t0 = time.perf_counter()
        display = fn(hdr)
        timings[label.split("\n")[0]] = time.perf_counter() - t0
        shown = tonemap_gamma(display, 1.0, srgb=True) if linear else display  # sRGB curve only
        linear_display = display if linear else display.pow(2.2)  # what a gamma-2.2 display emits
        curve = luminance(linear_display).flatten()[pick]
        panels.append((label, shown[0].permute(1, 2, 0).numpy(), curve.numpy()))

    h, w = hdr.shape[-2:]
    cols = 3
    rows = math.ceil((len(panels) + 1) / cols)
    panel_w = 2.6
    fig, axes = plt.subplots(rows, cols, figsize=(cols * panel_w, rows * panel_w * h / w + 0.9), dpi=90)
    axes = axes.ravel()
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, (label, image, _) in zip(axes, panels, strict=False):
        ax.imshow(np.clip(image, 0, 1), interpolation="lanczos")
        ax.set_title(label, fontsize=8)
        ax.set_axis_off()
    plot = axes[len(panels)]
    log_world = np.log10(world[pick].numpy())
    for i, (label, _, curve) in enumerate(panels):
        plot.scatter(log_world, curve, s=1.5, alpha=0.35, color=colours[i % len(colours)], label=label.split("\n")[0])
    plot.set_xlabel("log10 world luminance", fontsize=8)
    plot.set_ylabel("display luminance (linear)", fontsize=8)
    plot.set_title("tone curves on this scene's pixels", fontsize=8)
    plot.tick_params(labelsize=7)
    plot.set_ylim(-0.02, 1.02)
    plot.legend(fontsize=5.5, markerscale=4, loc="upper left", frameon=False)
    for ax in axes[len(panels) + 1 :]:
        ax.set_axis_off()
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    save_figure(fig, out)
    return timings


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--input", type=Path, default=DEFAULT_INPUT, help=f"HDR/EXR scene (default {DEFAULT_INPUT})")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"PNG to write (default {DEFAULT_OUT})")
    args = parser.parse_args(argv)
    if not args.input.is_file():
        parser.error(f"--input {args.input} not found (the development scenes live in {protocols.DEV_SCENES})")
    hdr = protocols.load_scene(args.input, max_side=None).float()  # full size; NaN and negative values zeroed
    hdr = hdr.expand(3, -1, -1)[None]
    title = f"{args.input.name}: {hdr.shape[-1]}x{hdr.shape[-2]}, {stops(luminance(hdr)):.1f} stops (p99.9 / p0.1)"
    timings = render(hdr, title, args.out)
    for name, seconds in timings.items():
        print(f"{name:<40} {seconds * 1e3:8.1f} ms")
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
