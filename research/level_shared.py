"""Lighter level networks on the shipped network's encoder, frozen, trained on the level labels alone.

The first level network of the package (``research/level_head.py``, since replaced) ran a whole second trunk,
fine-tuned, with a full-resolution head: about 1.5 times the edge network's work, which put grey images above the
issue's 2 s per megapixel and channel. Two variants reuse what the edge network computes anyway (its encoder's
outputs, :meth:`~torch_modulo.singleshot.learned.EdgeJumpNet.encode`):

- ``--half`` (:class:`HalfLevels`, shipped as ``torch_modulo/singleshot/weights/levels.pt`` through ``export``): a
  head of width ``--head-width`` at half resolution on the half-resolution features ``d2`` and the input pooled
  2 x 2, one cost per 2 x 2 block;
- without it (:class:`SharedLevels`, not kept): its own copy of the last decoder stage (``dec1``, started from the
  shipped one) and a head at full resolution.

    python -m research.level_shared train --half --head-width 32 --steps 12000 --seed 54 --out half.pt --card half.md
    python -m research.level_shared export --weights half.pt --out torch_modulo/singleshot/weights/levels.pt
    python -m research.level_shared eval --weights half.pt --split train    # vs the tree, and timing
    python -m research.level_shared train --steps 4000 --out shared.pt       # the variant not kept, ~17 min

``train`` writes the weights, a summary of the run beside them (``half.json``: settings, minutes, final loss, the
scenes it read) and, with ``--card``, a model card (data, settings, and the numbers of ``eval`` on the training and
validation scenes; ``card`` writes one for any record). The run of the shipped weights took about 22 minutes on 2
cores, the card about 5 more.

Evaluation decodes as the package does (the shipped tree, then :func:`torch_modulo.singleshot.levels.region_moves`)
and prints exact-k / rolled-over right (%) per protocol, and the seconds per megapixel of the level prediction.

``train --rolled-weight W`` weighs the values that rolled over ``W`` times in the loss; ``eval --prior P`` divides
the probabilities of the levels above 0 by ``P`` (tried, not kept: the weighting moves the head's prior towards
the rolled-over levels and nothing else; the shipped head with ``--prior 0.333`` scores as ``--rolled-weight 3``
does, docs/singleshot.md)::

    python -m research.level_shared train --half --head-width 32 --steps 12000 --seed 57 --rolled-weight 3 --out rw3.pt
    python -m research.level_shared eval --weights torch_modulo/singleshot/weights/levels.pt --prior 0.333333

``train --context W`` (:class:`ContextLevels`, tried, not kept: no better on the training scenes, the selection set
or the validation scenes, docs/singleshot.md) adds a coarse branch of width ``W`` beside the half-resolution head;
``--init`` starts a run from other level weights (the shipped ``levels.pt`` too), ``--crop`` and ``--batch`` set the
training crops::

    python -m research.level_shared train --context 32 --head-width 32 \
        --init torch_modulo/singleshot/weights/levels.pt --crop 320 --batch 5 --steps 2500 --lr 5e-4 --seed 70 \
        --out context.pt
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from research.level_head import Progress, cosine, level_loss, recipe_batches
from torch_modulo import protocols
from torch_modulo.singleshot.learned import (
    BAND,
    SLOTS,
    EdgeJumpNet,
    decode_jumps,
    edge_features,
    load_model,
    predict_jumps,
)
from torch_modulo.singleshot.levels import LEVELS, LevelHead, region_moves

BITS = 8
PERIOD = 1 << BITS
ROOT = Path(__file__).resolve().parents[1]

#: What a training batch is (research/level_head.py's recipe_batches), for the model card.
RECIPE = (
    "references/learned_single/train.py's batches of 6 crops of 128 x 128, luminance or RGB, the brightest region "
    "rolled over 2 to 20 times, half the scene crops exposed by their whole scene's percentile, 30% procedural, "
    "15% with shot and read noise; labels: every pixel's level floor(counts / 256), clipped to 0 .. 15"
)


class SharedLevels(nn.Module):
    """Level logits from the edge network's ``encode`` outputs: its own ``dec1`` and a :class:`LevelHead`."""

    def __init__(self, edge: EdgeJumpNet, head_width: int = 24, levels: int = LEVELS) -> None:
        super().__init__()
        self.dec1 = copy.deepcopy(edge.dec1)
        w = edge.config["width"]
        self.head = LevelHead(3 * w + 15, head_width, levels)

    def forward(self, x: torch.Tensor, e1: torch.Tensor, d2: torch.Tensor) -> torch.Tensor:
        up = F.interpolate(d2, scale_factor=2.0, mode="nearest")
        features = self.dec1(torch.cat([up, e1], dim=1))
        return self.head(torch.cat([features, up, x], dim=1))


