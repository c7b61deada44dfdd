"""Tests of references/learned_single/levels.py, the recipe of the shipped level weights: the head's shapes and loss,
its export to the package's format, a tiny training run with its summary and model card, and what it refuses."""

from __future__ import annotations

import json
import math
from argparse import Namespace
from pathlib import Path

import numpy as np
import pytest
import torch

from references.learned_single import levels as recipe
from torch_modulo.singleshot.learned import LEVEL_WEIGHTS, LEVELS, load_levels, load_model, predict_levels, weights_path


def test_half_head_shapes() -> None:
    edge = load_model()
    x = torch.zeros(1, 15, 16, 24)
    with torch.no_grad():
        out = recipe.HalfLevels(edge)(x, edge.encode(x)[1])
    assert out.shape == (1, 3, LEVELS, 16, 24)
    assert torch.equal(out[..., ::2, ::2], out[..., 1::2, 1::2])  # one cost per 2 x 2 block


def test_level_loss_counts_whole_periods_and_clips_at_the_top_level() -> None:
    counts = torch.tensor([10.0, 300.0, 600.0, 1e6]).view(1, 1, 1, 4)  # levels 0, 1, 2 and beyond the last
    flat = torch.zeros(1, 1, LEVELS, 1, 4)
    assert float(recipe.level_loss(flat, counts)) == pytest.approx(math.log(LEVELS))
    sure = torch.full((1, 1, LEVELS, 1, 4), -30.0)
    for i, level in enumerate((0, 1, 2, LEVELS - 1)):
        sure[0, 0, level, 0, i] = 30.0
    assert float(recipe.level_loss(sure, counts)) < 1e-6
    assert float(recipe.level_loss(sure, counts + 256)) > 30  # every value a period higher: all wrong but the top


def test_export_loads_in_the_package(tmp_path: Path) -> None:
    torch.manual_seed(0)
    edge = load_model()
    net = recipe.HalfLevels(edge)
    record = {"half": True, "head_width": 32, "levels": LEVELS, "state": net.state_dict()}
    torch.save(record, tmp_path / "half.pt")
    recipe.export(Namespace(weights=tmp_path / "half.pt", out=tmp_path / "levels.pt"))
    moduli = torch.randint(0, 256, (1, 40, 52), generator=torch.Generator().manual_seed(1))
    ours = recipe.level_costs(edge, recipe.load(tmp_path / "half.pt", edge), moduli)
    package = predict_levels(load_levels(tmp_path / "levels.pt"), moduli, 8)  # one per 2 x 2 block
    assert np.allclose(ours[..., ::2, ::2].astype(np.float32), package.astype(np.float32), atol=1e-2)


def test_load_reads_the_package_format() -> None:
    edge = load_model()
    net = recipe.load(Path(weights_path(None, LEVEL_WEIGHTS)), edge)  # the shipped levels.pt
    moduli = torch.randint(0, 256, (1, 40, 52), generator=torch.Generator().manual_seed(2))
    ours = recipe.level_costs(edge, net, moduli)[..., ::2, ::2]  # one per pixel: a pixel per block
    assert np.allclose(ours.astype(np.float32), predict_levels(load_levels(), moduli, 8).astype(np.float32), atol=1e-2)


def test_train_writes_weights_summary_and_card(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from torch_modulo.io import write_image

    counts = torch.arange(16 * 24, dtype=torch.float32).reshape(1, 1, 16, 24).expand(2, 3, 16, 24) * 5
    monkeypatch.setattr(recipe, "recipe_batches", lambda seed, threads: lambda: (torch.remainder(counts, 256), counts))
    y, x = torch.meshgrid(torch.linspace(0, 1, 24), torch.linspace(0, 1, 32), indexing="ij")
    write_image(tmp_path / "ramp.exr", torch.stack([1 + 30 * x * y, 1 + 20 * x, 1 + 10 * y]))
    monkeypatch.setattr(recipe, "scene_list", lambda split, data: [tmp_path / "ramp.exr"])
    out, card = tmp_path / "run" / "half.pt", tmp_path / "half.md"
    recipe.main(["train", "--head-width", "8", "--steps", "2", "--seed", "3", "--threads", "1", "--out", str(out)])
    assert recipe.load(out, load_model()).head.levels == LEVELS
    summary = json.loads((tmp_path / "run" / "half.json").read_text())
    assert summary["settings"]["steps"] == 2 and summary["settings"]["seed"] == 3 and summary["minutes"] >= 0
    recipe.main(["card", "--weights", str(out), "--out", str(card), "--splits", "validation"])
    text = card.read_text()
    assert "levels train --head-width 8 --steps 2 --lr 0.002 --seed 3" in text
    rows = [line for line in text.splitlines() if line.startswith("| validation (1) |")]
    assert [row.split(" | ")[1] for row in rows] == ["A", "A10", "B"]  # one row per protocol, with its numbers
    assert all(len(row.split(" / ")) == 3 for row in rows)


def test_refuses_records_of_other_heads(tmp_path: Path) -> None:
    """A record of a variant that was tried and not kept (a coarse branch, a full-resolution head) is neither loaded
    nor exported as the package's level weights."""
    edge = load_model()
    state = recipe.HalfLevels(edge).state_dict()
    for name, record in (
        ("context", {"half": True, "context": 8, "head_width": 32, "levels": LEVELS, "state": state}),
        ("full", {"half": False, "head_width": 32, "levels": LEVELS, "state": state}),
    ):
        torch.save(record, tmp_path / f"{name}.pt")
        with pytest.raises(SystemExit, match="half-resolution head"):
            recipe.export(Namespace(weights=tmp_path / f"{name}.pt", out=tmp_path / "levels.pt"))
        with pytest.raises(SystemExit, match="not a record of this recipe"):
            recipe.load(tmp_path / f"{name}.pt", edge)
    assert not (tmp_path / "levels.pt").exists()


def test_load_refuses_a_package_file_of_another_trunk(tmp_path: Path) -> None:
    edge = load_model()
    record = torch.load(weights_path(None, LEVEL_WEIGHTS), map_location="cpu", weights_only=True)
    key = next(iter(record["state"]))
    record["state"][key] = record["state"][key] + 1
    torch.save(record, tmp_path / "levels.pt")
    with pytest.raises(SystemExit, match="its trunk is not the edge network in use"):
        recipe.load(tmp_path / "levels.pt", edge)
