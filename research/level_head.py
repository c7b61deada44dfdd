"""A per-pixel level head trained with the edge-jump network, and region moves that use it: the prototype of
``torch_modulo/singleshot/levels.py`` and its first level network (a fine-tuned second trunk with a full-resolution
head; since replaced by ``research/level_shared.py --half``, whose ``export`` writes the package's ``levels.pt``; this
script's files no longer load in the package: the head there reads other features).

The learned tree fails mostly by whole regions a period off (``research.learned_regions``). A small head on the
network's full- and half-resolution features predicts, per pixel and channel, a distribution over the rollover
count ``k`` in ``0 .. 15`` (texture under multiplicative shading is larger in counts where the radiance is higher,
so a wrapped step of a given size says more about ``k`` at a low modulus than at a high one). Decoding stays exact:

1. the tree of ``unwrap_single(method="learned")`` gives ``k`` (``decode_edges``);
2. the whole plane moves by the global level the head prefers (the sum of its costs ``-log p(k)``);
3. region moves: the plane is cut into the regions joined by pairs the network is sure of (``-log p <= tau``); each
   region may move by ``-2 .. 2`` where ``lam * sum of the head's costs + sum of the moved border pairs' costs``
   drops; every round moves the regions whose drop is larger than all their neighbours', until none drops.

The output is ``I_m + k 2^N`` with integer ``k`` throughout. Training fine-tunes the shipped network and the head
together (``edge_loss`` + ``beta`` x the head's cross-entropy), on the training recipe's own batches
(``references/learned_single/train.py``: CC0/BSD scenes and procedural ones only), after the head alone on the
frozen network (``--frozen``). The weights those two commands wrote are in the history
(``mkdir -p research/weights && git show 03da5e0:research/weights/level_head.pt > research/weights/level_head.pt``)::

    python -m research.level_head train --frozen --steps 4000 --lr 2e-3 --out /tmp/head.pt     # ~15 min, 2 cores
    python -m research.level_head train --init /tmp/head.pt --steps 5000 --out research/weights/level_head.pt
    python -m research.level_head eval --weights research/weights/level_head.pt --split train --lams 0.3 1 3
    python -m research.level_head eval --weights research/weights/level_head.pt --data <selection set>
    python -m research.level_head eval --weights research/weights/level_head.pt --shipped-jumps --split validation

Reported per protocol: mean exact-k / rolled-over right (%) of the tree and of the region moves at each ``lam``,
scored per plane after aligning its global offset (``protocols.score_scene``), and the head's own accuracy.
"""

from __future__ import annotations

import argparse
import copy
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from research.learned_regions import confident_regions
from torch_modulo import protocols
from torch_modulo.singleshot.learned import (
    EdgeJumpNet,
    decode_edges,
    edge_features,
    edge_loss,
    edge_targets,
    load_model,
    predict_edges,
)
from torch_modulo.singleshot.levels import LEVELS, LevelHead

BITS = 8
PERIOD = 1 << BITS
SHIFTS = (-2, -1, 1, 2)
ROOT = Path(__file__).resolve().parents[1]
HEAD_INPUT = 16 + 32 + 15  # this head's input: full- and half-resolution features (upsampled) and the input


