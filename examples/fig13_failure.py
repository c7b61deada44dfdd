"""Fig. 13 of the paper: a failure case of single-shot unwrapping (a bright sun) that two captures recover.

    python examples/fig13_failure.py                 # writes examples/out/fig13_failure.png
    python examples/fig13_failure.py --quick --out /tmp/figs
    python examples/fig13_failure.py --scene polyhaven-cc0/sky.exr

Paper (Sec. 7, Fig. 13): "when the local dynamic range of ground truth is extremely huge (the region in the sun),
our single modulo image unwrapping method may fail, multi-shot recovery is required."

Here: a landscape with the sun in view (qt-preview/landscape.hdr of the development scenes, 256x128 RGBE; the Poly
Haven panoramas with a sun are lossy DWAB files whose compression rings around the sun, with large negative values
next to it; the embedded CC0 scene, which has no sun, is used with --quick, and, under its own name, when the
landscape is absent). Luminance is scaled so that its 99.9th
percentile is 1023 counts (the paper's single-shot ground truths span 10 to 12 stops) and clipped at 2^16 - 1, so
the sun keeps much of its local range (a 16-bit ground truth I). Single shot: I mod 256 unwrapped
by :func:`torch_modulo.unwrap_single` (the paper's graph cut). Two captures: exposures 1/256 and 1 of the same
radiance, 8-bit modulo frames, :func:`torch_modulo.unwrap_multi`. Scores: exact-k over the image and over the
pixels above 1023 counts (the sun and its halo), PSNR of the counts (peak 65535).
"""

from __future__ import annotations

import time
from pathlib import Path

import matplotlib.patches as patches
import numpy as np
import torch
from _common import find_scenes, parser, save_figure, show, table, verdict
from matplotlib import pyplot as plt

from torch_modulo import capture_modulo, exact_k_map, protocols, psnr, unwrap_multi
from torch_modulo.singleshot import unwrap_single
from torch_modulo.tonemap import luminance, tonemap_histogram

BITS = 8
TOP = 2.0**16 - 1
BRIGHT = 1023.0  # the 99.9th percentile of the scene
EXPOSURES = [1 / 256, 1.0]
SCENE = "qt-preview/landscape.hdr"


