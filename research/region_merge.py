"""Region merging on the learned jump probabilities: does summing the evidence of whole borders fix the tree?

``unwrap_single(method="learned")`` joins pixels along a spanning tree of the network's most confident pairs, so a
region's level hangs on the one pair the tree crosses into it. Here the tree's result is cut into regions at its
unsure pairs (cost ``-log p >= tau``), and regions are merged greedily, the pair of neighbouring regions with the
largest margin first, each time at the relative shift ``t`` (whole periods) that minimises the summed cost of
*every* pair on their common border: the region-level analogue of the maximum-likelihood tree, with loop
consistency.

    python -m research.region_merge --taus 0.01 0.1 1.0 --max-scenes 10      # training scenes, protocols A and B

Scenes: the CC0/BSD training split only (the decoder was judged on them); 10 of the 26, drawn with seed 0.
Found (docs/singleshot.md, "Learned"): at most a few tenths of a point either way; not shipped.
"""

from __future__ import annotations

import argparse
import heapq
import time
from pathlib import Path

import numpy as np
import torch

from torch_modulo import protocols
from torch_modulo.singleshot.grid import components
from torch_modulo.singleshot.learned import decode_edges, load_model, predict_edges

#: Cost of a jump outside the network's range.
MAX_COST = 30.0


