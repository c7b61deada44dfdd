"""Issue #35: a mosaic's refined guide (the default) fused region by region with the cells' own result.

    python -m research.mosaic_fusion     # all 39 dev scenes, protocol B mosaicked RGGB, longer side <= 512

Per colour plane of the cells' two images: the regions where the cells' counts (aligned by their most common
offset) differ from the default's by a constant are tried largest first (40 per difference, at least 4
photosites), each kept when it lowers that image's network energy (jump costs plus level costs at the default's
best level offset). Prints exact-k of the default, the cells and the fusion.
"""

import json

import numpy as np
import torch
from scipy import ndimage

import torch_modulo as tm
from torch_modulo import protocols
from torch_modulo.cfa import split_planes
from torch_modulo.singleshot.learned import BAND, load_levels, load_model, pair_costs, predict_jumps

P = 256
net, lv = load_model(), load_levels()
CELLS = ([0, 1, 3], [0, 2, 3])


def plane_energy(m, k, cost, first, u, g):
    e = sum(float(x.sum()) for x in pair_costs(m, k, cost, first, P))
    h, w = m.shape
    L = u.shape[0]
    lvl = u.astype(np.float64)[np.clip(k + g, 0, L - 1), np.arange(h)[:, None] // 2, np.arange(w)[None] // 2]
    return e + float(lvl.sum())


def best_offset(m, k, u):
    h, w = m.shape
    L = u.shape[0]
    pp = u.astype(np.float64)[:, np.arange(h)[:, None] // 2, np.arange(w)[None] // 2]
    return min(range(-L, L + 1), key=lambda g: float(np.take_along_axis(pp, np.clip(k + g, 0, L - 1)[None], 0).sum()))


val = {p.name for p in protocols.list_scenes(protocols.DEV_SCENES, split="validation")}
rows = {}
for path in protocols.list_scenes(protocols.DEV_SCENES):
    image = protocols.load_scene(path, 512)
    image = image.expand(3, -1, -1) if image.shape[0] == 1 else image
    h, w = image.shape[-2:]
    rgb = protocols.protocol_b(image[:, : h - h % 2, : w - w % 2].contiguous())
    truth = tm.mosaic(rgb, "RGGB")
    planes = split_planes(truth[None])[0]
    mod = torch.remainder(planes, P)
    ks = {}
    for name, opts in {"ref": {}, "cells": {"cells": True}}.items():
        out = split_planes(tm.unwrap_single(torch.remainder(truth, P)[None], 8, cfa="RGGB", **opts))[0]
        ks[name] = ((out - mod) / P).round().to(torch.int64).numpy()
    fused = ks["ref"].copy()
    for idx, cs in enumerate(CELLS):
        jump, cost, u = predict_jumps(net, mod[cs].float(), 8, False, 768, BAND, lv)
        first = jump.astype(np.int64) - BAND
        ints = mod[cs].to(torch.int64).numpy()
        for j, c in enumerate(cs):
            if idx == 1 and c != 2:
                continue
            kr, kc = ks["ref"][c], ks["cells"][c]
            d = kc - kr
            vals, cnt = np.unique(d, return_counts=True)
            kc = kc - vals[cnt.argmax()]  # align the cells' plane to the refined one
            d = kc - kr
            g = best_offset(ints[j], kr, u[j])
            cur = kr.copy()
            e_cur = plane_energy(ints[j], cur, cost[j], first[j], u[j], g)
            for dv in np.unique(d[d != 0]):
                lab, n = ndimage.label(d == dv)
                sizes = np.bincount(lab.ravel())[1:]
                for rid in np.argsort(-sizes)[:40] + 1:
                    if sizes[rid - 1] < 4:
                        break
                    trial = cur.copy()
                    trial[lab == rid] = kc[lab == rid]
                    e = plane_energy(ints[j], trial, cost[j], first[j], u[j], g)
                    if e < e_cur - 1e-6:
                        cur, e_cur = trial, e
            fused[c] = cur
    r = {}
    for name, k in {"ref": ks["ref"], "cells": ks["cells"], "fused": fused}.items():
        restored = torch.from_numpy(k * P).double() + mod
        r[name] = protocols.score_scene(restored, planes, 8, 4095.0).exact_k
    rows[path.name] = r
    print(path.name, {n: round(v, 4) for n, v in r.items()}, flush=True)
json.dump(rows, open("/tmp/p35/fusion.json", "w"))
for n in ("ref", "cells", "fused"):
    print(
        n,
        round(np.mean([r[n] for r in rows.values()]), 4),
        "val",
        round(np.mean([rows[s][n] for s in rows if s in val]), 4),
    )
