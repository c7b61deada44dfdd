"""Issue #35: how much support the level moves need before they move a region (``python -m research.level_support``).

Every dev scene under protocols A, A10 and B: the network runs once; then the level moves (:class:`RegionMoves`) with
a support rule ``tau``: a move that the border pairs oppose (their cost rises) is kept only if the level head prefers
the new level by at least ``tau`` nats per pixel on average over the region (``tau = 0``: today's rule, the sum
alone). Prints exact-k per variant against ``"guided"`` (anchored as ``unwrap_single`` anchors) and the means.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from torch_modulo import protocols
from torch_modulo.singleshot.anchor import anchor_k
from torch_modulo.singleshot.learned import BAND, decode_jumps, load_levels, load_model, predict_jumps
from torch_modulo.singleshot.learned.levels import RegionMoves
from torch_modulo.singleshot.pathfollow import quality_guided_colour_k

BITS, PERIOD = 8, 256


class SupportedMoves(RegionMoves):
    """:class:`RegionMoves` that refuses a move the border pairs oppose unless the level costs drop by at least
    ``support`` nats per pixel of the region on average (not shipped: it only cost, docs/singleshot.md)."""

    def __init__(self, *args, support: float = 0.0, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.support = support

    def drops(self, regions: np.ndarray, first: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
        delta, entry = super().drops(regions, first)
        if self.support <= 0:
            return delta, entry
        to = self.moved[regions] + np.asarray((-2, -1, 1, 2))[:, None]
        reach = self.level.shape[0] // 2
        level = np.where(np.abs(to) <= reach, self.level[np.clip(to, -reach, reach) + reach, regions], np.inf)
        level -= self.level[self.moved[regions] + reach, regions]
        size = self.starts[regions + 1] - self.starts[regions]
        with np.errstate(invalid="ignore"):
            weak = (delta - level > 0) & (level > -self.support * size)
        return np.where(weak, np.inf, delta), entry


def score(k: np.ndarray, m: np.ndarray, truth: torch.Tensor, peak: float) -> tuple[float, float]:
    k = np.stack([anchor_k(kc, 1e-3, modulus=mc, bits=BITS) for kc, mc in zip(k, m, strict=True)])
    s = protocols.score_scene(torch.from_numpy((m + PERIOD * k).astype(np.float64)), truth, BITS, peak)
    return s.exact_k, s.rolled_over_right


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--protocols", nargs="+", default=["A", "A10", "B"])
    ap.add_argument("--taus", nargs="+", type=float, default=[0.0, 0.1, 0.3, 0.7])
    ap.add_argument("--max-scenes", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    net, lv = load_model(), load_levels()
    scenes = protocols.list_scenes(protocols.DEV_SCENES)[: args.max_scenes or None]
    for proto in args.protocols:
        peak = protocols.PROTOCOL_PEAKS[proto]
        sums = np.zeros((len(args.taus) + 1, 2))
        for path in scenes:
            truth = protocols.protocol_counts(protocols.load_scene(path, 512), proto)
            m = torch.remainder(truth, PERIOD).to(torch.int64).numpy()
            jump, cost, u = predict_jumps(net, torch.from_numpy(m).float(), BITS, False, 768, BAND, lv)
            tree = [decode_jumps(p, jump[c], cost[c, :, BAND], BITS)[0] for c, p in enumerate(m)]
            rows = [score(quality_guided_colour_k(m.astype(np.float64), BITS), m, truth, peak)]
            for tau in args.taus:
                ks = []
                for c, p in enumerate(m):
                    moves = SupportedMoves(
                        p, tree[c], cost[c], jump[c].astype(np.int64) - BAND, u[c], BITS, support=tau
                    )
                    ks.append(moves.run())
                rows.append(score(np.stack(ks), m, truth, peak))
            sums += np.asarray(rows)
            line = " ".join(f"{100 * e:6.2f}" for e, _ in rows)
            print(f"{proto:3s} {path.name[-26:]:26s} guided/taus {line}", flush=True)
        print(proto, "means (exact-k, rolled) guided then taus", np.round(100 * sums / len(scenes), 2).tolist())


if __name__ == "__main__":
    main()
