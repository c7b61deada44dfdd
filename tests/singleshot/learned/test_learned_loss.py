"""Tests of the learned single-shot method: the training loss (loss.py): targets from counts, a tiny model that
learns."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from learned_helpers import scene  # tests/singleshot/learned/

from torch_modulo.capture import modulo_wrap
from torch_modulo.singleshot.learned import (
    EdgeJumpNet,
    edge_features,
    edge_loss,
    edge_targets,
)

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/singleshot/conftest.py


class TestTraining:
    def test_targets_match_counts(self) -> None:
        counts = torch.from_numpy(scene(16))[None, None]
        target, hard = edge_targets(counts, 8, 15)
        wd = (torch.diff(counts % 256, dim=-1) + 128) % 256 - 128
        assert torch.equal(torch.diff(counts, dim=-1), wd + 256 * (target[:, :, 0, :, :-1] - 15))
        assert bool(hard.any())

    def test_tiny_model_learns(self) -> None:
        torch.manual_seed(0)
        counts = torch.from_numpy(np.stack([scene(24, s) for s in range(2)])).float()[:, None].expand(2, 3, 24, 24)
        net = EdgeJumpNet(width=4, max_jump=7, dilations=(1,))
        opt = torch.optim.Adam(net.parameters(), lr=1e-2)
        x = edge_features(modulo_wrap(counts, 8), 8)
        target, _ = edge_targets(counts, 8, 7)
        losses = []
        for _ in range(20):
            loss = edge_loss(net(x), target)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(float(loss.detach()))
        assert losses[-1] < 0.6 * losses[0]