class HalfLevels(nn.Module):
    """Level logits at half resolution from the edge network's ``d2`` and the input pooled 2 x 2, upsampled (nearest)
    to full resolution: no full-resolution stage of its own."""

    def __init__(self, edge: EdgeJumpNet, head_width: int = 32, levels: int = LEVELS) -> None:
        super().__init__()
        self.head = LevelHead(2 * edge.config["width"] + 15, head_width, levels)

    def head_input(self, half: torch.Tensor) -> torch.Tensor:
        """What the head reads from the half-resolution features (``d2`` and the pooled input): those alone."""
        return half

    def forward(self, x: torch.Tensor, e1: torch.Tensor, d2: torch.Tensor) -> torch.Tensor:
        logits = self.head(self.head_input(torch.cat([d2, F.avg_pool2d(x, 2)], dim=1)))
        b, s, n, h, w = logits.shape
        return F.interpolate(logits.reshape(b, s * n, h, w), scale_factor=2.0, mode="nearest").view(
            b, s, n, 2 * h, 2 * w
        )


class ContextLevels(HalfLevels):
    """:class:`HalfLevels` with a coarse branch: ``d2`` pooled 8 x 8 (1/16 of the image), three 3 x 3 convolutions
    (dilations 1, 2, 4: about 120 pixels more radius than the trunk's 142), upsampled (bilinear) and given to the
    head beside ``d2``. A bright region's level may hang on what lies beyond the trunk's view (tried, not kept)."""

    def __init__(self, edge: EdgeJumpNet, head_width: int = 32, levels: int = LEVELS, context: int = 32) -> None:
        super().__init__(edge, head_width, levels)
        cin = 2 * edge.config["width"] + 15
        self.context = LevelHead(cin, context, 1).net[:-1]  # a level head's three dilated convolutions
        self.head = LevelHead(cin + context, head_width, levels)

    def head_input(self, half: torch.Tensor) -> torch.Tensor:
        """The half-resolution features and the coarse branch's, upsampled to them."""
        coarse = self.context(F.avg_pool2d(half, 8, ceil_mode=True))
        coarse = F.interpolate(coarse, size=half.shape[-2:], mode="bilinear", align_corners=False)
        return torch.cat([half, coarse], dim=1)


def load(path: Path, edge: EdgeJumpNet) -> nn.Module:
    """A ``train`` record, or a package level weights file (``export``'s output, whose trunk is ``edge``), as the
    research network."""
    record = torch.load(path, map_location="cpu", weights_only=True)
    if "head" in record:  # the package's format: a half-resolution head on a copy of its trunk
        trunk = edge.state_dict()
        if record["state"].keys() != trunk.keys() or any(
            not torch.equal(v.float(), trunk[k].half().float()) for k, v in record["state"].items()
        ):
            raise SystemExit(f"{path}: its trunk is not the edge network in use")
        head = {k: v.float() for k, v in record["head"].items()}
        net = HalfLevels(edge, int(head["net.0.bias"].numel()), int(head["net.6.bias"].numel()) // SLOTS)
        net.head.load_state_dict(head)
        return net.eval()
    if record.get("context"):
        net = ContextLevels(edge, record["head_width"], record["levels"], record["context"])
    else:
        net = (HalfLevels if record.get("half") else SharedLevels)(edge, record["head_width"], record["levels"])
    net.load_state_dict({k: v.float() for k, v in record["state"].items()})
    return net.eval()


@torch.no_grad()
def level_costs(edge: EdgeJumpNet, net: nn.Module, moduli: torch.Tensor) -> np.ndarray:
    """(C, LEVELS, H, W) float16 costs of (C, H, W) moduli, one per pixel (whole image at once; research only)."""
    c, h, w = moduli.shape
    x = moduli[None].float().expand(1, 3, h, w)
    x = F.pad(x, (0, (-w) % edge.stride, 0, (-h) % edge.stride), mode="replicate")
    features = edge_features(x, BITS)
    logits = net(features, *edge.encode(features))[0, :c, :, :h, :w]
    return (-torch.log_softmax(logits, dim=1)).numpy().astype(np.float16)


def start_from(net: nn.Module, init: nn.Module) -> None:
    """Copy ``init``'s weights into ``net`` where the shapes allow; a first convolution with more input channels
    takes ``init``'s in its first ones and zeros in the rest (a :class:`ContextLevels` starts as the
    :class:`HalfLevels` it is given, its coarse branch unused)."""
    state = net.state_dict()
    for key, value in init.state_dict().items():
        if key not in state:
            continue
        if state[key].shape == value.shape:
            state[key] = value.clone()
        elif state[key].ndim == 4 and state[key].shape[0] == value.shape[0] and state[key].shape[2:] == value.shape[2:]:
            state[key] = torch.zeros_like(state[key])
            state[key][:, : value.shape[1]] = value
        else:
            raise SystemExit(f"--init: {key} has shape {tuple(value.shape)}, this network {tuple(state[key].shape)}")
    net.load_state_dict(state)


def train(args: argparse.Namespace) -> None:
    batch = recipe_batches(args)
    edge = load_model()
    if args.context:
        net = ContextLevels(edge, args.head_width, context=args.context).train()
    else:
        net = (HalfLevels if args.half else SharedLevels)(edge, args.head_width).train()
    if args.init is not None:
        start_from(net, load(args.init, edge))
    opt = torch.optim.Adam(net.parameters(), lr=args.lr)
    progress = Progress(args.steps)
    for step in range(args.steps):
        cosine(opt, args.lr, step, args.steps)
        wrapped, counts = batch()
        x = edge_features(wrapped, BITS)
        with torch.no_grad():
            e1, d2 = edge.encode(x)
        loss = level_loss(net(x, e1, d2), counts, args.rolled_weight)
        opt.zero_grad()
        loss.backward()
        opt.step()
        progress(step, float(loss.detach()))
    record = {
        "half": args.half or bool(args.context),
        "context": args.context,
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
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items() if k != "func"},
        "recipe": RECIPE,
        # what recipe_batches read (the recipe's load_train_scenes: the training split of the dev scenes)
        "scenes": [
            str(p.relative_to(protocols.DEV_SCENES)) for p in protocols.list_scenes(protocols.DEV_SCENES, "train")
        ],
    }
    summary_path(args.out).write_text(json.dumps(summary, indent=2) + "\n")
    if args.card is not None:
        write_card(argparse.Namespace(weights=args.out, out=args.card, splits=["train", "validation"], data=None))