def _border_tables(m, k, logp, bits, tau, shifts):
    """Region labels of the tree's result cut at unsure pairs, and every region pair's border cost per shift."""
    h, w = m.shape
    period, half = 1 << bits, 1 << (bits - 1)
    kk = logp.shape[1]
    j = (kk - 1) // 2
    cost = np.clip(-np.asarray(logp, dtype=np.float64), 0.0, MAX_COST)
    ids = np.arange(h * w).reshape(h, w)
    restored = m + period * k
    firsts, seconds, jumps, vectors = [], [], [], []
    for direction, (a, b) in enumerate(((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :]))):
        wd = np.mod(m[b] - m[a] + half, period) - half
        firsts.append(ids[a].ravel())
        seconds.append(ids[b].ravel())
        jumps.append(((restored[b] - restored[a] - wd) // period + j).ravel())
        vectors.append(cost[direction][(slice(None), *a)].reshape(kk, -1).T)
    first, second, n, cv = map(np.concatenate, (firsts, seconds, jumps, vectors))
    inside = (n >= 0) & (n < kk)
    current = np.where(inside, cv[np.arange(n.size), np.clip(n, 0, kk - 1)], MAX_COST)
    joined = current < tau
    count, labels = components(h * w, first[joined], second[joined])
    la, lb = labels[first], labels[second]
    border = la != lb
    la, lb, n, cv = la[border], lb[border], n[border], cv[border]
    x, y = np.minimum(la, lb), np.maximum(la, lb)
    sign = np.where(lb == y, 1, -1)  # shifting region y by t changes the pair's jump by sign * t
    index = n[:, None] + sign[:, None] * shifts[None, :]
    valid = (index >= 0) & (index < kk)
    table = np.where(valid, np.take_along_axis(cv, np.clip(index, 0, kk - 1), 1), MAX_COST)
    key = x.astype(np.int64) * count + y
    order = np.argsort(key, kind="stable")
    key, table = key[order], table[order]
    keys, starts = np.unique(key, return_index=True)
    sums = np.add.reduceat(table, starts, axis=0) if keys.size else np.zeros((0, shifts.size))
    return count, labels, {divmod(int(q), count): t for q, t in zip(keys, sums, strict=True)}


def merge_regions(m: np.ndarray, k: np.ndarray, logp: np.ndarray, bits: int, tau: float = 0.1) -> np.ndarray:
    """``k`` of one plane after greedy region merging on the summed border costs (see the module docstring)."""
    m, k = np.asarray(m, dtype=np.int64), np.asarray(k, dtype=np.int64)
    j = (logp.shape[1] - 1) // 2
    shifts = np.arange(-j, j + 1)
    count, labels, tables = _border_tables(m, k, logp, bits, tau, shifts)
    neighbours = [set() for _ in range(count)]
    for a, b in tables:
        neighbours[a].add(b)
        neighbours[b].add(a)
    version: dict[tuple[int, int], int] = {}
    heap: list[tuple[float, int, int, int]] = []

    def push(a: int, b: int) -> None:
        pair = (min(a, b), max(a, b))
        best_two = np.partition(tables[pair], 1)[:2]
        version[pair] = version.get(pair, 0) + 1
        heapq.heappush(heap, (-(best_two[1] - best_two[0]), *pair, version[pair]))

    def table(a: int, b: int) -> np.ndarray:  # the cost of shifting b by t relative to a
        return tables[(a, b)] if a < b else tables[(b, a)][::-1]

    def store(a: int, b: int, t: np.ndarray) -> None:
        tables[(a, b) if a < b else (b, a)] = t if a < b else t[::-1].copy()

    for pair in list(tables):
        push(*pair)
    size = np.bincount(labels, minlength=count)
    parent, relative = np.arange(count), np.zeros(count, dtype=np.int64)
    alive = np.ones(count, dtype=bool)
    while heap:
        _, a, b, v = heapq.heappop(heap)
        if not (alive[a] and alive[b]) or version.get((a, b)) != v or (a, b) not in tables:
            continue
        best = int(shifts[np.argmin(tables.pop((a, b)))])  # b moves by best relative to a
        keep, gone, delta = (a, b, best) if size[a] >= size[b] else (b, a, -best)
        parent[gone], relative[gone], alive[gone] = keep, delta, False
        size[keep] += size[gone]
        neighbours[keep].discard(gone)
        for c in list(neighbours[gone]):
            if c == keep:
                continue
            old = table(gone, c)
            moved = np.full_like(old, old.max())  # c relative to keep is c relative to gone, plus delta
            if delta >= 0:
                moved[delta:] = old[: old.size - delta]
            else:
                moved[:delta] = old[-delta:]
            del tables[(min(gone, c), max(gone, c))]
            neighbours[c].discard(gone)
            if c in neighbours[keep]:
                store(keep, c, table(keep, c) + moved)
            else:
                store(keep, c, moved)
                neighbours[keep].add(c)
                neighbours[c].add(keep)
            push(keep, c)
        neighbours[gone] = set()
    offset = np.zeros(count, dtype=np.int64)
    for r in range(count):
        node = r
        while parent[node] != node:
            offset[r] += relative[node]
            node = parent[node]
    return k + offset[labels].reshape(k.shape)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=protocols.DEV_SCENES)
    ap.add_argument("--taus", nargs="+", type=float, default=[0.01, 0.1, 1.0])
    ap.add_argument("--max-scenes", type=int, default=10)
    ap.add_argument("--protocols", nargs="+", default=["A", "B"])
    ap.add_argument("--scale", type=int, default=512)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    net = load_model()
    scenes = protocols.list_scenes(args.data, split="train")
    pick = np.random.default_rng(0).choice(len(scenes), min(args.max_scenes, len(scenes)), replace=False)
    scenes = [scenes[i] for i in sorted(pick)]
    for proto in args.protocols:
        results: dict[str, list[tuple[float, float]]] = {"tree": [], **{f"tau={t}": [] for t in args.taus}}
        for path in scenes:
            truth = protocols.protocol_counts(protocols.load_scene(path, args.scale), proto)
            modulus = torch.remainder(truth, 256).long()
            logp = predict_edges(net, modulus, 8).numpy()
            planes = modulus.numpy()
            k = np.stack([decode_edges(m, lp, 8)[0] for m, lp in zip(planes, logp, strict=True)])
            candidates = {"tree": k}
            for tau in args.taus:
                start = time.perf_counter()
                candidates[f"tau={tau}"] = np.stack(
                    [merge_regions(m, kk, lp, 8, tau) for m, kk, lp in zip(planes, k, logp, strict=True)]
                )
                print(f"  {path.name} tau={tau}: {time.perf_counter() - start:.1f} s", flush=True)
            for name, kk in candidates.items():
                score = protocols.score_scene(torch.from_numpy(planes + 256.0 * kk), truth, 8)
                results[name].append((score.exact_k, score.rolled_over_right))
        for name, rows in results.items():
            a = np.array(rows, dtype=float)
            print(f"{proto} {name:10s} exact-k {np.nanmean(a[:, 0]):.4f} rolled-over right {np.nanmean(a[:, 1]):.4f}")


if __name__ == "__main__":
    main()
