"""Can a model of where the steep steps are, fitted on dev scenes, guide single-shot unwrapping?

Two variants, both measured under protocol A (README.md, "A learned steep-step model"):

- ``tree``: path following on a spanning tree whose pair weights are ``-log P(smooth | features)`` from a small
  model (18 local features of the wrapped image around a 4-neighbour pair -> 16 tanh units -> P(the true step is
  at least half a period)), fitted on the ``tune`` half of the scenes (even indices, sorted by path) and scored
  on both halves against quality-guided path following.
- ``cut``: the same probabilities as per-pair costs ``-log P(n)`` of the number of periods ``n`` hidden in each
  step (the split of ``P(n != 0)`` over ``n`` taken from the tune scenes' statistics per ``|wrapped step|``),
  minimised from the ``tree`` result by binary graph-cut moves (PyMaxflow), reporting the model energy of the
  result and of the truth.

The model is research code: it is not part of the package. The fit is full-batch Adam (minutes).

Examples (from the repository root):
    python -m research.edges                      # fit, then both variants
    python -m research.edges --cut-scenes 10      # the graph cut on the first 10 scenes only
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import maxflow
import numpy as np
import torch
from scipy.ndimage import uniform_filter

from research.common import DATA, PERIOD, load, protocol_a, scores, select_scenes
from torch_modulo.singleshot.graphcut import PairTerms
from torch_modulo.singleshot.grid import integrate_wrapped, pair_indices, spanning_tree, wrapped_difference
from torch_modulo.singleshot.pathfollow import quality_guided_k

HALF = PERIOD // 2
N_FEATURES = 18
T_MAX = 16  # periods hidden in one step considered by the cut


def features(modulus: np.ndarray) -> np.ndarray:
    """(H, W - 1, 18) features of every horizontal pair (y, x)-(y, x + 1); vertical pairs: pass the transpose."""
    m = modulus.astype(np.int64)
    wh = wrapped_difference(m[:, 1:] - m[:, :-1], PERIOD).astype(np.float64)
    wv = wrapped_difference(m[1:, :] - m[:-1, :], PERIOD).astype(np.float64)
    a = np.abs(wh) / HALF
    ap = np.pad(a, 1, mode="edge")
    sp = np.pad(wh, 1, mode="edge")
    up, down, left, right = ap[:-2, 1:-1], ap[2:, 1:-1], ap[1:-1, :-2], ap[1:-1, 2:]
    second_left = np.abs(wrapped_difference(wh - sp[1:-1, :-2], PERIOD)) / HALF
    second_right = np.abs(wrapped_difference(sp[1:-1, 2:] - wh, PERIOD)) / HALF
    par_up = np.abs(wrapped_difference(wh - sp[:-2, 1:-1], PERIOD)) / HALF
    par_down = np.abs(wrapped_difference(wh - sp[2:, 1:-1], PERIOD)) / HALF
    loop = wh[:-1, :] + wv[:, 1:] - wh[1:, :] - wv[:, :-1]  # 2 x 2 loops: non-zero is a residue
    residue = (loop != 0).astype(np.float64)
    below, above = np.pad(residue, ((0, 1), (0, 0))), np.pad(residue, ((1, 0), (0, 0)))
    av = np.abs(wv) / HALF
    texture_v = uniform_filter(np.pad(av, ((0, 1), (0, 0)), mode="edge"), size=5, mode="nearest")
    texture = (uniform_filter(a, size=5, mode="nearest") + 0.5 * (texture_v[:, :-1] + texture_v[:, 1:])) / 2
    vq, vr = np.pad(av, ((1, 0), (0, 0)), mode="edge"), np.pad(av, ((0, 1), (0, 0)), mode="edge")
    perpendicular = np.maximum.reduce([vq[:, :-1], vq[:, 1:], vr[:, :-1], vr[:, 1:]])
    return np.stack(
        [
            a,
            a**2,
            up,
            down,
            left,
            right,
            second_left,
            second_right,
            par_up,
            par_down,
            above,
            below,
            above * below,
            texture,
            perpendicular,
            a * texture,
            np.minimum(par_up, par_down),
            np.minimum(second_left, second_right),
        ],
        axis=-1,
    )


def steep_labels(truth: np.ndarray) -> np.ndarray:
    """1 where the true horizontal step is not its wrapped value (at least half a period)."""
    d = truth[:, 1:] - truth[:, :-1]
    return (wrapped_difference(d, PERIOD) != d).astype(np.float64)


def fit(truths: list[np.ndarray], epochs: int, seed: int = 0) -> torch.nn.Module:
    x, y = [], []
    for truth in truths:
        for t in (truth, truth.T):
            x.append(features(np.mod(t, PERIOD)).reshape(-1, N_FEATURES))
            y.append(steep_labels(t).ravel())
    xt = torch.tensor(np.concatenate(x), dtype=torch.float32)
    yt = torch.tensor(np.concatenate(y), dtype=torch.float32)
    torch.manual_seed(seed)
    model = torch.nn.Sequential(torch.nn.Linear(N_FEATURES, 16), torch.nn.Tanh(), torch.nn.Linear(16, 1))
    opt = torch.optim.Adam(model.parameters(), lr=1e-2)
    for _ in range(epochs):
        opt.zero_grad()
        loss = torch.nn.functional.binary_cross_entropy_with_logits(model(xt).squeeze(-1), yt)
        loss.backward()
        opt.step()
    base = float(yt.mean())
    entropy = -(base * np.log(base) + (1 - base) * np.log(1 - base))
    print(f"fit: {xt.shape[0]} pairs, {100 * base:.1f}% steep; loss {loss.item():.4f} nats (prior {entropy:.4f})")
    return model


def steep_probability(model: torch.nn.Module, modulus: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """P(steep) of horizontal (H, W - 1) and vertical (H - 1, W) pairs."""
    with torch.no_grad():
        ph = torch.sigmoid(model(torch.tensor(features(modulus), dtype=torch.float32))).squeeze(-1)
        pv = torch.sigmoid(model(torch.tensor(features(modulus.T), dtype=torch.float32))).squeeze(-1)
    return ph.double().numpy(), pv.double().numpy().T


def _pairs(shape: tuple[int, int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Flat indices of the horizontal, then the vertical 4-neighbour pairs."""
    return [pair_indices(*shape, (0, 1)), pair_indices(*shape, (1, 0))]