def scores(
    edge: EdgeJumpNet, net: nn.Module, scenes: list[Path], proto: str, prior: float = 1.0
) -> tuple[np.ndarray, float]:
    """Mean exact-k / rolled-over right (%) of the tree and of the region moves over ``scenes`` under ``proto`` (four
    values), and the level prediction's seconds per megapixel and channel. ``prior``: the probabilities of the levels
    above 0 are divided by it (``log prior`` added to their costs), which undoes a ``--rolled-weight`` of that size."""
    rows, seconds, pixels = [], 0.0, 0
    for path in scenes:
        truth = protocols.protocol_counts(protocols.load_scene(path, 512), proto)
        moduli = torch.remainder(truth, PERIOD).to(torch.int64)
        planes = moduli.numpy()
        jump, cost = predict_jumps(edge, moduli.float(), BITS, band=BAND)
        start = time.perf_counter()
        u = level_costs(edge, net, moduli)
        if prior != 1.0:
            u[:, 1:] += np.float16(np.log(prior))
        seconds += time.perf_counter() - start
        pixels += planes.size
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
    return 100 * np.nanmean(np.array(rows), axis=0), seconds / pixels * 1e6


def scene_list(split: str, data: Path | None) -> list[Path]:
    """The dev scenes of ``split``, or every scene of another folder ``data``."""
    return (
        protocols.list_scenes(data, "all") if data is not None else protocols.list_scenes(protocols.DEV_SCENES, split)
    )


def evaluate(args: argparse.Namespace) -> None:
    torch.set_num_threads(args.threads)
    edge = load_model()
    net = load(args.weights, edge)
    scenes = scene_list(args.split, args.data)
    for proto in args.protocols:
        mean, speed = scores(edge, net, scenes, proto, args.prior)
        print(
            f"{proto} ({len(scenes)} scenes) tree {mean[0]:.2f} / {mean[1]:.2f} | moves {mean[2]:.2f} / {mean[3]:.2f}"
            f" | levels {speed:.3f} s/MP/ch (whole image, not the package's strips)",
            flush=True,
        )


def summary_path(weights: Path) -> Path:
    """Where ``train`` writes the summary of the run that made ``weights``: beside it, ``.json`` for ``.pt``."""
    return weights.with_suffix(".json")


