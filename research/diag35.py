"""Issue #35 diagnostics: the learned method's stages on one scene, scored and timed one by one.

    python -m research.diag35 SCENE [SCENE ...] --protocols A B [--cfa RGGB] [--scale 512]

Per scene and protocol: exact-k of the tree alone, after the level moves (the default), of ``"guided"``, and the
seconds of the network, the trees, the level moves and ``"guided"``. With ``--cfa``, protocol B mosaicked: the
mosaic's guide solved by the default path (tree, cuts) and the full RGB planes.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

import torch_modulo as tm
from torch_modulo import protocols
from torch_modulo.cfa import split_planes
from torch_modulo.singleshot.learned import (
    BAND,
    decode_jumps,
    load_levels,
    load_model,
    predict_jumps,
    refine_band,
    region_moves,
)
from torch_modulo.singleshot.pathfollow import quality_guided_colour_k

BITS, PERIOD = 8, 256


def exact(k: np.ndarray, truth: torch.Tensor) -> float:
    restored = torch.from_numpy(np.asarray(k, dtype=np.float64) * PERIOD) + torch.remainder(truth, PERIOD)
    return protocols.score_scene(restored, truth, BITS, 4095.0).exact_k


def stages(truth: torch.Tensor, levels: bool = True, cuts: int = 0) -> dict[str, float]:
    """Exact-k and seconds of each stage on (C, H, W) true counts."""
    m = torch.remainder(truth, PERIOD)
    net = load_model()
    lv = load_levels() if levels else None
    t0 = time.perf_counter()
    out = predict_jumps(net, m.float(), BITS, False, 768, BAND, lv)
    jump, cost = out[0], out[1]
    t1 = time.perf_counter()
    planes = m.to(torch.int64).numpy()
    k_tree = np.stack([decode_jumps(p, jump[i], cost[i, :, BAND], BITS)[0] for i, p in enumerate(planes)])
    t2 = time.perf_counter()
    k_fin = k_tree.copy()
    first = jump.astype(np.int64) - BAND
    if cuts:
        k_fin = np.stack([refine_band(p, k_fin[i], cost[i], first[i], BITS, cuts) for i, p in enumerate(planes)])
    t3 = time.perf_counter()
    if levels:
        k_fin = np.stack([region_moves(p, k_fin[i], cost[i], first[i], out[2][i], BITS) for i, p in enumerate(planes)])
    t4 = time.perf_counter()
    k_g = quality_guided_colour_k(planes.astype(np.float64), BITS)
    t5 = time.perf_counter()
    return {
        "tree": exact(k_tree, truth),
        "final": exact(k_fin, truth),
        "guided": exact(k_g, truth),
        "s_net": t1 - t0,
        "s_tree": t2 - t1,
        "s_cuts": t3 - t2,
        "s_levels": t4 - t3,
        "s_guided": t5 - t4,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--protocols", nargs="+", default=["A", "B"])
    ap.add_argument("--scale", type=int, default=512)
    ap.add_argument("--cfa", default=None)
    args = ap.parse_args()
    for name in args.scenes:
        image = protocols.load_scene(protocols.DEV_SCENES / name, args.scale)
        if args.cfa:
            image = image.expand(3, -1, -1) if image.shape[0] == 1 else image
            h, w = image.shape[-2:]
            rgb = protocols.protocol_b(image[:, : h - h % 2, : w - w % 2].contiguous())
            truth = tm.mosaic(rgb, args.cfa)
            t0 = time.perf_counter()
            out = tm.unwrap_single(torch.remainder(truth, PERIOD)[None], BITS, cfa=args.cfa)[0]
            t1 = time.perf_counter()
            mos = protocols.score_scene(split_planes(out), split_planes(truth), BITS, 4095.0).exact_k
            print(f"{name} cfa mosaic {mos:.4f} ({t1 - t0:.2f} s) rgb:", stages(rgb), flush=True)
            continue
        for proto in args.protocols:
            truth = protocols.protocol_counts(image, proto)
            r = stages(truth)
            print(name, proto, {k: round(v, 4) for k, v in r.items()}, flush=True)


if __name__ == "__main__":
    main()
