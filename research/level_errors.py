"""Where the level moves stop, and why: the errors of ``unwrap_single(method="learned")`` against its own energy.

The default decodes the shipped networks' outputs by the tree, then
:func:`~torch_modulo.singleshot.learned.region_moves` over the regions joined by pairs the edge network is sure of.
This asks, per split and protocol, what is left:

- **oracle**: every region (joined by pairs of cost ``<= tau``) put at its best level, the most common ``k_true - k``
  of its pixels: how much a perfect decision over these regions could give;
- **energy**: the cost ``region_moves`` lowers (level costs ``-log p(k)`` plus every pair's cost of its jump, the
  band's ``MAX_COST`` outside it), of the truth (aligned to the result's offset) against the result's: where the
  truth costs more, no search over this energy finds it;
- **head on errors**: how often the level head's most likely level is the true one on the values the result gets
  wrong, and how often overall;
- **isolated**: the share of the wrong values with at most one wrong 4-neighbour (single-pixel noise) against
  errors in clusters;
- **large wrong regions**: for every region of at least 0.1% of a plane that the result puts at another level than
  the oracle, the change of the level costs and of the pair costs when that region alone moves to the oracle's
  level; the share of their pixels where both, one or none favour the truth.
- **border of the main wrong level** (``--borders``): per plane where the most common wrong offset covers at least
  5% of the values, the pairs between those values and the right ones: on how many the edge network's most likely
  jump is the truth's and on how many the result's, the summed costs ``-log p`` of the truth's jumps and of the
  result's, and how many of the pairs are true steps below half a period (the crossings the smooth-step oracle of
  ``research/single_limits.py`` takes) and read as such (most likely jump = the truth's).

    python -m research.level_errors --split train            # the 26 training scenes, protocols A, A10 and B
    python -m research.level_errors --split validation --protocols A
    python -m research.level_errors --split validation --borders   # also a line per plane with a large wrong level

Each plane's scores are aligned by its most common offset, as ``protocols.score_scene`` does; means over scenes.
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np
import torch
from scipy import ndimage

from torch_modulo import protocols
from torch_modulo.singleshot.grid import grid_components
from torch_modulo.singleshot.learned import (
    BAND,
    DIRECTIONS,
    MAX_COST,
    decode_jumps,
    load_levels,
    load_model,
    pair_costs,
    predict_jumps,
    region_moves,
)

BITS = 8
PERIOD = 1 << BITS
TOP_LEVEL = 15  # the report by true level lumps the levels from this one on


def offset(d: np.ndarray) -> int:
    """The most common value of an integer array (the alignment of the scores)."""
    values, counts = np.unique(d, return_counts=True)
    return int(values[counts.argmax()])


def regions(table: np.ndarray, tau: float) -> tuple[int, np.ndarray]:
    """The regions joined by pairs whose least cost in ``table`` ((2, K, H, W)) is at most ``tau``: count, (H, W)."""
    count, flat = grid_components(*(table[d].min(axis=0)[a] <= tau for d, (a, _) in enumerate(DIRECTIONS)))
    return count, flat.reshape(table.shape[-2:])


def oracle(k: np.ndarray, true_k: np.ndarray, labels: np.ndarray, count: int) -> np.ndarray:
    """``k`` with every region moved by the most common ``true_k - k`` of its pixels."""
    d = (true_k - k).ravel()
    lo, span = d.min(), d.max() - d.min() + 1
    key = labels.ravel().astype(np.int64) * span + (d - lo)
    pairs, n = np.unique(key, return_counts=True)
    region, value = pairs // span, pairs % span + lo
    order = np.lexsort((-n, region))
    first = np.r_[True, region[order][1:] != region[order][:-1]]
    shift = np.zeros(count, dtype=np.int64)
    shift[region[order][first]] = value[order][first]
    return k + shift[labels]


def energy(m: np.ndarray, k: np.ndarray, table: np.ndarray, first: np.ndarray, u: np.ndarray) -> tuple[float, float]:
    """``region_moves``' cost of ``k`` (weight 1): the level costs' sum and the pairs' sum."""
    levels = u.shape[0]
    level = float(np.take_along_axis(u, np.clip(k, 0, levels - 1)[None], 0).astype(np.float64).sum())
    costs = pair_costs(m, k, np.clip(table, 0.0, MAX_COST).astype(np.float64), first, PERIOD, 0, 0)
    return level, float(sum(c.sum() for c in costs))


