"""Fig. 8 of the paper: a continuous band 0..255 seen by 4-bit cameras, intensity against modulo.

    python examples/fig08_band.py                 # writes examples/out/fig08_band.png
    python examples/fig08_band.py --quick --out /tmp/figs

Paper (Sec. 5.2): a 1-D band whose values range linearly from 0 to 255, captured by 4-bit cameras: an intensity
camera with 2 captures (exposure ratio 16), an intensity camera with 5 captures (ratio 2 each, 1:2:4:8:16) and a
modulo camera with 2 captures (ratio 16). "We can observe obvious quantization effects in both 2 captures and 5
captures cases for an intensity camera [...] multi-shot UHDR gives an almost perfect reconstruction."

Here the band is sampled at ``--samples`` points; the exposures are 1/16 ... 1, so the longest exposure reads the
band in counts and the shortest one never saturates (or rolls over). Intensity frames are merged with
:func:`torch_modulo.merge_intensity` (the binary mask of Sec. 5.2; Debevec's hat weights are printed too), modulo
frames unwrapped with :func:`torch_modulo.unwrap_multi`. All reconstructions use the same convention
``E = I / tau`` (the lower edge of the quantisation cell, Eq. 7), and errors are against the continuous band.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from _common import parser, save_figure, table, verdict
from matplotlib import pyplot as plt

from torch_modulo import capture_intensity, capture_modulo, merge_intensity, unwrap_multi

BITS = 4
EXPOSURES_2 = [1 / 16, 1.0]
EXPOSURES_5 = [1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0]


def reconstruct(band: torch.Tensor) -> dict[str, torch.Tensor]:
    """The band (1, 1, 1, N) radiance reconstructed by each method, keyed by label."""

    def stack(capture, taus):  # (B, M, C, H, W)
        return torch.stack([capture(band, t, bits=BITS) for t in taus], dim=1)

    return {
        "intensity, 2 captures (1:16)": merge_intensity(stack(capture_intensity, EXPOSURES_2), EXPOSURES_2, BITS),
        "intensity, 5 captures (1:2:4:8:16)": merge_intensity(stack(capture_intensity, EXPOSURES_5), EXPOSURES_5, BITS),
        "modulo, 2 captures (1:16)": unwrap_multi(stack(capture_modulo, EXPOSURES_2), EXPOSURES_2, BITS),
        "intensity, 5 captures, hat weights": merge_intensity(
            stack(capture_intensity, EXPOSURES_5), EXPOSURES_5, BITS, weights="hat"
        ),
    }


def main(argv: list[str] | None = None) -> dict[str, object]:
    args = parser(__doc__.split("\n\n")[0]).parse_args(argv)
    n = 256 if args.quick else 1024
    band = torch.linspace(0.0, 255.0, n, dtype=torch.float64).view(1, 1, 1, n)
    results = reconstruct(band)
    upper = band >= 128
    errors: dict[str, dict[str, float]] = {}
    rows = []
    for label, estimate in results.items():
        err = (estimate - band).abs()
        e = {
            "mean": float(err.mean()),
            "max": float(err.max()),
            "rmse": float(err.square().mean().sqrt()),
            "mean_upper": float(err[upper].mean()),
            "levels": int(torch.unique(estimate).numel()),
        }
        errors[label] = e
        rows.append([label, e["mean"], e["rmse"], e["max"], e["mean_upper"], e["levels"]])
    print(f"Fig. 8: band 0..255 at {n} samples, {BITS}-bit cameras; error = |reconstruction - band|")
    table(rows, ["method", "mean err", "RMSE", "max err", "mean err (band >= 128)", "distinct levels"])

    shown = [k for k in results if "hat" not in k]
    fig = plt.figure(figsize=(9.0, 6.4), dpi=100)
    grid = fig.add_gridspec(len(shown) + 2, 2, height_ratios=[1] * (len(shown) + 1) + [2.4], hspace=0.9)
    strip = np.repeat(band[0, 0].numpy(), 24, axis=0)
    ax = fig.add_subplot(grid[0, 0])
    ax.imshow(strip, cmap="gray", vmin=0, vmax=255, aspect="auto")
    ax.set_title("ground truth: band 0..255", fontsize=8)
    ax.set_axis_off()
    fig.add_subplot(grid[0, 1]).set_axis_off()
    vmax = max(errors[k]["max"] for k in shown)
    image = None
    for i, label in enumerate(shown, start=1):
        est = np.repeat(results[label][0, 0].numpy(), 24, axis=0)
        ax = fig.add_subplot(grid[i, 0])
        ax.imshow(est, cmap="gray", vmin=0, vmax=255, aspect="auto")
        ax.set_title(label, fontsize=8)
        ax.set_axis_off()
        ax = fig.add_subplot(grid[i, 1])
        image = ax.imshow(np.abs(est - strip), cmap="inferno", vmin=0, vmax=vmax, aspect="auto")
        ax.set_title(f"|error|: mean {errors[label]['mean']:.2f}, max {errors[label]['max']:.2f}", fontsize=8)
        ax.set_axis_off()
    ax = fig.add_subplot(grid[-1, :])
    x = band[0, 0, 0].numpy()
    for label in shown:
        ax.plot(x, (results[label] - band)[0, 0, 0].numpy(), lw=0.9, label=label)
    ax.set_xlabel("true radiance (band value)", fontsize=8)
    ax.set_ylabel("reconstruction - truth", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, frameon=False, loc="lower left")
    ax.set_xlim(0, 255)
    if image is not None:
        fig.colorbar(image, ax=fig.axes[3:7:2], fraction=0.03, pad=0.01).ax.tick_params(labelsize=6)
    fig.suptitle(f"Fig. 8: a band 0..255 seen by {BITS}-bit cameras (error maps share one colour scale)", fontsize=9)
    path = save_figure(fig, Path(args.out) / "fig08_band.png")

    mod = errors["modulo, 2 captures (1:16)"]
    i2 = errors["intensity, 2 captures (1:16)"]
    i5 = errors["intensity, 5 captures (1:2:4:8:16)"]
    holds = mod["max"] < 1.0 and mod["mean"] < min(i2["mean"], i5["mean"]) and mod["max"] < min(i2["max"], i5["max"])
    line = verdict(
        holds,
        "2 modulo captures beat 2 and 5 intensity captures (4-bit)",
        f"mean |error| {mod['mean']:.2f} vs {i2['mean']:.2f} and {i5['mean']:.2f}; "
        f"max {mod['max']:.2f} vs {i2['max']:.2f} and {i5['max']:.2f}",
    )
    return {"errors": errors, "holds": holds, "png": path, "verdict": line}


if __name__ == "__main__":
    main()