def ground_truth(path: Path, max_side: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Radiance (counts per unit exposure) and the 16-bit counts I at exposure 1, both (1, 1, H, W) float64."""
    y = luminance(protocols.load_scene(path, max_side)[None])
    p999 = float(torch.quantile(y.flatten().float(), 0.999))
    radiance = (y * (BRIGHT / p999)).clamp(max=TOP)
    return radiance, torch.floor(radiance)


def tonemapped(counts: torch.Tensor) -> np.ndarray:
    return tonemap_histogram(counts.float(), srgb=True)[0, 0].double().numpy()


def wrong_k_overlay(grey: np.ndarray, ok: torch.Tensor) -> np.ndarray:
    """A dimmed grey image with the pixels whose rollover count is wrong in red, (H, W, 3)."""
    rgb = np.repeat(0.6 * grey[..., None], 3, axis=-1)
    rgb[~ok[0, 0].numpy()] = (1.0, 0.1, 0.1)
    return rgb


def box_around(image: torch.Tensor, side: int) -> tuple[int, int, int]:
    """(top, left, side) of a square of about ``side`` pixels centred on the brightest pixel of ``image``."""
    h, w = image.shape[-2:]
    side = min(side, h, w)
    rc, cc = divmod(int(image.flatten().argmax()), w)
    top = min(max(rc - side // 2, 0), h - side)
    left = min(max(cc - side // 2, 0), w - side)
    return top, left, side


def draw(
    stem: str,
    truth: torch.Tensor,
    modulus: torch.Tensor,
    frames: torch.Tensor,
    results: dict[str, torch.Tensor],
    scores: dict[str, dict[str, float]],
) -> plt.Figure:
    """The panels (truth, moduli, both results, the wrong-k map) and their close-ups around the brightest pixel."""
    single, multi, ok_single = results["single"], results["multi"], results["ok_single"]
    h, w = truth.shape[-2:]
    top, left, side = box_around(truth, max(16, h // 4))
    panels = [
        ("ground truth (16 bits)", tonemapped(truth)),
        ("8-bit modulus (exposure 1)", (modulus / 255)[0, 0].numpy()),
        (
            f"single shot: {100 * scores['single shot']['exact_k_bright']:.0f}% exact\nabove {BRIGHT:.0f} counts",
            tonemapped(single),
        ),
        ("8-bit modulus (exposure 1/256)", (frames[0, 0] / 255)[0].numpy()),
        (
            f"two captures: {100 * scores['two captures (1:256)']['exact_k_bright']:.0f}% exact\n"
            f"above {BRIGHT:.0f} counts",
            tonemapped(multi),
        ),
    ]
    panels.insert(3, ("single shot: wrong k in red", wrong_k_overlay(tonemapped(truth), ok_single)))
    fig, axes = plt.subplots(
        2,
        len(panels),
        figsize=(2.3 * len(panels), 2.3 * h / w + 3.4),
        dpi=90,
        gridspec_kw={"height_ratios": [h / w, 1.0], "hspace": 0.25},
    )
    for j, (title, image) in enumerate(panels):
        show(axes[0, j], image, title)
        axes[0, j].add_patch(patches.Rectangle((left, top), side, side, fill=False, ec="deepskyblue", ls="--", lw=1))
        show(axes[1, j], image[top : top + side, left : left + side], "close-up (dashed box)" if j == 0 else "")
    fig.suptitle(f"Fig. 13: {stem}: single shot fails around the sun; two captures recover it", fontsize=9)
    fig.subplots_adjust(left=0.01, right=0.99, bottom=0.02, top=0.86, wspace=0.05)
    return fig


def main(argv: list[str] | None = None) -> dict[str, object]:
    p = parser(__doc__.split("\n\n")[0])
    p.add_argument("--scene", default=None, help=f"scene under the scenes folder (default {SCENE}; 'embedded')")
    args = p.parse_args(argv)
    ((stem, path),) = find_scenes([args.scene or ("embedded" if args.quick else SCENE)], required=bool(args.scene))
    radiance, truth = ground_truth(path, 256 if args.quick else 512)

    modulus = torch.remainder(truth, 2**BITS)
    start = time.perf_counter()
    single = unwrap_single(modulus, bits=BITS, method="fast", workers=1)
    t_single = time.perf_counter() - start
    frames = torch.stack([capture_modulo(radiance, t, bits=BITS) for t in EXPOSURES], dim=1)
    multi = unwrap_multi(frames, EXPOSURES, BITS, return_counts=True)

    bright = truth > BRIGHT
    ok_single = exact_k_map(single, truth, BITS)
    ok_multi = exact_k_map(multi, truth, BITS, align=False)
    scores = {}
    for label, restored, ok in (("single shot", single, ok_single), ("two captures (1:256)", multi, ok_multi)):
        scores[label] = {
            "exact_k": float(ok.double().mean()),
            "exact_k_bright": float(ok[bright].double().mean()) if bool(bright.any()) else float("nan"),
            "psnr": float(psnr(restored, truth, peak=TOP)[0]),
            "identical": bool(torch.equal(restored, truth)),
        }
    print(
        f"Fig. 13: {stem} {tuple(truth.shape[-2:])}, counts up to {int(truth.max())} (16 bits), "
        f"{int(bright.sum())} pixels above {BRIGHT:.0f}; single shot {t_single:.2f} s"
    )
    table(
        [
            [k, f"{100 * v['exact_k']:.2f}", f"{100 * v['exact_k_bright']:.1f}", f"{v['psnr']:.2f}", v["identical"]]
            for k, v in scores.items()
        ],
        ["method", "exact-k %", f"exact-k % above {BRIGHT:.0f}", "PSNR dB (peak 65535)", "identical"],
    )

    fig = draw(stem, truth, modulus, frames, {"single": single, "multi": multi, "ok_single": ok_single}, scores)
    path = save_figure(fig, Path(args.out) / "fig13_failure.png")

    s, m = scores["single shot"], scores["two captures (1:256)"]
    holds = bool(bright.any()) and s["exact_k_bright"] < 0.5 and m["identical"]
    line = verdict(
        holds,
        "single shot fails on a sun, two captures recover it",
        f"above {BRIGHT:.0f} counts: single shot {100 * s['exact_k_bright']:.1f}% exact-k, two captures "
        f"{100 * m['exact_k_bright']:.1f}% (whole image {100 * s['exact_k']:.2f}% vs {100 * m['exact_k']:.2f}%)",
    )
    return {
        "scene": stem,
        "scores": scores,
        "holds": holds,
        "png": path,
        "verdict": line,
        "bright_pixels": int(bright.sum()),
    }


if __name__ == "__main__":
    main()