def pair_jumps(m: np.ndarray, k: np.ndarray) -> list[np.ndarray]:
    """Per direction (right, down), the jump ``n`` of every pair under ``k``: ``I_j - I_i = w(m_j - m_i) + n 2^N``."""
    out = []
    for a, b in DIRECTIONS:
        wd = np.mod(m[b] - m[a] + PERIOD // 2, PERIOD) - PERIOD // 2
        out.append((m[b] + PERIOD * k[b] - m[a] - PERIOD * k[a] - wd) // PERIOD)
    return out


#: ``border_report`` looks at planes whose most common wrong offset covers at least this share of the values.
BORDER_SHARE = 0.05


def border_report(
    m: np.ndarray, k: np.ndarray, table: np.ndarray, first: np.ndarray, truth: np.ndarray
) -> dict[str, float] | None:
    """The pairs between the values at the result's most common wrong offset and the right ones (None when that
    offset covers less than :data:`BORDER_SHARE` of the plane): what the edge network says at that border.

    Args:
        m: (H, W) moduli; ``k``: the result's (H, W) rollover counts; ``table``, ``first``: the band of jump costs
            (``table[d, BAND]`` is the most likely jump's, ``first + BAND`` that jump); ``truth``: (H, W) true counts.

    Returns:
        ``share`` and ``offset`` of the wrong level, ``pairs`` on its border, ``net picks truth`` / ``net picks
        result`` (the most likely jump is the truth's / the result's), ``truth cost`` / ``result cost`` (sums of
        ``-log p`` over the border, :data:`MAX_COST` outside the band), ``small steps`` (true steps below half a
        period) and ``small steps read`` (those whose most likely jump is the truth's).
    """
    true_k = truth // PERIOD
    d = k - true_k
    d -= offset(d)
    values, counts = np.unique(d[d != 0], return_counts=True)
    if not counts.size or counts.max() < BORDER_SHARE * d.size:
        return None
    wrong = int(values[counts.argmax()])
    costs_truth = pair_costs(m, true_k, table, first, PERIOD, 0, 0)  # a pair's cost depends on its jump alone
    costs_result = pair_costs(m, k, table, first, PERIOD, 0, 0)
    out = {"share": float(counts.max() / d.size), "offset": wrong}
    sums = defaultdict(float)
    jumps_truth, jumps_result = pair_jumps(m, true_k), pair_jumps(m, k)
    for direction, (a, b) in enumerate(DIRECTIONS):
        jt, jr = jumps_truth[direction], jumps_result[direction]
        border = ((d[a] == 0) & (d[b] == wrong)) | ((d[a] == wrong) & (d[b] == 0))
        likely = first[direction][a] + BAND
        small = border & (np.abs(truth[b] - truth[a]) < PERIOD // 2)
        sums["pairs"] += int(border.sum())
        sums["net picks truth"] += int((border & (likely == jt)).sum())
        sums["net picks result"] += int((border & (likely == jr)).sum())
        sums["truth cost"] += float(costs_truth[direction][border].sum())
        sums["result cost"] += float(costs_result[direction][border].sum())
        sums["small steps"] += int(small.sum())
        sums["small steps read"] += int((small & (likely == jt)).sum())
    return out | sums


def plane_report(
    m: np.ndarray,
    tree: np.ndarray,
    table: np.ndarray,
    first: np.ndarray,
    u: np.ndarray,
    truth: np.ndarray,
    peak: float | None = None,
    moved: np.ndarray | None = None,
):
    """The numbers of one plane (a dict of sums and counts); ``u``: (L, H, W) level costs, one per pixel; ``peak``:
    the protocol's largest count (the values there were clipped); ``moved``: the region moves' result from ``tree``,
    when the caller has it already."""
    true_k = truth // PERIOD
    if moved is None:
        moved = region_moves(m, tree, table, first, u, BITS, block=1)
    wrong = (moved - true_k) != offset(moved - true_k)
    out = {"values": m.size, "wrong": int(wrong.sum())}
    by_level = np.minimum(true_k, TOP_LEVEL).ravel()
    for key, values in (("at k", np.ones(m.size)), ("right at k", ~wrong.ravel())):
        for level, n in enumerate(np.bincount(by_level, values, TOP_LEVEL + 1).tolist()):
            out[f"{key} {level}"] = int(n)
    if peak is not None:
        clipped = truth >= peak
        out["clipped"], out["clipped right"] = int(clipped.sum()), int((clipped & ~wrong).sum())
    for tau in (0.01, 0.1, 0.5):
        count, labels = regions(table, tau)
        k = oracle(moved, true_k, labels, count)
        out[f"oracle {tau:g}"] = int(((k - true_k) == offset(k - true_k)).sum())
    aligned = true_k + offset(moved - true_k)  # the truth at the result's offset
    e_moved, e_true = energy(m, moved, table, first, u), energy(m, aligned, table, first, u)
    out["truth costs more"] = int(sum(e_true) > sum(e_moved))
    out["truth's level costs more"] = int(e_true[0] > e_moved[0])
    head = u.argmin(axis=0)
    out["head right"] = int((head == np.clip(true_k, 0, u.shape[0] - 1)).sum())
    out["head right on wrong"] = int((head == np.clip(true_k, 0, u.shape[0] - 1))[wrong].sum())
    neighbours = ndimage.convolve(wrong.astype(np.int64), np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]]), mode="constant")
    out["isolated"] = int((wrong & (neighbours <= 1)).sum())
    count, labels = regions(table, 0.01)
    best = oracle(moved, aligned, labels, count)
    size = np.bincount(labels.ravel(), minlength=count)
    large = np.unique(labels[best != moved])
    for r in large[size[large] >= 0.001 * m.size]:
        trial = moved.copy()
        inside = labels == r
        trial[inside] = best[inside]
        e = energy(m, trial, table, first, u)
        key = ("both favour", "level favours", "pairs favour", "neither favours")[
            2 * (e[0] >= e_moved[0]) + (e[1] >= e_moved[1])
        ]
        out[f"large: {key}"] = out.get(f"large: {key}", 0) + int(inside.sum())
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", default="train", choices=protocols.SPLITS)
    ap.add_argument("--protocols", nargs="+", default=["A", "A10", "B"], choices=list(protocols.PROTOCOL_PEAKS))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--borders", action="store_true", help="a line per plane whose main wrong level is large")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    net, levels = load_model(), load_levels()
    scenes = protocols.list_scenes(protocols.DEV_SCENES, args.split)
    for proto in args.protocols:
        per_scene, totals = [], defaultdict(int)
        for path in scenes:
            truth = protocols.protocol_counts(protocols.load_scene(path, 512), proto).to(torch.int64)
            moduli = torch.remainder(truth, PERIOD)
            jump, cost, u = predict_jumps(net, moduli.float(), BITS, band=BAND, levels=levels)
            scene = defaultdict(int)
            for c in range(moduli.shape[0]):
                m, t = moduli[c].numpy(), truth[c].numpy()
                pixels = u[c].repeat(2, axis=1).repeat(2, axis=2)[:, : m.shape[0], : m.shape[1]]  # a cost per pixel
                tree = decode_jumps(m, jump[c], cost[c, :, BAND], BITS)[0]
                first = jump[c].astype(np.int64) - BAND
                # the default's result (the same k as the package's costs per 2 x 2 block with block=2)
                moved = region_moves(m, tree, cost[c], first, pixels, BITS, block=1)
                report = plane_report(m, tree, cost[c], first, pixels, t, protocols.PROTOCOL_PEAKS[proto], moved)
                for key, value in report.items():
                    scene[key] += value
                if args.borders:
                    border = border_report(m, moved, cost[c], first, t)
                    if border is not None:
                        print(
                            f"{proto} {path.parent.name}/{path.name} plane {c}: {100 * border['share']:.1f}% of the "
                            f"values at offset {border['offset']:+d}; {border['pairs']:.0f} border pairs, the "
                            f"network's most likely jump is the truth's on {border['net picks truth']:.0f} and the "
                            f"result's on {border['net picks result']:.0f}; costs of the truth's jumps "
                            f"{border['truth cost']:.0f}, of the result's {border['result cost']:.0f}; "
                            f"{border['small steps']:.0f} true steps below half a period, "
                            f"{border['small steps read']:.0f} of them read so",
                            flush=True,
                        )
            scene["planes"] = moduli.shape[0]
            per_scene.append(scene)
            for key, value in scene.items():
                totals[key] += value
        mean = {key: np.mean([s.get(key, 0) / s["values"] for s in per_scene]) for key in totals}
        right = 100 * (1 - mean["wrong"])
        oracles = ", ".join(f"tau {key.split()[1]} {100 * mean[key]:.2f}" for key in totals if key.startswith("oracle"))
        large = sum(totals[k] for k in totals if k.startswith("large"))
        shares = ", ".join(
            f"{k.removeprefix('large: ')} {totals[k] / large:.2f}" for k in sorted(totals) if k.startswith("large")
        )
        level_more = totals["truth's level costs more"]
        print(
            f"{proto} ({len(scenes)} scenes): exact-k {right:.2f}, region oracle {oracles} | the truth costs more than "
            f"the result on {totals['truth costs more']} of {totals['planes']} planes (its level costs: "
            f"{level_more}) | head right on {100 * totals['head right'] / totals['values']:.1f}% "
            f"of the values, on {100 * totals['head right on wrong'] / max(totals['wrong'], 1):.1f}% of the wrong ones"
            f" | isolated errors {totals['isolated'] / max(totals['wrong'], 1):.2f} | wrong large regions "
            f"{large / max(totals['wrong'], 1):.2f} of the wrong values: {shares or 'none'}",
            flush=True,
        )
        present = [j for j in range(TOP_LEVEL + 1) if totals[f"at k {j}"]]
        print(
            f"{proto} by true k (all planes pooled; k: share of the values %, right %): "
            + ", ".join(
                f"{j}{'+' if j == TOP_LEVEL else ''}: {100 * totals[f'at k {j}'] / totals['values']:.2f} "
                f"{100 * totals[f'right at k {j}'] / totals[f'at k {j}']:.0f}"
                for j in present
            )
            + f" | clipped at the peak: {100 * totals['clipped'] / totals['values']:.2f}% of the values, "
            f"{100 * totals['clipped right'] / max(totals['clipped'], 1):.0f}% right",
            flush=True,
        )


if __name__ == "__main__":
    main()
