"""How much of a real scene can single-shot unwrapping recover at all, and does the confidence map find the rest?

For every development scene (``--split`` for one side of the split) under protocols A, A10 and B (same scenes,
downsampling and scores as benchmarks/bench_single.py, through research/common.py), per channel:

- ``largest``: the share of pixels in the largest region joined by true neighbour steps ``|I_i - I_j| < 128``
  (8-neighbourhood). Inside such a region the wrapped differences integrate to the truth; between regions only
  a prior can choose the level.
- ``oracle``: exact-k and PSNR of path following on a spanning tree that uses only truly smooth pairs where it
  can (told by the truth which 4-neighbour steps are below half a period). No smoothness-based method can do
  better than knowing exactly where the steep steps are, so this bounds every method that unwraps by
  integrating small differences (the paper's energy, phase unwrapping, the priors of docs/singleshot.md).
  Also its *rolled-over right* (exact-k over the values whose true ``k > 0``, as bench_single scores it):
  what such a method can get right of the part a conventional camera saturates.
- ``method``: exact-k and PSNR of a method (``--method``: ``guided``, the default method of unwrap_single, by
  default; ``quality`` (path following per channel), any method of unwrap_single with options as bench_single
  takes them (``learned``, ``fast:tile=0``), ``skimage``, or ``none`` for the oracle alone), and how well
  :func:`torch_modulo.singleshot.unwrap_confidence` on its result finds its errors: the ROC AUC of
  ``1 - confidence`` for "k is wrong" (after the global offset is aligned), and the share of the wrong pixels
  among the 10% least confident.
- channels at their true level: channels whose most common rollover difference from the truth is 0 *without*
  aligning offsets (what the anchoring of ``k = 0`` decides), for the method's result and for the truth re-anchored
  by :func:`torch_modulo.singleshot.anchor.anchor_k` (a perfect solver); in the JSON summary.
- with ``--priors``: for truncated-linear pair potentials ``min(|I_i - I_j|, T)`` (8-neighbourhood; T = 8, 32
  and 128 counts: robust priors that stop charging for steps beyond T), the energy of the truth divided by the
  energy of the method's result. Above 1 means that the prior prefers the wrong result to the truth, so no
  optimiser of that prior can recover the scene.

Examples (from the repository root):
    python -m research.single_limits                      # A, A10 and B, method="guided"
    python -m research.single_limits --split validation --method learned
    python -m research.single_limits --protocols A --method fast --max-scenes 5
    python -m research.single_limits --protocols A --priors
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from research.common import BITS, DATA, PERIOD, aligned, run_method, select_scenes
from torch_modulo import protocols
from torch_modulo._argtypes import nonnegative_int, positive_int
from torch_modulo.singleshot import unwrap_confidence
from torch_modulo.singleshot.anchor import anchor_k
from torch_modulo.singleshot.grid import (
    components,
    integrate_wrapped,
    pair_indices,
    pair_offsets,
    pair_slices,
    spanning_tree,
)
from torch_modulo.singleshot.pathfollow import quality_guided_k


def _pairs(shape: tuple[int, int], neighborhood: int) -> tuple[np.ndarray, np.ndarray]:
    """Flat indices of both ends of every neighbour pair."""
    pairs = [pair_indices(*shape, off) for off in pair_offsets(neighborhood)]
    return np.concatenate([p[0] for p in pairs]), np.concatenate([p[1] for p in pairs])


def largest_smooth_region(truth: np.ndarray) -> float:
    """Share of the pixels in the largest region joined by true steps below half a period (8-neighbourhood)."""
    i, j = _pairs(truth.shape, 8)
    flat = truth.ravel()
    smooth = np.abs(flat[i] - flat[j]) < PERIOD // 2
    _, labels = components(truth.size, i[smooth], j[smooth])
    return float(np.bincount(labels).max() / truth.size)


def oracle_k(truth: np.ndarray, seed: int = 0) -> np.ndarray:
    """Path following on a spanning tree of truly smooth 4-neighbour pairs (steep pairs only where unavoidable)."""
    i, j = _pairs(truth.shape, 4)
    flat = truth.ravel()
    steep = np.abs(flat[i] - flat[j]) >= PERIOD // 2
    # Ties broken at random so that the tree is not biased to rows or columns.
    weights = np.where(steep, 1000.0, 1.0) + 1e-3 * np.random.default_rng(seed).random(i.size)
    parent = spanning_tree(truth.size, i, j, weights)
    k = integrate_wrapped(np.mod(truth, PERIOD).astype(np.int64), parent, PERIOD)
    return k - k.min()


TRUNCATIONS = (8, 32, 128)


def truncated_energy(image: np.ndarray, cap: float) -> float:
    """``sum min(|I_i - I_j|, cap)`` over the 8-neighbour pairs of every channel of (C, H, W) counts."""
    total = 0.0
    for plane in image:
        for off in pair_offsets(8):
            first, second = pair_slices(*plane.shape, off)
            total += float(np.minimum(np.abs(plane[first] - plane[second]), cap).sum())
    return total


def scene_scores(restored: np.ndarray, truth: np.ndarray, protocol: str) -> tuple[float, float, float]:
    """Exact-k, rolled-over right and PSNR of restored (C, H, W) counts, as bench_single scores them."""
    peak = protocols.PROTOCOL_PEAKS[protocol]
    score = protocols.score_scene(torch.from_numpy(restored), torch.from_numpy(truth), BITS, peak)
    return score.exact_k, score.rolled_over_right, score.psnr


def restore(method: str, modulus: np.ndarray) -> tuple[np.ndarray, float]:
    """(C, H, W) restored counts and seconds."""
    if method == "quality":
        start = time.perf_counter()
        out = np.stack([m + PERIOD * quality_guided_k(m.astype(np.int64), BITS) for m in modulus]).astype(np.float64)
        out -= PERIOD * np.floor(out.reshape(out.shape[0], -1).min(axis=1) / PERIOD)[:, None, None]
        return out, time.perf_counter() - start
    return run_method(method, modulus, 1)


def auc(score: np.ndarray, positive: np.ndarray) -> float:
    """ROC AUC of ``score`` for ``positive`` (ties get their mean rank); NaN without both classes."""
    from scipy.stats import rankdata

    n_pos = int(positive.sum())
    n_neg = positive.size - n_pos
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(score)
    return float((ranks[positive].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def rank_scores(confidence: np.ndarray, wrong: np.ndarray) -> tuple[float, float]:
    """AUC of 1 - confidence for the wrong pixels, and the share of them among the 10% least confident pixels."""
    order = np.argsort(confidence, kind="stable")
    low = order[: max(1, int(0.1 * confidence.size))]
    caught = float(wrong[low].sum() / wrong.sum()) if wrong.any() else float("nan")
    return auc(-confidence, wrong), caught


def confidence_scores(restored: np.ndarray, truth: np.ndarray) -> tuple[float, float, float]:
    """AUC of 1 - confidence for wrong k, share of wrong pixels among the 10% least confident, share wrong."""
    conf = unwrap_confidence(torch.from_numpy(restored), BITS).numpy().ravel()
    shifted = aligned(restored, truth)
    wrong = (np.floor(shifted / PERIOD) != np.floor(truth / PERIOD)).ravel()
    return (*rank_scores(conf, wrong), float(wrong.mean()))


def _at_true_level(k: np.ndarray, k_true: np.ndarray) -> bool:
    values, counts = np.unique(k - k_true, return_counts=True)
    return bool(values[counts.argmax()] == 0)


def channels_at_true_level(restored: np.ndarray, truth: np.ndarray) -> tuple[int, int]:
    """Channels whose most common rollover difference from the truth is 0 (no offset aligned): of the result, and
    of the truth itself re-anchored by ``anchor_k`` (what a perfect solver would return)."""
    result = perfect = 0
    for r, t in zip(restored, truth, strict=True):
        k_true = np.floor(t / PERIOD).astype(np.int64)
        result += _at_true_level(np.floor(r / PERIOD).astype(np.int64), k_true)
        perfect += _at_true_level(anchor_k(k_true, modulus=np.mod(t, PERIOD).astype(np.int64), bits=BITS), k_true)
    return result, perfect


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=DATA)
    parser.add_argument("--split", default="all", choices=protocols.SPLITS, help="only one side of the split")
    parser.add_argument("--protocols", nargs="+", default=["A", "A10", "B"], choices=list(protocols.PROTOCOL_PEAKS))
    parser.add_argument(
        "--method", default="guided", help="guided (default), quality, any unwrap_single method spec, skimage or none"
    )
    parser.add_argument("--scale", type=positive_int, default=512)
    parser.add_argument("--max-scenes", type=nonnegative_int, default=0)
    parser.add_argument("--priors", action="store_true", help="also compare truncated-linear prior energies")
    args = parser.parse_args()
    if args.priors and args.method == "none":
        parser.error("--priors compares the method's result with the truth: it needs a --method other than none")
    scenes = select_scenes(args.data, args.max_scenes, args.split)
    with_method = args.method != "none"
    for proto in args.protocols:
        rows = []
        print(
            f"protocol {proto}: scene, largest smooth region, oracle exact-k / rolled-over right / PSNR"
            + (f", {args.method} exact-k / rolled-over right / PSNR," if with_method else "")
        )
        if with_method:
            print("  confidence AUC, share of errors among the 10% least confident, share wrong")
        for path in scenes:
            truth = protocols.protocol_counts(protocols.load_scene(path, args.scale), proto).numpy()
            modulus = np.mod(truth, PERIOD)
            largest = float(np.mean([largest_smooth_region(t) for t in truth]))
            oracle = np.stack([np.mod(t, PERIOD) + PERIOD * oracle_k(t) for t in truth])
            o_k, o_rolled, o_psnr = scene_scores(oracle, truth, proto)
            row = {
                "scene": path.relative_to(args.data).as_posix(),
                "largest": largest,
                "oracle_k": o_k,
                "oracle_rolled": o_rolled,
                "oracle_psnr": o_psnr,
                "channels": int(truth.shape[0]),
            }
            line = f"{row['scene'][-30:]:30s} {largest:.3f} | {o_k:.3f} {o_rolled:.3f} {o_psnr:6.2f}"
            if with_method:
                restored, _ = restore(args.method, modulus)
                m_k, m_rolled, m_psnr = scene_scores(restored, truth, proto)
                c_auc, caught, wrong = confidence_scores(restored, truth)
                level_result, level_perfect = channels_at_true_level(restored, truth)
                row.update(
                    k=m_k,
                    rolled=m_rolled,
                    psnr=m_psnr,
                    conf_auc=c_auc,
                    caught10=caught,
                    wrong=wrong,
                    level_result=level_result,
                    level_perfect=level_perfect,
                )
                line += f" | {m_k:.3f} {m_rolled:.3f} {m_psnr:6.2f} | {c_auc:.3f} {caught:.2f} {wrong:.3f}"
            if args.priors:
                for cap in TRUNCATIONS:
                    row[f"truth_over_found_T{cap}"] = truncated_energy(truth, cap) / truncated_energy(restored, cap)
                    line += f" | T{cap} {row[f'truth_over_found_T{cap}']:.3f}"
            rows.append(row)
            print(line, flush=True)
        print(json.dumps(summarize(rows, proto, args.method, args.split, args.priors)))


def summarize(rows: list[dict], protocol: str, method: str, split: str, priors: bool = False) -> dict:
    """The means over scenes of :func:`main`'s rows (PSNR capped at 100 dB; NaN scores left out)."""

    def mean(key: str, subset=rows) -> float:
        values = [min(r[key], 100.0) for r in subset if np.isfinite(r[key])]
        return float(np.mean(values)) if values else float("nan")

    summary = {
        "protocol": protocol,
        "split": split,
        "scenes": len(rows),
        "largest_smooth_region": mean("largest"),
        "oracle_exact_k": mean("oracle_k"),
        "oracle_rolled_over_right": mean("oracle_rolled"),
        "oracle_psnr": mean("oracle_psnr"),
    }
    if method == "none":
        return summary
    good = [r for r in rows if r["wrong"] < 0.1]
    summary |= {
        "method": method,
        "exact_k": mean("k"),
        "rolled_over_right": mean("rolled"),
        "psnr": mean("psnr"),
        "confidence_auc": mean("conf_auc"),
        "errors_in_least_confident_10pct": mean("caught10"),
        "channels": sum(r["channels"] for r in rows),
        "channels_at_true_level": sum(r["level_result"] for r in rows),
        "channels_at_true_level_if_perfect": sum(r["level_perfect"] for r in rows),
        "scenes_under_10pct_wrong": len(good),
        "confidence_auc_those": mean("conf_auc", good),
        "errors_in_least_confident_10pct_those": mean("caught10", good),
    }
    if priors:
        for cap in TRUNCATIONS:
            summary[f"scenes_truth_energy_higher_T{cap}"] = sum(r[f"truth_over_found_T{cap}"] > 1 for r in rows)
    return summary


if __name__ == "__main__":
    main()
