"""Unit tests of research/level_shared.py: the half-resolution head's shapes and its export to the package's format."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from research import level_shared
from torch_modulo.singleshot.learned import load_model, weights_path
from torch_modulo.singleshot.levels import LEVEL_WEIGHTS, load_levels, predict_levels


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
    package = predict_levels(load_levels(tmp_path / "levels.pt"), moduli, 8)  # one per 2 x 2 block
    assert np.allclose(research[..., ::2, ::2].astype(np.float32), package.astype(np.float32), atol=1e-2)


def test_train_writes_weights_summary_and_card(tmp_path, monkeypatch) -> None:
    from torch_modulo.io import write_image

    counts = torch.arange(16 * 24, dtype=torch.float32).reshape(1, 1, 16, 24).expand(2, 3, 16, 24) * 5
    monkeypatch.setattr(level_shared, "recipe_batches", lambda args: lambda: (torch.remainder(counts, 256), counts))
    y, x = torch.meshgrid(torch.linspace(0, 1, 24), torch.linspace(0, 1, 32), indexing="ij")
    write_image(tmp_path / "ramp.exr", torch.stack([1 + 30 * x * y, 1 + 20 * x, 1 + 10 * y]))
    monkeypatch.setattr(level_shared, "scene_list", lambda split, data: [tmp_path / "ramp.exr"])
    out, card = tmp_path / "run" / "half.pt", tmp_path / "half.md"
    level_shared.main(["train", "--half", "--steps", "2", "--seed", "3", "--threads", "1", "--out", str(out)])
    assert level_shared.load(out, load_model()).head.levels == level_shared.LEVELS
    summary = json.loads((tmp_path / "run" / "half.json").read_text())
    assert summary["settings"]["steps"] == 2 and summary["settings"]["seed"] == 3 and summary["minutes"] >= 0
    level_shared.main(["card", "--weights", str(out), "--out", str(card), "--splits", "validation"])
    text = card.read_text()
    assert "--half --head-width 24 --steps 2 --lr 0.002 --seed 3" in text
    rows = [line for line in text.splitlines() if line.startswith("| validation (1) |")]
    assert [row.split(" | ")[1] for row in rows] == ["A", "A10", "B"]  # one row per protocol, with its numbers
    assert all(len(row.split(" / ")) == 3 for row in rows)


def test_load_reads_the_package_format(tmp_path) -> None:
    edge = load_model()
    net = level_shared.load(Path(weights_path(None, LEVEL_WEIGHTS)), edge)  # the shipped levels.pt
    moduli = torch.randint(0, 256, (1, 40, 52), generator=torch.Generator().manual_seed(2))
    research = level_shared.level_costs(edge, net, moduli)[..., ::2, ::2]  # one per pixel: a pixel per block
    assert np.allclose(
        research.astype(np.float32), predict_levels(load_levels(), moduli, 8).astype(np.float32), atol=1e-2
    )


def test_context_head_starts_as_its_init_and_is_not_exported(tmp_path) -> None:
    torch.manual_seed(4)
    edge = load_model()
    init = level_shared.load(Path(weights_path(None, LEVEL_WEIGHTS)), edge)
    net = level_shared.ContextLevels(edge, 32, context=8)
    level_shared.start_from(net, init)
    x = torch.rand(1, 15, 40, 56)  # a side that is not a multiple of the coarse branch's 16 pixels
    with torch.no_grad():
        features = edge.encode(x)
        assert torch.equal(net(x, *features), init(x, *features))  # the coarse branch enters at zero weight
        for p in net.context.parameters():
            p.add_(0.1)
        net.head.net[0].weight.add_(0.1)
        assert not torch.allclose(net(x, *features), init(x, *features))
    record = {"half": True, "context": 8, "head_width": 32, "levels": level_shared.LEVELS, "state": net.state_dict()}
    torch.save(record, tmp_path / "context.pt")
    loaded = level_shared.load(tmp_path / "context.pt", edge)
    assert isinstance(loaded, level_shared.ContextLevels)
    with torch.no_grad():
        assert torch.allclose(loaded(x, *features), net(x, *features), atol=1e-2)
    try:
        level_shared.export(argparse.Namespace(weights=tmp_path / "context.pt", out=tmp_path / "levels.pt"))
    except SystemExit as err:
        assert "--context" in str(err)
    else:
        raise AssertionError("a --context record was exported as the package's LevelNet")
    assert not (tmp_path / "levels.pt").exists()


def test_start_from_names_a_shape_it_cannot_copy() -> None:
    edge = load_model()
    wide, narrow = level_shared.HalfLevels(edge, 32), level_shared.HalfLevels(edge, 16)
    try:
        level_shared.start_from(narrow, wide)
    except SystemExit as err:
        assert "head.net.0" in str(err)
    else:
        raise AssertionError("start_from copied weights of another width")
