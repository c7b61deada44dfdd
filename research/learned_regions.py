"""How much a per-region level decision could add to the learned method: an oracle over its confident regions.

``unwrap_single(method="learned")`` fails mostly by whole regions a period off. Cut the image into the regions
joined by pairs the network is sure of (cost ``-log p <= tau``; a minimum spanning tree joins each such region with
those pairs only, so the tree fixes every level inside it relative to the others), then let an oracle put every
large region (at least ``--min-share`` of the plane) at its best level (the most common ``k_true - k`` of its
pixels); smaller regions keep the tree's levels. The exact-k reached is what a perfect
region-level decision (a per-pixel level head, unary terms in a graph cut, a second exposure) could give without
changing a single pair inside the regions; the tree's own result is the lower line.

    python -m research.learned_regions                          # all 39 scenes, protocols A, A10 and B
    python -m research.learned_regions --split validation --taus 0.01 0.1

Reported per split: mean exact-k / rolled-over right of the tree and of the oracle at each ``tau``, and the mean
number of large regions per plane (how many decisions the oracle makes) with the share of the pixels they hold.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from torch_modulo import protocols
from torch_modulo.singleshot.grid import components, pair_indices, pair_slices
from torch_modulo.singleshot.learned import decode_jumps, load_model, predict_jumps

BITS = 8
PERIOD = 1 << BITS


def confident_regions(cost: np.ndarray, tau: float) -> tuple[int, np.ndarray]:
    """Regions of one plane joined by its pairs of cost ``<= tau``: ``(count, (H, W) labels)``.

    ``cost``: (2, H, W) costs of the right (direction 0) and down (direction 1) pairs, as :func:`predict_jumps`
    returns them; the last column's right pairs and the last row's down pairs are ignored.
    """
    _, h, w = cost.shape
    firsts, seconds = [], []
    for direction, offset in enumerate(((0, 1), (1, 0))):  # the pair is stored at its first (left or upper) end
        first, second = pair_indices(h, w, offset)
        sure = cost[direction][pair_slices(h, w, offset)[0]].ravel() <= tau
        firsts.append(first[sure])
        seconds.append(second[sure])
    count, labels = components(h * w, np.concatenate(firsts), np.concatenate(seconds))
    return count, labels.reshape(h, w)


def oracle_levels(
    k: np.ndarray, true_k: np.ndarray, labels: np.ndarray, count: int, min_share: float
) -> tuple[np.ndarray, int, float]:
    """``k`` with every region of at least ``min_share`` of the pixels shifted to its most common ``true_k - k``
    (ties: the smallest shift); the number of such regions and the share of the pixels they hold."""
    common, sizes = region_modes(true_k - k, labels, count)
    large = sizes >= min_share * labels.size
    shift = np.where(large, common, 0)
    return k + shift[labels], int(large.sum()), float(sizes[large].sum() / labels.size)


def region_modes(d: np.ndarray, labels: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """The most common integer value of ``d`` in each of ``count`` regions (ties: the smallest) and each region's
    size in pixels."""
    d = d.ravel()
    lo = int(d.min())
    votes = np.zeros((count, int(d.max()) - lo + 1), dtype=np.int64)
    np.add.at(votes, (labels.ravel(), d - lo), 1)
    return votes.argmax(axis=1) + lo, votes.sum(axis=1)


def scene_rows(
    truth: torch.Tensor, taus: list[float], net: torch.nn.Module, min_share: float
) -> list[tuple[float, float, float, float]]:
    """(exact-k, rolled-over right, large regions per plane, their share) of the tree, then of the oracle at each
    ``tau``."""
    modulus = torch.remainder(truth, PERIOD).to(torch.int64)
    planes = modulus.numpy()
    jump, cost = predict_jumps(net, modulus, BITS)
    true_k = torch.floor(truth / PERIOD).to(torch.int64).numpy()
    tree = np.stack([decode_jumps(m, j, c, BITS)[0] for m, j, c in zip(planes, jump, cost, strict=True)])
    results = [(tree, 0.0, 0.0)]
    for tau in taus:
        planes_out = [
            oracle_levels(tree[c], true_k[c], *confident_regions(cost[c], tau)[::-1], min_share)
            for c in range(planes.shape[0])
        ]
        k = np.stack([p[0] for p in planes_out])
        results.append((k, float(np.mean([p[1] for p in planes_out])), float(np.mean([p[2] for p in planes_out]))))
    rows = []
    for k, count, share in results:
        score = protocols.score_scene(torch.from_numpy(planes + PERIOD * k).double(), truth.double(), BITS)
        rows.append((score.exact_k, score.rolled_over_right, count, share))
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", default="all", choices=protocols.SPLITS)
    ap.add_argument("--protocols", nargs="+", default=["A", "A10", "B"], choices=list(protocols.PROTOCOL_PEAKS))
    ap.add_argument("--taus", nargs="+", type=float, default=[0.01, 0.1, 0.5])
    ap.add_argument("--scale", type=int, default=512)
    ap.add_argument("--min-share", type=float, default=0.01, help="smallest region the oracle moves (of a plane)")
    args = ap.parse_args(argv)
    net = load_model()
    scenes = protocols.list_scenes(protocols.DEV_SCENES, split=args.split)
    names = ["tree"] + [f"oracle, tau {t:g}" for t in args.taus]
    for proto in args.protocols:
        rows = np.array(
            [
                scene_rows(
                    protocols.protocol_counts(protocols.load_scene(p, args.scale), proto),
                    args.taus,
                    net,
                    args.min_share,
                )
                for p in scenes
            ]
        )  # (scenes, variants, 4)
        for i, name in enumerate(names):
            exact, rolled, count, share = np.nanmean(rows[:, i], axis=0)
            extra = f", {count:.1f} regions moved per plane, holding {share:.1%} of it" if i else ""
            print(f"{proto:3s} {args.split} ({len(scenes)}) {name}: exact-k {exact:.4f}, rolled {rolled:.4f}{extra}")


if __name__ == "__main__":
    main()
