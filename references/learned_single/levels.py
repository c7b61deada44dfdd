"""Train the level head of ``unwrap_single(method="learned", levels=True)``, export it, and write its model card.

The head (:class:`HalfLevels`) sits on the shipped edge network's encoder, frozen: four convolutions at half resolution
on the encoder's half-resolution features ``d2`` and the input pooled 2 x 2
(:meth:`~torch_modulo.singleshot.learned.EdgeJumpNet.encode`), one distribution over the rollover count ``k`` in
``0 .. LEVELS - 1`` per 2 x 2 block and channel. It is trained on the level labels alone (``floor(counts / 2^N)``,
cross-entropy), on the batches of the edge network's recipe (:mod:`references.learned_single.train`: CC0/BSD scenes
and procedural ones, crops of 128 x 128, half the scene crops exposed by their whole scene's percentile). ``export``
writes a record as the package's level weights (:class:`~torch_modulo.singleshot.learned.LevelNet`: a copy of the
trunk and the head); ``card`` scores a record as the package decodes (the shipped tree, then
:func:`~torch_modulo.singleshot.learned.region_moves`) and writes a model card. From the repository root::

    python -m references.learned_single.levels train --head-width 32 --steps 12000 --seed 54 --out OUT/half.pt \
        --card OUT/half.md
    python -m references.learned_single.levels export --weights OUT/half.pt --out OUT/levels.pt
    python -m references.learned_single.levels card --weights OUT/half.pt --out OUT/half.md --data <selection set>

``train`` writes the weights, a summary of the run beside them (``half.json``: settings, minutes, final loss, the
scenes it read) and, with ``--card``, the model card. The shipped head took about 22 minutes on 2 cores, the card
about 5 more.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from references.learned_single import train as recipe
from torch_modulo import protocols
from torch_modulo.singleshot.learned import (
    BAND,
    LEVELS,
    SLOTS,
    EdgeJumpNet,
    LevelHead,
    decode_jumps,
    edge_features,
    load_model,
    predict_jumps,
    region_moves,
)

BITS = 8
PERIOD = 1 << BITS
#: The training crops' side and the crops per step.
CROP, BATCH = 128, 6

#: What a training batch is (:func:`recipe_batches`), for the model card.
RECIPE = (
    "references/learned_single/train.py's batches of 6 crops of 128 x 128, luminance or RGB, the brightest region "
    "rolled over 2 to 20 times, half the scene crops exposed by their whole scene's percentile, 30% procedural, "
    "15% with shot and read noise; labels: every pixel's level floor(counts / 256), clipped to 0 .. 15"
)


class HalfLevels(nn.Module):
    """Level logits at half resolution from the edge network's ``d2`` and the input pooled 2 x 2, upsampled (nearest)
    to full resolution for the loss: the package's :class:`~torch_modulo.singleshot.learned.LevelNet` head.

    Shape:
        - Input: (B, 15, H, W) :func:`~torch_modulo.singleshot.learned.edge_features` and the encoder's
          (B, 2 width, H / 2, W / 2) ``d2``.
        - Output: (B, 3, levels, H, W) logits per channel slot.
    """

    def __init__(self, edge: EdgeJumpNet, head_width: int = 32, levels: int = LEVELS) -> None:
        super().__init__()
        self.head = LevelHead(2 * edge.config["width"] + 15, head_width, levels)

    def forward(self, x: torch.Tensor, d2: torch.Tensor) -> torch.Tensor:
        logits = self.head(torch.cat([d2, F.avg_pool2d(x, 2)], dim=1))
        b, s, n, h, w = logits.shape
        return F.interpolate(logits.reshape(b, s * n, h, w), scale_factor=2.0, mode="nearest").view(
            b, s, n, 2 * h, 2 * w
        )


def recipe_batches(seed: int, threads: int) -> Callable[[], tuple[torch.Tensor, torch.Tensor]]:
    """Seed torch, set the threads and load the edge recipe's training scenes: a function that draws one batch
    ``(wrapped, counts)`` of (BATCH, 3, CROP, CROP) moduli and their true counts."""
    torch.manual_seed(seed)
    torch.set_num_threads(threads)
    options = recipe.parse_args(["--crop", str(CROP), "--batch", str(BATCH), "--scene-exposure", "0.5"])
    rng = np.random.default_rng(seed)
    scenes = recipe.load_train_scenes(options.scene_side, options.data)
    references = [recipe.exposure_references(s) for s in scenes]
    return lambda: recipe.make_batch(scenes, options.batch, options.crop, rng, options, references)


def level_loss(logits: torch.Tensor, counts: torch.Tensor) -> torch.Tensor:
    """Cross-entropy of (B, S, LEVELS, H, W) level logits against the levels of (B, S, H, W) true counts
    (``floor(counts / 2^N)``, clipped to the head's levels)."""
    levels = torch.floor(counts / PERIOD).long().clamp_(0, LEVELS - 1)
    return F.cross_entropy(logits.permute(0, 1, 3, 4, 2).reshape(-1, LEVELS), levels.reshape(-1))


def load(path: Path, edge: EdgeJumpNet) -> HalfLevels:
    """A ``train`` record, or a package level weights file (``export``'s output, whose trunk must be ``edge``)."""
    record = torch.load(path, map_location="cpu", weights_only=True)
    if "head" in record:  # the package's format: the head on a copy of its trunk
        trunk = edge.state_dict()
        if record["state"].keys() != trunk.keys() or any(
            not torch.equal(v.float(), trunk[k].half().float()) for k, v in record["state"].items()
        ):
            raise SystemExit(f"{path}: its trunk is not the edge network in use")
        head = {k: v.float() for k, v in record["head"].items()}
        net = HalfLevels(edge, int(head["net.0.bias"].numel()), int(head["net.6.bias"].numel()) // SLOTS)
        net.head.load_state_dict(head)
        return net.eval()
    if not record.get("half") or record.get("context"):
        raise SystemExit(f"{path}: not a record of this recipe (a half-resolution head without a coarse branch)")
    net = HalfLevels(edge, record["head_width"], record["levels"])
    net.load_state_dict({k: v.float() for k, v in record["state"].items()})
    return net.eval()


@torch.no_grad()
def level_costs(edge: EdgeJumpNet, net: HalfLevels, moduli: torch.Tensor) -> np.ndarray:
    """(C, LEVELS, H, W) float16 costs ``-log p(k)`` of (C, H, W) moduli, one per pixel (the whole image at once)."""
    c, h, w = moduli.shape
    x = moduli[None].float().expand(1, 3, h, w)
    x = F.pad(x, (0, (-w) % edge.stride, 0, (-h) % edge.stride), mode="replicate")
    features = edge_features(x, BITS)
    logits = net(features, edge.encode(features)[1])[0, :c, :, :h, :w]
    return (-torch.log_softmax(logits, dim=1)).numpy().astype(np.float16)


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
    """Train a head (Adam, cosine learning rate from ``args.lr``) and write its record, summary and card."""
    batch = recipe_batches(args.seed, args.threads)
    edge = load_model()
    net = HalfLevels(edge, args.head_width).train()
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    progress = Progress(args.steps)
    for step in range(args.steps):
        for group in opt.param_groups:
            group["lr"] = args.lr * 0.5 * (1 + math.cos(math.pi * step / args.steps))
        wrapped, counts = batch()
        x = edge_features(wrapped, BITS)
        with torch.no_grad():
            d2 = edge.encode(x)[1]
        loss = level_loss(net(x, d2), counts)
        opt.zero_grad()
        loss.backward()
        opt.step()
        progress(step, float(loss.detach()))
    record = {
        "half": True,
        "head_width": args.head_width,
        "levels": LEVELS,
        "state": {k: v.detach().half() for k, v in net.state_dict().items()},
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(record, args.out)
    summary = {
        "weights": args.out.name,
        "minutes": round((time.perf_counter() - progress.start) / 60, 1),
        "head_parameters": sum(p.numel() for p in net.parameters()),
        "final_loss": progress.smooth,
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "recipe": RECIPE,
        # what recipe_batches read (the recipe's load_train_scenes: the training split of the dev scenes)
        "scenes": [
            str(p.relative_to(protocols.DEV_SCENES)) for p in protocols.list_scenes(protocols.DEV_SCENES, "train")
        ],
    }
    summary_path(args.out).write_text(json.dumps(summary, indent=2) + "\n")
    if args.card is not None:
        write_card(argparse.Namespace(weights=args.out, out=args.card, splits=["train", "validation"], data=None))


def export(args: argparse.Namespace) -> None:
    """A ``train`` record as the package's level weights: the shipped edge network as the trunk, and the head."""
    edge = load_model()
    record = torch.load(args.weights, map_location="cpu", weights_only=True)
    if not record.get("half") or record.get("context"):
        raise SystemExit(f"{args.weights}: only a half-resolution head without --context is the package's LevelNet")
    head = {k.removeprefix("head."): v for k, v in record["state"].items() if k.startswith("head.")}
    out = {"config": edge.config, "state": {k: v.half() for k, v in edge.state_dict().items()}, "head": head}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(out, args.out)


def scores(edge: EdgeJumpNet, net: HalfLevels, scenes: list[Path], proto: str) -> np.ndarray:
    """Mean exact-k / rolled-over right (%) of the shipped tree and of the region moves with ``net``'s levels over
    ``scenes`` (longer side 512) under ``proto``: four values, each plane aligned by its most common offset."""
    rows = []
    for path in scenes:
        truth = protocols.protocol_counts(protocols.load_scene(path, 512), proto)
        moduli = torch.remainder(truth, PERIOD).to(torch.int64)
        planes = moduli.numpy()
        jump, cost = predict_jumps(edge, moduli.float(), BITS, band=BAND)
        u = level_costs(edge, net, moduli)
        row = []
        for c in range(planes.shape[0]):
            tree = decode_jumps(planes[c], jump[c], cost[c, :, BAND], BITS)[0]
            moved = region_moves(planes[c], tree, cost[c], jump[c].astype(np.int64) - BAND, u[c], BITS, block=1)
            row.append((tree, moved))
        out = []
        for i in range(2):
            k = np.stack([r[i] for r in row])
            score = protocols.score_scene(torch.from_numpy(planes + PERIOD * k).double(), truth.double(), BITS)
            out += [score.exact_k, score.rolled_over_right]
        rows.append(out)
    return 100 * np.nanmean(np.array(rows), axis=0)


def scene_list(split: str, data: Path | None) -> list[Path]:
    """The dev scenes of ``split``, or every scene of another folder ``data``."""
    return (
        protocols.list_scenes(data, "all") if data is not None else protocols.list_scenes(protocols.DEV_SCENES, split)
    )


def summary_path(weights: Path) -> Path:
    """Where ``train`` writes the summary of the run that made ``weights``: beside it, ``.json`` for ``.pt``."""
    return weights.with_suffix(".json")


def write_card(args: argparse.Namespace) -> None:
    """A model card (markdown) of a ``train`` record or a package level weights file: its data and settings (from the
    summary beside it, if any), and :func:`scores` on ``args.splits`` (and on every scene of ``args.data``)."""
    summary_file = summary_path(args.weights)
    summary = json.loads(summary_file.read_text()) if summary_file.exists() else None
    edge = load_model()
    net = load(args.weights, edge)
    lines = [
        f'# Model card: `{args.weights.name}` (a level head for `unwrap_single(method="learned", levels=...)`)',
        "",
    ]
    if summary is None:
        lines += [f"No summary of the run beside the weights (`{summary_file.name}`): data and settings unknown.", ""]
    else:
        settings = summary["settings"]
        loss = "none" if summary["final_loss"] is None else f"{summary['final_loss']:.4f}"
        lines += [
            "## Data",
            "",
            f"Crops of the {len(summary['scenes'])} CC0/BSD scenes of the training split and procedural scenes, as "
            f"the recipe makes them: {summary['recipe']}. The validation scenes are never read in training.",
            "",
            "Scenes: " + ", ".join(f"`{name}`" for name in summary["scenes"]) + ".",
            "",
            "## Settings",
            "",
            f"`python -m references.learned_single.levels train --head-width {settings['head_width']} --steps "
            f"{settings['steps']} --lr {settings['lr']} --seed {settings['seed']}` "
            f"({summary['minutes']} minutes, {settings['threads']} threads; {summary['head_parameters']} trained "
            f"parameters; final smoothed loss {loss}). The trunk is the shipped edge network, frozen.",
            "",
        ]
    lines += [
        "## Numbers",
        "",
        "Exact-k / rolled-over right (%), longer side 512, each plane aligned by its most common offset; the shipped "
        "edge network's tree, then `region_moves` with these levels (`python -m references.learned_single.levels "
        "card`).",
        "",
        "| scenes | protocol | tree | with the level moves |",
        "|---|---|---|---|",
    ]
    groups = [(split, scene_list(split, None)) for split in args.splits]
    if args.data is not None:
        groups.append((f"every scene of `{args.data.name}`", scene_list("all", args.data)))
    for name, scenes in groups:
        for proto in ("A", "A10", "B"):
            mean = scores(edge, net, scenes, proto)
            lines.append(
                f"| {name} ({len(scenes)}) | {proto} | {mean[0]:.2f} / {mean[1]:.2f} | {mean[2]:.2f} / {mean[3]:.2f} |"
            )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}", flush=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train", help="train a level head on the shipped edge network's frozen encoder")
    t.add_argument("--steps", type=int, default=12000)
    t.add_argument("--lr", type=float, default=2e-3)
    t.add_argument("--head-width", type=int, default=32)
    t.add_argument("--seed", type=int, default=54)
    t.add_argument("--threads", type=int, default=2)
    t.add_argument("--out", type=Path, required=True)
    t.add_argument("--card", type=Path, default=None, help="then write a model card here (evaluates: minutes)")
    x = sub.add_parser("export", help="a train record as torch_modulo's level weights (levels.pt)")
    x.add_argument("--weights", type=Path, required=True)
    x.add_argument("--out", type=Path, required=True)
    c = sub.add_parser("card", help="a model card of a train record or a levels.pt: data, settings and numbers")
    c.add_argument("--weights", type=Path, required=True)
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--splits", nargs="+", default=["train", "validation"], choices=protocols.SPLITS)
    c.add_argument("--data", type=Path, default=None, help="also every scene of another folder")
    args = ap.parse_args(argv)
    {"train": train, "export": export, "card": write_card}[args.command](args)


if __name__ == "__main__":
    main()