def trunk_and_head_input(net: EdgeJumpNet, wrapped: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The network's full-resolution features of (B, 3, H, W) moduli and the head's input built from them."""
    x = edge_features(wrapped, BITS)
    e1, d2 = net.encode(x)
    features = net.decode(e1, d2)
    return features, torch.cat([features, F.interpolate(d2, scale_factor=2.0, mode="nearest"), x], dim=1)


def load(path: Path) -> tuple[EdgeJumpNet, LevelHead]:
    """The network and head of a file written by :func:`train` (eval mode)."""
    record = torch.load(path, map_location="cpu", weights_only=True)
    net = EdgeJumpNet(**record["config"])
    net.load_state_dict({k: v.float() for k, v in record["state"].items()})
    head = LevelHead(cin=HEAD_INPUT)
    head.load_state_dict({k: v.float() for k, v in record["head"].items()})
    return net.eval(), head.eval()


def level_costs(net: EdgeJumpNet, head: LevelHead, moduli: torch.Tensor) -> np.ndarray:
    """(C, LEVELS, H, W) costs ``-log p(k)`` of (C, H, W) moduli, C = 1 (seen as grey) or 3."""
    c, h, w = moduli.shape
    x = moduli[None].float().expand(1, 3, h, w)
    x = F.pad(x, (0, (-w) % net.stride, 0, (-h) % net.stride), mode="replicate")
    with torch.no_grad():
        logits = head(trunk_and_head_input(net, x)[1])[0, :c, :, :h, :w]
    return (-torch.log_softmax(logits, dim=1)).numpy()


def _unary(u: np.ndarray, k: np.ndarray) -> np.ndarray:
    """The head's cost of every pixel at level ``k``, clipped to the levels it knows (the training labels were
    clipped at the last; a negative level takes level 0's cost)."""
    return np.take_along_axis(u, np.clip(k, 0, u.shape[0] - 1)[None], 0)[0]


def region_moves(
    modulus: np.ndarray, k: np.ndarray, logp: np.ndarray, u: np.ndarray, lam: float, tau: float = 0.01, rounds: int = 60
) -> np.ndarray:
    """``k`` of one plane moved by the head's global level, then by region moves (see the module docstring).

    Args:
        modulus: (H, W) integer moduli.
        k: (H, W) integer rollover counts (the tree's).
        logp: (2, 2J + 1, H, W) jump log-probabilities (``predict_edges``).
        u: (LEVELS, H, W) the head's costs.
        lam: the weight of the head's costs against the pairs'.
        tau: pairs of cost ``-log p <= tau`` join a region.
        rounds: the most rounds of moves.

    Returns:
        int64 (H, W): ``k`` plus an integer per region (``modulus + k 2^N`` stays consistent with the modulus).
    """
    m = np.asarray(modulus, dtype=np.int64)
    k = np.asarray(k, dtype=np.int64)
    j = (logp.shape[1] - 1) // 2
    count, labels = confident_regions(np.maximum(-logp.max(axis=1), 0.0), tau)
    offsets = range(-u.shape[0], u.shape[0] + 1)
    k = k + min(offsets, key=lambda g: (float(_unary(u, k + g).sum()), abs(g)))  # ties: the smallest move
    flat = labels.ravel()
    borders = []
    for direction, (a, b) in enumerate(((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :]))):
        d = m[b] - m[a]
        wrap = (np.mod(d + PERIOD // 2, PERIOD) - PERIOD // 2 - d) // PERIOD  # k_b - k_a = wrap + n
        cross = labels[a] != labels[b]
        borders.append(
            (labels[a][cross], labels[b][cross], wrap[cross], logp[direction][(slice(None), *a)][:, cross], a, b, cross)
        )

    def cost(lp: np.ndarray, n: np.ndarray) -> np.ndarray:
        index = n + j
        inside = (index >= 0) & (index < lp.shape[0])
        value = np.take_along_axis(lp, np.clip(index, 0, lp.shape[0] - 1)[None], 0)[0]
        return np.where(inside, np.minimum(-value, 30.0), 30.0)

    for _ in range(rounds):
        delta = np.zeros((len(SHIFTS), count))
        here = _unary(u, k)
        for i, s in enumerate(SHIFTS):
            delta[i] = lam * np.bincount(flat, (_unary(u, k + s) - here).ravel(), count)
        for la, lb, wrap, lp, a, b, cross in borders:
            n = k[b][cross] - k[a][cross] - wrap
            now = cost(lp, n)
            for i, s in enumerate(SHIFTS):  # moving a region by s changes the jumps of its border pairs by -+s
                delta[i] += np.bincount(la, cost(lp, n - s) - now, count) + np.bincount(
                    lb, cost(lp, n + s) - now, count
                )
        best, choice = delta.min(axis=0), delta.argmin(axis=0)
        neighbours = np.full(count, np.inf)
        for la, lb, *_ in borders:
            np.minimum.at(neighbours, la, best[lb])
            np.minimum.at(neighbours, lb, best[la])
        move = (best < -1e-6) & (best < neighbours)  # no two neighbours move in one round
        if not move.any():
            break
        k = k + np.where(move, np.array(SHIFTS)[choice], 0)[labels]
    return k


def recipe_batches(args: argparse.Namespace) -> Callable[[], tuple[torch.Tensor, torch.Tensor]]:
    """Seed torch (``args.seed``), set ``args.threads`` and load the training recipe's scenes (CC0/BSD and procedural
    ones only, ``references/learned_single/train.py``): a function that draws one batch ``(wrapped, counts)``."""
    sys.path.insert(0, str(ROOT / "references" / "learned_single"))
    import train as recipe

    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)
    crop, size = str(getattr(args, "crop", 128)), str(getattr(args, "batch", 6))
    options = recipe.parse_args(["--crop", crop, "--batch", size, "--scene-exposure", "0.5"])
    rng = np.random.default_rng(args.seed)
    scenes = recipe.load_train_scenes(options.scene_side, options.data)
    references = [recipe.exposure_references(s) for s in scenes]
    return lambda: recipe.make_batch(scenes, options.batch, options.crop, rng, options, references)


def level_loss(logits: torch.Tensor, counts: torch.Tensor, rolled_weight: float = 1.0) -> torch.Tensor:
    """Cross-entropy of (B, S, LEVELS, H, W) level logits against the levels of (B, S, H, W) true counts
    (``floor(counts / 2^N)``, clipped to the head's levels); the values that rolled over (level above 0) weigh
    ``rolled_weight`` times as much (a weighted mean)."""
    levels = torch.floor(counts / PERIOD).long().clamp_(0, LEVELS - 1)
    weight = None
    if rolled_weight != 1.0:
        weight = torch.full((LEVELS,), float(rolled_weight), device=logits.device)
        weight[0] = 1.0
    return F.cross_entropy(logits.permute(0, 1, 3, 4, 2).reshape(-1, LEVELS), levels.reshape(-1), weight)


def cosine(opt: torch.optim.Optimizer, lr: float, step: int, steps: int) -> None:
    """Set the learning rate of step ``step`` of ``steps`` on a cosine from ``lr``."""
    for group in opt.param_groups:
        group["lr"] = lr * 0.5 * (1 + math.cos(math.pi * step / steps))


class Progress:
    """Prints a running mean of the loss every 50 steps."""

    def __init__(self, steps: int) -> None:
        self.steps, self.start, self.smooth = steps, time.perf_counter(), None

    def __call__(self, step: int, value: float) -> None:
        self.smooth = value if self.smooth is None else 0.98 * self.smooth + 0.02 * value
        if (step + 1) % 50 == 0:
            elapsed = time.perf_counter() - self.start
            print(f"step {step + 1}/{self.steps} loss {self.smooth:.4f} {elapsed:.0f}s", flush=True)


def train(args: argparse.Namespace) -> None:
    batch = recipe_batches(args)
    net = copy.deepcopy(load_model())
    head = LevelHead(cin=HEAD_INPUT)
    if args.init is not None:  # a head trained before (e.g. with --frozen), and its network
        net, head = load(args.init)
    for p in net.parameters():
        p.requires_grad_(not args.frozen)
    net.train(not args.frozen)
    head.train()
    params = [*head.parameters()] if args.frozen else [*net.parameters(), *head.parameters()]
    opt = torch.optim.Adam(params, lr=args.lr)
    progress = Progress(args.steps)
    for step in range(args.steps):
        cosine(opt, args.lr, step, args.steps)
        wrapped, counts = batch()
        target, _ = edge_targets(counts, BITS, net.max_jump)
        with torch.set_grad_enabled(not args.frozen):
            features, head_input = trunk_and_head_input(net, wrapped)
        head_loss = level_loss(head(head_input), counts)
        if args.frozen or args.edge_weight == 0:
            loss = head_loss
        else:
            loss = args.edge_weight * edge_loss(net.logits(features), target, 2.0) + args.beta * head_loss
        opt.zero_grad()
        loss.backward()
        opt.step()
        progress(step, float(loss.detach()))
    record = {
        "config": net.config,
        "state": {k: v.detach().half() for k, v in net.state_dict().items()},
        "head": {k: v.detach().half() for k, v in head.state_dict().items()},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(record, args.out)


def evaluate(args: argparse.Namespace) -> None:
    torch.set_num_threads(args.threads)
    net, head = load(args.weights)
    jumps = load_model() if args.shipped_jumps else net  # the pairs' network: the fine-tuned one, or the shipped one
    folder = args.data or protocols.DEV_SCENES
    scenes = protocols.list_scenes(folder, split=args.split if args.data is None else "all")
    for proto in args.protocols:
        rows = []
        for path in scenes:
            truth = protocols.protocol_counts(protocols.load_scene(path, 512), proto)
            moduli = torch.remainder(truth, PERIOD).to(torch.int64)
            planes = moduli.numpy()
            with torch.no_grad():
                logp = predict_edges(jumps, moduli, BITS).numpy()
            u = level_costs(net, head, moduli)
            tree = np.stack([decode_edges(planes[c], logp[c], BITS)[0] for c in range(planes.shape[0])])
            variants = [tree] + [
                np.stack([region_moves(planes[c], tree[c], logp[c], u[c], lam) for c in range(planes.shape[0])])
                for lam in args.lams
            ]
            row = []
            for k in variants:
                score = protocols.score_scene(torch.from_numpy(planes + PERIOD * k).double(), truth.double(), BITS)
                row += [score.exact_k, score.rolled_over_right]
            true_k = torch.floor(truth / PERIOD).long().clamp(0, LEVELS - 1).numpy()
            row.append(float((u.argmin(axis=1) == true_k).mean()))
            rows.append(row)
        mean = np.nanmean(np.array(rows), axis=0)
        names = ["tree"] + [f"lam {lam:g}" for lam in args.lams]
        cells = " | ".join(f"{n}: {100 * mean[2 * i]:.2f} / {100 * mean[2 * i + 1]:.2f}" for i, n in enumerate(names))
        print(f"{proto} ({len(scenes)} scenes) {cells} | head alone {100 * mean[-1]:.2f}", flush=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train", help="fine-tune the shipped network with a level head")
    t.add_argument("--steps", type=int, default=5000)
    t.add_argument("--lr", type=float, default=5e-4)
    t.add_argument("--beta", type=float, default=0.5, help="weight of the head's cross-entropy")
    t.add_argument("--seed", type=int, default=31)
    t.add_argument("--threads", type=int, default=2)
    t.add_argument("--out", type=Path, default=ROOT / "research" / "weights" / "level_head.pt")
    t.add_argument("--edge-weight", type=float, default=1.0, help="the edge loss's weight (0: levels alone)")
    t.add_argument("--frozen", action="store_true", help="train the head alone on the shipped network's features")
    t.add_argument("--init", type=Path, default=None, help="start from a file this command wrote")
    e = sub.add_parser("eval", help="tree vs region moves on the scenes")
    e.add_argument("--weights", type=Path, required=True, help="a file this command's train wrote")
    e.add_argument("--split", default="train", choices=protocols.SPLITS)
    e.add_argument("--data", type=Path, default=None, help="another scenes folder (all its scenes)")
    e.add_argument("--protocols", nargs="+", default=["A", "A10", "B"], choices=list(protocols.PROTOCOL_PEAKS))
    e.add_argument("--lams", nargs="+", type=float, default=[1.0])
    e.add_argument("--threads", type=int, default=2)
    e.add_argument(
        "--shipped-jumps", action="store_true", help="the tree and the pairs from the shipped network; the head's own"
    )
    args = ap.parse_args(argv)
    (train if args.command == "train" else evaluate)(args)


if __name__ == "__main__":
    main()
