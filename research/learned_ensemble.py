"""Several trained weights at once: the mean of their jump log-probabilities, decoded by the same tree.

If the learned method's errors were the variance of one training run, weights trained with other seeds or settings
would disagree on them and their mean would fix some; if they are what the network and the data cannot tell, the
runs agree and the mean changes nothing.

    python -m research.learned_ensemble --split train --weights S4.pt SEED10.pt HW1.pt
    python -m research.learned_ensemble --data <selection set> --weights ...

Reported per protocol: mean exact-k / rolled-over right of the first weights alone, then of the mean of the first
two, the first three, ... (all of them last).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from torch_modulo import protocols
from torch_modulo.singleshot.learned import decode_edges, load_model, predict_edges

BITS = 8
PERIOD = 1 << BITS


def mean_logp(logps: list[torch.Tensor]) -> torch.Tensor:
    """The normalised mean of (C, 2, 2J + 1, H, W) jump log-probabilities (a product of experts)."""
    return torch.log_softmax(torch.stack(logps).mean(dim=0), dim=2)


def scene_rows(truth: torch.Tensor, nets: list[torch.nn.Module]) -> list[tuple[float, float]]:
    """(exact-k, rolled-over right) of the first 1, 2, ... networks' mean on one scene."""
    moduli = torch.remainder(truth, PERIOD).to(torch.int64)
    planes = moduli.numpy()
    logps = [predict_edges(net, moduli, BITS) for net in nets]
    rows = []
    for n in range(1, len(nets) + 1):
        logp = mean_logp(logps[:n]).numpy()
        k = np.stack([decode_edges(m, lp, BITS)[0] for m, lp in zip(planes, logp, strict=True)])
        score = protocols.score_scene(torch.from_numpy(planes + PERIOD * k).double(), truth.double(), BITS)
        rows.append((score.exact_k, score.rolled_over_right))
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--weights", nargs="+", required=True, help="weights files; the first is the reference")
    ap.add_argument("--split", default="all", choices=protocols.SPLITS)
    ap.add_argument("--data", type=Path, default=protocols.DEV_SCENES, help="scene folder")
    ap.add_argument("--protocols", nargs="+", default=["A", "A10", "B"], choices=list(protocols.PROTOCOL_PEAKS))
    ap.add_argument("--scale", type=int, default=512)
    args = ap.parse_args(argv)
    nets = [load_model(w) for w in args.weights]
    scenes = protocols.list_scenes(args.data, split=args.split)
    for proto in args.protocols:
        rows = np.array(
            [scene_rows(protocols.protocol_counts(protocols.load_scene(p, args.scale), proto), nets) for p in scenes]
        )
        for n, (exact, rolled) in enumerate(np.nanmean(rows, axis=0), start=1):
            print(
                f"{proto:3s} {args.split} ({len(scenes)}) mean of {n} weights: exact-k {exact:.4f}, rolled {rolled:.4f}"
            )


if __name__ == "__main__":
    main()