def tree_k(modulus: np.ndarray, costs: list[np.ndarray]) -> np.ndarray:
    """Path following on the minimum spanning tree of 4-neighbour pairs weighted by ``costs`` (> 0)."""
    (hi, hj), (vi, vj) = _pairs(modulus.shape)
    weights = np.concatenate([c.ravel() for c in costs])
    parent = spanning_tree(modulus.size, np.concatenate([hi, vi]), np.concatenate([hj, vj]), weights)
    return integrate_wrapped(modulus.astype(np.int64), parent, PERIOD)


def period_split(truths: list[np.ndarray]) -> np.ndarray:
    """(9, 2 T_MAX + 1) P(t | steep, |wrapped step| bucket of 16 counts), t = periods towards the smaller step."""
    table = np.zeros((9, 2 * T_MAX + 1))
    for truth in truths:
        for i, j in _pairs(truth.shape):
            d = truth.ravel()[i] - truth.ravel()[j]
            w = wrapped_difference(d, PERIOD)
            t = np.clip((d - w) // PERIOD * np.where(w >= 0, -1, 1), -T_MAX, T_MAX) + T_MAX
            bucket = np.minimum(np.abs(w) // 16, 8)
            np.add.at(table, (bucket, t), 1.0)
    table += 0.5
    table[:, T_MAX] = 0.0
    return table / table.sum(axis=1, keepdims=True)


class PairCosts:
    """``-log P(t)`` of every 4-neighbour pair's hidden periods, and binary graph-cut moves over ``k``."""

    def __init__(self, modulus: np.ndarray, probs: tuple[np.ndarray, np.ndarray], split: np.ndarray) -> None:
        flat = modulus.ravel().astype(np.int64)
        self.n, self.shape = flat.size, modulus.shape
        self.terms = []
        for (i, j), p in zip(_pairs(modulus.shape), probs, strict=True):
            dm = flat[i] - flat[j]
            w = wrapped_difference(dm, PERIOD)
            p = np.clip(p.ravel(), 1e-6, 1 - 1e-6)
            cost = -np.log(p[:, None] * split[np.minimum(np.abs(w) // 16, 8)] + 1e-300)
            cost[:, T_MAX] = -np.log(1 - p)
            self.terms.append((i, j, (dm - w) // PERIOD, np.where(w >= 0, -1, 1), cost))

    @staticmethod
    def _cost(cost: np.ndarray, t: np.ndarray) -> np.ndarray:
        return cost[np.arange(t.size), np.clip(t, -T_MAX, T_MAX) + T_MAX]

    def energy(self, k: np.ndarray) -> float:
        flat = k.ravel()
        return float(sum(self._cost(c, (flat[i] - flat[j] + c0) * s).sum() for i, j, c0, s, c in self.terms))

    def move(self, k: np.ndarray, step: int) -> np.ndarray:
        flat = k.ravel()
        graph = maxflow.Graph[float]()
        graph.add_nodes(self.n)
        unary = np.zeros(self.n)
        for i, j, c0, s, c in self.terms:
            t = (flat[i] - flat[j] + c0) * s
            e0 = self._cost(c, t)
            a, b = self._cost(c, t + step * s) - e0, self._cost(c, t - step * s) - e0
            cij, cji, m = PairTerms.decompose(a, b)
            graph.add_edges(i, j, cij, cji)
            unary += np.bincount(i, weights=m, minlength=self.n) - np.bincount(j, weights=m, minlength=self.n)
        nz = np.flatnonzero(unary)
        graph.add_grid_tedges(nz, np.maximum(unary[nz], 0), np.maximum(-unary[nz], 0))
        graph.maxflow()
        return graph.get_grid_segments(np.arange(self.n)).reshape(self.shape)

    def minimise(self, k: np.ndarray, max_cuts: int = 60) -> tuple[np.ndarray, float]:
        energy, cuts = self.energy(k), 0
        for step in (1, -1, 1, -1, 2, -2, 1, -1):
            while cuts < max_cuts:
                moved = k + step * self.move(k, step)
                cuts += 1
                e = self.energy(moved)
                if e >= energy - 1e-9:
                    break
                k, energy = moved, e
        return k, energy


def score(modulus: np.ndarray, k: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """exact-k and PSNR of ``modulus + k 2**bits`` (offsets aligned, as in the benchmarks)."""
    restored = (modulus + PERIOD * (k - k.min())).astype(np.float64)
    return scores(restored[None], truth[None].astype(np.float64))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--epochs", type=int, default=300)
    ap.add_argument("--cut-scenes", type=int, default=10, help="run the graph-cut variant on this many scenes")
    ap.add_argument("--max-scenes", type=int, default=0, help="only the first N scenes (a quick check)")
    ap.add_argument("--model", type=Path, default=None, help="load the fitted model from here if it exists, else save")
    args = ap.parse_args()
    scenes = select_scenes(args.data, args.max_scenes)
    truths = [protocol_a(load(p, 512))[0].astype(np.int64) for p in scenes]
    tune = [t for i, t in enumerate(truths) if i % 2 == 0]
    start = time.perf_counter()
    if args.model is not None and args.model.exists():
        model = torch.nn.Sequential(torch.nn.Linear(N_FEATURES, 16), torch.nn.Tanh(), torch.nn.Linear(16, 1))
        model.load_state_dict(torch.load(args.model))
    else:
        model = fit(tune, args.epochs)
        if args.model is not None:
            torch.save(model.state_dict(), args.model)
    split = period_split(tune)
    print(f"fitted in {time.perf_counter() - start:.0f} s")
    rows = []
    for index, (path, truth) in enumerate(zip(scenes, truths, strict=True)):
        modulus = np.mod(truth, PERIOD)
        probs = steep_probability(model, modulus)
        k_tree = tree_k(modulus, [-np.log(1 - p) + 1e-6 for p in probs])
        k_qg = quality_guided_k(modulus.astype(np.int64), 8)
        row = {"scene": path.name, "split": "tune" if index % 2 == 0 else "held"}
        for name, k in (("quality", k_qg), ("tree", k_tree)):
            row[name] = score(modulus, k, truth)
        if index < args.cut_scenes:
            costs = PairCosts(modulus, probs, split)
            k_cut, e_cut = costs.minimise(k_tree)
            row["cut"] = score(modulus, k_cut, truth)
            row["cut_energy_found"], row["cut_energy_truth"] = e_cut, costs.energy(truth // PERIOD)
        rows.append(row)
        cut = f" | cut {row['cut'][0]:.3f} {row['cut'][1]:6.2f}" if "cut" in row else ""
        print(
            f"{path.name[:30]:30s} {row['split']} | quality {row['quality'][0]:.3f} {row['quality'][1]:6.2f} | "
            f"tree {row['tree'][0]:.3f} {row['tree'][1]:6.2f}{cut}",
            flush=True,
        )
    summary = {}
    for split_name in ("tune", "held"):
        part = [r for r in rows if r["split"] == split_name]
        for name in ("quality", "tree", "cut"):
            got = [r[name] for r in part if name in r]
            if got:
                summary[f"{split_name}_{name}"] = {
                    "scenes": len(got),
                    "exact_k": float(np.mean([g[0] for g in got])),
                    "psnr": float(np.mean([min(g[1], 100.0) for g in got])),
                }
    cut_rows = [r for r in rows if "cut" in r]
    summary["cut_truth_energy_higher"] = f"{sum(r['cut_energy_truth'] > r['cut_energy_found'] for r in cut_rows)}"
    summary["cut_scenes"] = len(cut_rows)
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
