"""More context for the learned tree at no training cost: the same network run on the image decimated by 2 or 4.

A modulus image decimated by ``s`` (every ``s``-th pixel) is the modulus image of the decimated radiance, so the
network can read it as it is; there a bright region ``s`` times larger fits in its receptive field. Two ways to use
what it says about the full image, both exact (``I_m + k 2^N`` with integer ``k``):

- **long pairs**: every pair of the decimated image is a pair of full-resolution pixels ``s`` apart, with a jump
  and a cost; one spanning tree (Kruskal on the costs) over the full image's pairs and those long pairs;
- **region shifts**: the decimated image's own tree gives ``k`` on the coarse grid; every region of the full
  image joined by pairs the network is sure of (``research.learned_regions``) is moved to the most common
  difference between that coarse ``k`` and its own, relative to the largest region (optionally only where the
  coarse result is more confident than the fine one).

    python -m research.learned_scales --split validation
    python -m research.learned_scales --split train

Reported: mean exact-k / rolled-over right of the tree and of each variant, per protocol.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from research.learned_regions import confident_regions, region_modes
from torch_modulo import protocols
from torch_modulo.singleshot.grid import path_to_root, spanning_tree
from torch_modulo.singleshot.learned import decode_jumps, load_model, predict_jumps

BITS = 8
PERIOD = 1 << BITS


def long_pairs(
    modulus: np.ndarray, jump: np.ndarray, cost: np.ndarray, step: int, width: int
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The pairs of a plane decimated by ``step`` from a plane ``width`` pixels wide, in its flat indices.

    ``modulus`` (h, w) is the decimated plane, ``jump`` and ``cost`` its (2, h, w) prediction. Returns, per
    direction, ``(first, second, dk, cost)`` with ``dk = k_second - k_first``.
    """
    h, w = modulus.shape
    flat = (np.arange(h)[:, None] * step) * width + np.arange(w)[None, :] * step
    out = []
    for d, (a, b) in enumerate(((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :]))):
        diff = modulus[b].astype(np.int64) - modulus[a]
        wrapped = np.mod(diff + PERIOD // 2, PERIOD) - PERIOD // 2
        dk = (wrapped + PERIOD * jump[d][a].astype(np.int64) - diff) // PERIOD
        out.append((flat[a].ravel(), flat[b].ravel(), dk.ravel(), cost[d][a].ravel().astype(np.float64)))
    return out


def decode_pairs(n: int, pairs: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]) -> np.ndarray:
    """``k`` of ``n`` pixels integrated along the minimum spanning tree of ``pairs`` (``(first, second, dk,
    cost)``; of two pairs joining the same pixels the cheaper is kept), rooted at pixel 0."""
    first, second, dk, cost = (np.concatenate(parts) for parts in zip(*pairs, strict=True))
    lo, hi = np.minimum(first, second), np.maximum(first, second)
    dk = np.where(first == lo, dk, -dk)  # k_hi - k_lo
    key = lo * n + hi
    order = np.lexsort((cost, key))
    keep = order[np.r_[True, key[order][1:] != key[order][:-1]]]
    key, lo, hi, dk, cost = key[keep], lo[keep], hi[keep], dk[keep], cost[keep]
    parent = spanning_tree(n, lo, hi, cost + 1e-9)
    child = np.arange(n)
    a, b = np.minimum(child, parent), np.maximum(child, parent)
    step = dk[np.minimum(np.searchsorted(key, a * n + b), len(key) - 1)]
    step = np.where(child == b, step, -step)  # k_child - k_parent
    step[parent == child] = 0
    return path_to_root(parent, step)


