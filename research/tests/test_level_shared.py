"""Unit tests of research/level_shared.py: the half-resolution head's shapes and its export to the package's format."""

from __future__ import annotations

import argparse

import numpy as np
import torch

from research import level_shared
from torch_modulo.singleshot.learned import load_model
from torch_modulo.singleshot.levels import load_levels, predict_levels


def test_half_head_shapes() -> None:
    edge = load_model()
    x = torch.zeros(1, 15, 16, 24)
    with torch.no_grad():
        out = level_shared.HalfLevels(edge)(x, *edge.encode(x))
    assert out.shape == (1, 3, level_shared.LEVELS, 16, 24)


def test_export_loads_in_the_package(tmp_path) -> None:
    torch.manual_seed(0)
    edge = load_model()
    net = level_shared.HalfLevels(edge)
    record = {"half": True, "head_width": 32, "levels": level_shared.LEVELS, "state": net.state_dict()}
    torch.save(record, tmp_path / "half.pt")
    level_shared.export(argparse.Namespace(weights=tmp_path / "half.pt", out=tmp_path / "levels.pt"))
    moduli = torch.randint(0, 256, (1, 40, 52), generator=torch.Generator().manual_seed(1))
    research = level_shared.level_costs(edge, level_shared.load(tmp_path / "half.pt", edge), moduli)
    package = predict_levels(load_levels(tmp_path / "levels.pt"), moduli, 8)
    assert np.allclose(research.astype(np.float32), package.astype(np.float32), atol=1e-2)
