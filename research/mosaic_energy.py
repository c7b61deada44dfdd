"""Issue #35: can a mosaic's two learned routes be arbitrated by the network's own energy?

    python -m research.mosaic_energy            # all 39 dev scenes, protocol B mosaicked RGGB, longer side <= 512

Per scene: the full RGB planes (the default; scored at the photosites), and three routes of the mosaic: the guide
(the default: interpolated wrapped colours, 4 cuts, no level moves), the guide with level moves and no cuts, and the
cells (``cells=True``: two half-resolution colour images of the photosites). Each route's result is scored (exact-k
over the four colour planes) and given the energy the level moves lower, under the network run on the cells' own
images, (R, G1, B) and (R, G2, B): every pair's jump cost plus every 2 x 2 block's level cost at the level offset
the costs prefer. Then per scene the route of least energy is taken, among two or three routes, and the means and
the scenes more than 2 points below their RGB planes are printed (all 39 and the 13 validation scenes).
"""

from __future__ import annotations

import numpy as np
import torch

import torch_modulo as tm
from torch_modulo import protocols
from torch_modulo.cfa import split_planes
from torch_modulo.singleshot.learned import BAND, load_levels, load_model, pair_costs, predict_jumps

BITS, PERIOD = 8, 256
ROUTES = {"guide": {}, "guide_levels": {"levels": True, "max_cuts": 0}, "cells": {"cells": True}}
#: The two half-resolution colour images of an RGGB cell: (R, G1, B) and (R, G2, B).
CELL_IMAGES = ([0, 1, 3], [0, 2, 3])


def energy(m: np.ndarray, k: np.ndarray, cost: np.ndarray, first: np.ndarray, u: np.ndarray) -> float:
    """Pair costs plus level costs (at the best global level offset) of ``k`` on (C, H, W) moduli ``m``."""
    total = 0.0
    for c in range(m.shape[0]):
        total += sum(float(x.sum()) for x in pair_costs(m[c], k[c], cost[c], first[c], PERIOD))
        h, w = m[c].shape
        per_pixel = u[c].astype(np.float64)[:, np.arange(h)[:, None] // 2, np.arange(w)[None] // 2]
        levels = per_pixel.shape[0]
        total += min(
            float(np.take_along_axis(per_pixel, np.clip(k[c] + g, 0, levels - 1)[None], 0).sum())
            for g in range(-levels, levels + 1)
        )
    return total


def scene_rows(path) -> dict[str, tuple[float, float]]:
    image = protocols.load_scene(path, 512)
    image = image.expand(3, -1, -1) if image.shape[0] == 1 else image
    h, w = image.shape[-2:]
    rgb = protocols.protocol_b(image[:, : h - h % 2, : w - w % 2].contiguous())
    truth = tm.mosaic(rgb, "RGGB")
    planes = split_planes(truth[None])[0]
    moduli = torch.remainder(planes, PERIOD)
    net, levels = load_model(), load_levels()
    models = []
    for cells in CELL_IMAGES:
        jump, cost, u = predict_jumps(net, moduli[cells].float(), BITS, False, 768, BAND, levels)
        models.append((cells, moduli[cells].to(torch.int64).numpy(), cost, jump.astype(np.int64) - BAND, u))
    out = {}
    restored = tm.mosaic(tm.unwrap_single(torch.remainder(rgb, PERIOD)[None], BITS)[0], "RGGB")
    out["rgb"] = (protocols.score_scene(split_planes(restored[None])[0], planes, BITS, 4095.0).exact_k, 0.0)
    for name, options in ROUTES.items():
        result = split_planes(tm.unwrap_single(torch.remainder(truth, PERIOD)[None], BITS, cfa="RGGB", **options))[0]
        k = ((result - moduli) / PERIOD).round().to(torch.int64).numpy()
        e = sum(energy(m, k[cells], cost, first, u) for cells, m, cost, first, u in models)
        out[name] = (protocols.score_scene(result, planes, BITS, 4095.0).exact_k, e)
    return out


def main() -> None:
    validation = {p.name for p in protocols.list_scenes(protocols.DEV_SCENES, split="validation")}
    rows = {}
    for path in protocols.list_scenes(protocols.DEV_SCENES):
        rows[path.name] = scene_rows(path)
        print(path.name, {n: (round(a, 4), round(e, 1)) for n, (a, e) in rows[path.name].items()}, flush=True)
    choices = [(r,) for r in ROUTES] + [("guide", "cells"), ("guide_levels", "cells"), tuple(ROUTES)]
    for routes in choices:
        exact = {s: min((r[x] for x in routes), key=lambda v: v[1])[0] for s, r in rows.items()}
        below = [s for s in rows if exact[s] < rows[s]["rgb"][0] - 0.02]
        print(
            f"least energy of {'+'.join(routes)}: mean {np.mean(list(exact.values())):.4f}, validation "
            f"{np.mean([exact[s] for s in validation]):.4f}, {len(below)} scenes 2 points below their RGB planes"
        )
    best = {s: max(v[0] for n, v in r.items() if n != "rgb") for s, r in rows.items()}
    print(
        f"best route per scene (oracle): mean {np.mean(list(best.values())):.4f}, validation "
        f"{np.mean([best[s] for s in validation]):.4f}, {sum(best[s] < rows[s]['rgb'][0] - 0.02 for s in rows)} below"
    )


if __name__ == "__main__":
    main()
