"""Fig. 14 of the paper (noise): where single-shot and multi-shot unwrapping break as sensor noise grows.

    python examples/fig14_noise.py                 # writes examples/out/fig14_noise.png
    python examples/fig14_noise.py --quick --out /tmp/figs
    python examples/fig14_noise.py --no-single     # multi-shot only (no graph cut)
    python examples/fig14_noise.py --method learned --out /tmp/figs  # single shot by the default method
    python examples/fig14_noise.py --method guided:denoise=0.7 --out /tmp/figs

Paper (Sec. 7, Fig. 14, real data): "As noise is more obvious in the least significant bits, it will degrade
the recovery performance. [...] a longer exposure of 8000 ms modulo image is intentionally captured [...] The number
of wraps and noise level are both much higher [...] Artifacts in the unwrapped result are caused by both factors."

Two radiance maps, each scaled to at most ``PEAK`` = 3840 counts at exposure 1 (15 rollovers of the 8-bit counter;
the 1/16 exposure keeps 16 counts of headroom): the smooth surface of Fig. 2 (on which noise-free single-shot
unwrapping is exact, so every error is the noise's doing) and the luminance of the embedded CC0 room (Poly Haven
"apartment"). They are captured by :class:`torch_modulo.sensors.SimulatedModuloSensor` with read noise ``sigma``
counts rms (``NoiseModel(read_noise=sigma, shot_noise=False)``, one electron per count), ``sigma`` from 0 to 32; a
last level adds photon shot noise (the default ``NoiseModel()``: Poisson with one electron per count, so about 62
counts rms at 3840 counts, plus 1 e- read noise). Recoveries:

- single shot (:func:`torch_modulo.unwrap_single`, the paper's graph cut, ``method="fast"``; ``--method`` picks
  another) of the exposure-1 frame;
- two captures at ratio 16 (exposures 1/16 and 1) and at ratio 256 (1/256 and 1, the largest ratio an 8-bit sensor
  allows) with :func:`torch_modulo.unwrap_multi` (the robust rule).

The reference for each is the same sensor, same seed, with a counter that never rolls over (40 bits): it sees the
same noise, so every error counted is an unwrapping error, not the noise itself. Score: exact-k share (single shot
after aligning the global offset; multi-shot absolute).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from _common import parser, save_figure, show, table, verdict
from fig02_wrap_unwrap import surface
from matplotlib import pyplot as plt

from torch_modulo import exact_k_map, exact_k_share, protocols, unwrap_multi
from torch_modulo.assets import default_scene_path
from torch_modulo.sensors import NoiseModel, SimulatedModuloSensor
from torch_modulo.tonemap import luminance

BITS = 8
PEAK = 3840.0
SIGMAS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)
QUICK_SIGMAS = (0.0, 4.0, 32.0)
SHOT = "shot"
SEED = 7
SINGLE_SMOOTH = "single shot, smooth surface"
SINGLE_ROOM = "single shot, room"
MULTI = {"2 captures 1:16, room": [1 / 16, 1.0], "2 captures 1:256, room": [1 / 256, 1.0]}


def scenes(quick: bool) -> dict[str, torch.Tensor]:
    """Radiance maps (1, 1, H, W) float64 with maximum ``PEAK``: the smooth surface and the room's luminance."""
    smooth = surface(128)  # smaller, its steepest slopes pass 2^(N-1) per pixel and aliasing sets in
    smooth = (smooth - smooth.min()) / (smooth.max() - smooth.min()) * (PEAK - 1) + 0.5
    room = luminance(protocols.load_scene(default_scene_path(), 96 if quick else 256)[None])
    return {"smooth": smooth, "room": room * (PEAK / float(room.max()))}


def noise_model(level: float | str) -> NoiseModel:
    if level == SHOT:
        return NoiseModel()
    return NoiseModel(read_noise=float(level), shot_noise=False)


def capture(radiance: torch.Tensor, exposures: list[float], noise: NoiseModel) -> tuple[torch.Tensor, torch.Tensor]:
    """Moduli (1, M, 1, H, W) and the reference counts that never roll over, with the same noise draws."""
    moduli = SimulatedModuloSensor(BITS, noise, seed=SEED)(radiance, exposures).moduli
    reference = SimulatedModuloSensor(40, noise, seed=SEED)(radiance, exposures).moduli
    return moduli, reference


def run_level(
    maps: dict[str, torch.Tensor], level: float | str, single: bool, method: str = "fast"
) -> dict[str, object]:
    noise = noise_model(level)
    out: dict[str, object] = {}
    if single:
        from torch_modulo.singleshot import unwrap_single

        for label, key in ((SINGLE_SMOOTH, "smooth"), (SINGLE_ROOM, "room")):
            moduli, reference = capture(maps[key], [1.0], noise)
            name, options = protocols.parse_method(method)  # e.g. "guided:denoise=0.7"
            restored = unwrap_single(moduli[:, 0], bits=BITS, method=name, workers=1, **options)
            out[label] = float(exact_k_share(restored, reference[:, 0], BITS)[0])
            if key == "smooth":
                ok = exact_k_map(restored, reference[:, 0], BITS)
                out["_images"] = (moduli[0, 0, 0], restored[0, 0], ok[0, 0])
    for label, taus in MULTI.items():
        moduli, reference = capture(maps["room"], taus, noise)
        counts = unwrap_multi(moduli, taus, BITS, return_counts=True)
        out[label] = float(exact_k_share(counts, reference[:, -1], BITS, align=False)[0])
    return out