def write_card(args: argparse.Namespace) -> None:
    """A model card (markdown) of a ``train`` record: its data and settings (from its summary), and exact-k /
    rolled-over right of the shipped tree and of the region moves with its levels on ``args.splits`` (and on every
    scene of ``args.data``)."""
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
        weight = settings.get("rolled_weight", 1.0)
        rolled = "" if weight == 1.0 else f" --rolled-weight {weight:g}"
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
            f"`python -m research.level_shared train {'--half ' if settings.get('half') else ''}--head-width "
            f"{settings['head_width']} --steps {settings['steps']} --lr {settings['lr']} --seed {settings['seed']}"
            f"{rolled}` "
            f"({summary['minutes']} minutes, {settings['threads']} threads; {summary['head_parameters']} trained "
            f"parameters; final smoothed loss {loss}). The trunk is the shipped edge network, "
            "frozen.",
            "",
        ]
    lines += [
        "## Numbers",
        "",
        "Exact-k / rolled-over right (%), longer side 512, each plane aligned by its most common offset; the shipped "
        "edge network's tree, then `region_moves` with these levels (`python -m research.level_shared eval`).",
        "",
        "| scenes | protocol | tree | with the level moves |",
        "|---|---|---|---|",
    ]
    groups = [(split, scene_list(split, None)) for split in args.splits]
    if args.data is not None:
        groups.append((f"every scene of `{args.data.name}`", scene_list("all", args.data)))
    for name, scenes in groups:
        for proto in ("A", "A10", "B"):
            mean, _ = scores(edge, net, scenes, proto)
            lines.append(
                f"| {name} ({len(scenes)}) | {proto} | {mean[0]:.2f} / {mean[1]:.2f} | {mean[2]:.2f} / {mean[3]:.2f} |"
            )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(f"wrote {args.out}", flush=True)


def export(args: argparse.Namespace) -> None:
    """A ``--half`` record as the package's level weights: the shipped edge network as the trunk, and the head."""
    edge = load_model()
    record = torch.load(args.weights, map_location="cpu", weights_only=True)
    if not record.get("half") or record.get("context"):
        raise SystemExit(f"{args.weights}: only a --half record without --context is the package's LevelNet")
    head = {k.removeprefix("head."): v for k, v in record["state"].items() if k.startswith("head.")}
    out = {"config": edge.config, "state": {k: v.half() for k, v in edge.state_dict().items()}, "head": head}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    torch.save(out, args.out)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    t = sub.add_parser("train", help="train a level head on the frozen encoder (with a decoder stage unless --half)")
    t.add_argument("--steps", type=int, default=6000)
    t.add_argument("--lr", type=float, default=2e-3)
    t.add_argument("--head-width", type=int, default=24)
    t.add_argument("--half", action="store_true", help="a head at half resolution on d2 alone (HalfLevels)")
    t.add_argument("--seed", type=int, default=53)
    t.add_argument("--context", type=int, default=0, help="width of a coarse branch (ContextLevels; 0: none)")
    t.add_argument("--init", type=Path, default=None, help="start from these level weights (a record or levels.pt)")
    t.add_argument("--crop", type=int, default=128, help="training crops' side")
    t.add_argument("--batch", type=int, default=6, help="crops per step")
    t.add_argument("--rolled-weight", type=float, default=1.0, help="weigh the values that rolled over this much")
    t.add_argument("--threads", type=int, default=2)
    t.add_argument("--out", type=Path, required=True)
    t.add_argument("--card", type=Path, default=None, help="then write a model card here (evaluates: minutes)")
    e = sub.add_parser("eval", help="the shipped tree vs the region moves on the scenes")
    e.add_argument("--weights", type=Path, required=True)
    e.add_argument("--split", default="train", choices=protocols.SPLITS)
    e.add_argument("--data", type=Path, default=None, help="another scenes folder (all its scenes)")
    e.add_argument("--protocols", nargs="+", default=["A", "A10", "B"], choices=list(protocols.PROTOCOL_PEAKS))
    e.add_argument("--threads", type=int, default=2)
    e.add_argument("--prior", type=float, default=1.0, help="divide the levels above 0's probabilities by this")
    x = sub.add_parser("export", help="a --half record as torch_modulo/singleshot/weights/levels.pt")
    x.add_argument("--weights", type=Path, required=True)
    x.add_argument("--out", type=Path, required=True)
    c = sub.add_parser("card", help="a model card of a train record: data, settings and numbers")
    c.add_argument("--weights", type=Path, required=True)
    c.add_argument("--out", type=Path, required=True)
    c.add_argument("--splits", nargs="+", default=["train", "validation"], choices=protocols.SPLITS)
    c.add_argument("--data", type=Path, default=None, help="also every scene of another folder")
    args = ap.parse_args(argv)
    {"train": train, "eval": evaluate, "export": export, "card": write_card}[args.command](args)


if __name__ == "__main__":
    main()
