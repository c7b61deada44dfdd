"""How well the learned decoder's confidence ranks its own errors, against ``unwrap_confidence`` on the same results.

For every scene of a split, under protocols A and B (longer side 256): ``unwrap_single(method="learned")``, the
pixels whose aligned rollover count is wrong, and two confidence maps of that result: ``tm.learned_confidence``
(the weakest pair on the tree path, from the network's probabilities) and ``tm.unwrap_confidence`` (bottleneck
steps of the restored image). Reported over the scene-protocol pairs with at least one error: the mean ROC AUC
(probability that a wrong pixel is less confident than a right one) and the mean share of the errors among the
10% least confident pixels (``single_limits.rank_scores``, as for ``unwrap_confidence`` there); the same over the
pairs under 10% wrong.

    python -m research.learned_confidence --split train
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

import torch_modulo as tm
from research.single_limits import rank_scores
from torch_modulo import protocols


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--split", default="train", choices=protocols.SPLITS)
    ap.add_argument("--scale", type=int, default=256)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    rows = []
    for path in protocols.list_scenes(protocols.DEV_SCENES, split=args.split):
        for proto in ("A", "B"):
            truth = protocols.protocol_counts(protocols.load_scene(path, args.scale), proto)
            modulus = torch.remainder(truth, 256)
            restored = tm.unwrap_single(modulus, 8, method="learned")
            aligned = protocols.align_offsets(restored, truth)
            wrong = (torch.floor(aligned / 256) != torch.floor(truth / 256)).numpy().ravel()
            if not wrong.any():
                continue
            auc_learned, caught_learned = rank_scores(tm.learned_confidence(modulus, 8).numpy().ravel(), wrong)
            auc_steps, caught_steps = rank_scores(tm.unwrap_confidence(restored, 8).numpy().ravel(), wrong)
            rows.append([auc_learned, auc_steps, caught_learned, caught_steps, wrong.mean()])
    a = np.array(rows)
    for name, part in (("all", a), ("under 10% wrong", a[a[:, 4] < 0.1])):
        m = np.nanmean(part[:, :4], axis=0)
        print(
            f"{args.split}, {name} ({len(part)} scene-protocol pairs): ROC AUC learned_confidence {m[0]:.3f}, "
            f"unwrap_confidence {m[1]:.3f}; errors among the 10% least confident: {m[2]:.3f} vs {m[3]:.3f}"
        )


if __name__ == "__main__":
    main()