def main(argv: list[str] | None = None) -> dict[str, object]:
    p = parser(__doc__.split("\n\n")[0])
    p.add_argument("--no-single", action="store_true", help="skip single-shot unwrapping (the graph cut)")
    p.add_argument(
        "--method",
        default="fast",
        help="unwrap_single method for the single-shot columns, with numeric options as in guided:denoise=0.7 "
        "(default: fast, the graph cut)",
    )
    args = p.parse_args(argv)
    maps = scenes(args.quick)
    levels: list[float | str] = [*(QUICK_SIGMAS if args.quick else SIGMAS), SHOT]
    single = not args.no_single
    results = {level: run_level(maps, level, single, args.method) for level in levels}
    methods = ([SINGLE_SMOOTH, SINGLE_ROOM] if single else []) + list(MULTI)

    print(
        f"Fig. 14: up to {PEAK:.0f} counts ({PEAK / 2**BITS:.0f} rollovers) on an {BITS}-bit modulo sensor; "
        f"exact-k share (%) by read noise (counts rms); '{SHOT}' = Poisson, 1 e-/count, + 1 e- read noise"
    )
    table([[str(lv)] + [f"{100 * results[lv][m]:.2f}" for m in methods] for lv in levels], ["noise"] + methods)

    numeric = [lv for lv in levels if lv != SHOT]
    shown = [lv for lv in (0.0, 16.0, 32.0, SHOT) if lv in levels] if single else []
    fig = plt.figure(figsize=(12.0, 3.6 + 2.6 * len(shown) / 4 * 3 * (len(shown) > 0)), dpi=90)
    rows_n = 1 + (3 if shown else 0)
    grid = fig.add_gridspec(rows_n, max(len(shown), 1), height_ratios=[1.4] + [1] * (rows_n - 1))
    ax = fig.add_subplot(grid[0, :])
    x = [max(lv, 0.25) for lv in numeric]  # sigma = 0 drawn at 0.25 on the log axis
    for m, marker in zip(methods, "osd^", strict=False):
        line = ax.plot(x, [100 * results[lv][m] for lv in numeric], marker=marker, ms=4, label=m)[0]
        ax.axhline(100 * results[SHOT][m], ls=":", lw=0.9, color=line.get_color())
    ax.set_xscale("log", base=2)
    ax.set_xticks(x, ["0"] + [f"{v:g}" for v in numeric[1:]])
    ax.set_xlabel("read noise (counts rms); dotted: photon shot noise (1 e-/count) + 1 e- read noise", fontsize=8)
    ax.set_ylabel("exact-k share (%)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, frameon=False, loc="lower left")
    ax.set_title(
        f"unwrapping under noise ({BITS}-bit counter, up to {PEAK / 2**BITS:.0f} rollovers at exposure 1)", fontsize=9
    )
    for j, level in enumerate(shown):
        modulus, restored, ok = results[level]["_images"]
        label = "shot noise" if level == SHOT else f"read noise {level:g}"
        show(fig.add_subplot(grid[1, j]), modulus.numpy() / 255.0, f"smooth surface: modulus, {label}")
        show(fig.add_subplot(grid[2, j]), restored.numpy(), "single shot (linear)", vmin=0, vmax=PEAK + 200)
        k_map = np.where(ok.numpy()[..., None], np.array([0.85, 0.85, 0.85]), np.array([0.9, 0.1, 0.1]))
        show(fig.add_subplot(grid[3, j]), k_map, f"wrong k in red: {100 * results[level][SINGLE_SMOOTH]:.1f}% right")
    fig.suptitle("Fig. 14: noise in the low bits against single-shot and multi-shot unwrapping", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    path = save_figure(fig, Path(args.out) / "fig14_noise.png")

    summary = {str(lv): {m: results[lv][m] for m in methods} for lv in levels}
    worst = max(numeric)
    # The room's single-shot errors come from the model (its bright window), not the noise: left out of the test.
    tested = [m for m in methods if m != SINGLE_ROOM]
    degrades = all(min(results[worst][m], results[SHOT][m]) < results[0.0][m] for m in tested)
    line = verdict(
        degrades,
        "noise in the low bits breaks unwrapping (single shot only at large noise)",
        "; ".join(
            f"{m}: {100 * results[0.0][m]:.1f}% -> {100 * results[worst][m]:.1f}% at {worst:g} counts, "
            f"{100 * results[SHOT][m]:.1f}% with shot noise"
            for m in methods
        ),
    )
    return {"results": summary, "holds": degrades, "png": path, "verdict": line}


if __name__ == "__main__":
    main()