def shift_regions(
    k: np.ndarray, coarse: np.ndarray, labels: np.ndarray, count: int, min_share: float, gate: np.ndarray | None
) -> np.ndarray:
    """``k`` with every region of at least ``min_share`` of the plane moved to its most common ``coarse - k``,
    relative to the largest region's; with ``gate`` (per region, bool), only the regions it allows."""
    shift, sizes = region_modes(coarse - k, labels, count)
    shift -= shift[sizes.argmax()]
    move = sizes >= min_share * labels.size
    if gate is not None:
        move &= gate
    return k + np.where(move, shift, 0)[labels]


def _up(x: np.ndarray, step: int, shape: tuple[int, int]) -> np.ndarray:
    """Nearest-neighbour upsampling of a decimated plane back to ``shape``."""
    return np.repeat(np.repeat(x, step, 0), step, 1)[: shape[0], : shape[1]]


def scene_rows(truth: torch.Tensor, net: torch.nn.Module) -> list[tuple[float, float]]:
    """(exact-k, rolled-over right) of the tree and of each variant (:data:`VARIANTS`) on one scene."""
    planes = torch.remainder(truth, PERIOD).to(torch.int64).numpy()
    c, h, w = planes.shape
    preds = {s: predict_jumps(net, torch.from_numpy(planes[:, ::s, ::s].copy()), BITS) for s in (1, 2, 4)}
    trees = {
        s: [decode_jumps(m, j, q, BITS) for m, j, q in zip(planes[:, ::s, ::s], *preds[s], strict=True)] for s in (1, 2)
    }
    results = [np.stack([t[0] for t in trees[1]])]
    for steps in ((2,), (2, 4)):
        ks = []
        for i in range(c):
            pairs = long_pairs(planes[i], preds[1][0][i], preds[1][1][i], 1, w)
            for s in steps:
                pairs += long_pairs(planes[i, ::s, ::s], preds[s][0][i], preds[s][1][i], s, w)
            ks.append(decode_pairs(h * w, pairs).reshape(h, w))
        results.append(np.stack(ks))
    for gated in (False, True):
        ks = []
        for i in range(c):
            count, labels = confident_regions(preds[1][1][i], 0.01)
            fine_k, fine_conf = trees[1][i]
            coarse_k, coarse_conf = (_up(x, 2, (h, w)) for x in trees[2][i])
            gate = None
            if gated:  # the coarse tree more confident than the fine one, on average over the region
                coarse_sum, fine_sum = (
                    np.bincount(labels.ravel(), np.log(x).ravel(), count) for x in (coarse_conf, fine_conf)
                )
                gate = coarse_sum > fine_sum
            ks.append(shift_regions(fine_k, coarse_k, labels, count, 0.001, gate))
        results.append(np.stack(ks))
    rows = []
    for k in results:
        score = protocols.score_scene(torch.from_numpy(planes + PERIOD * k).double(), truth.double(), BITS)
        rows.append((score.exact_k, score.rolled_over_right))
    return rows


#: The variants :func:`scene_rows` reports after the tree.
VARIANTS = ("long pairs 1/2", "long pairs 1/2 + 1/4", "region shifts 1/2", "region shifts 1/2, gated")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", default="all", choices=protocols.SPLITS)
    ap.add_argument("--protocols", nargs="+", default=["A", "A10", "B"], choices=list(protocols.PROTOCOL_PEAKS))
    ap.add_argument("--scale", type=int, default=512)
    ap.add_argument("--weights", default=None, help="weights file (default: the shipped weights)")
    args = ap.parse_args(argv)
    net = load_model(args.weights)
    scenes = protocols.list_scenes(protocols.DEV_SCENES, split=args.split)
    for proto in args.protocols:
        rows = np.array(
            [scene_rows(protocols.protocol_counts(protocols.load_scene(p, args.scale), proto), net) for p in scenes]
        )
        for name, (exact, rolled) in zip(("tree", *VARIANTS), np.nanmean(rows, axis=0), strict=True):
            print(f"{proto:3s} {args.split} ({len(scenes)}) {name}: exact-k {exact:.4f}, rolled {rolled:.4f}")


if __name__ == "__main__":
    main()
