"""The research scripts that run the shipped networks, end to end on one small generated scene (no dev scenes needed):
they run on the package's public names and print their reports."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from research import learned_confidence, level_errors
from torch_modulo import protocols
from torch_modulo.io import write_image


@pytest.fixture
def scenes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A scenes folder with one training scene (a textured ramp and a lamp 800 times brighter), as the dev scenes."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:64, 0:96].astype(np.float64)
    img = 0.05 + 0.3 * x / 96 + 0.05 * rng.random((64, 96)) + 40.0 * ((y - 20) ** 2 + (x - 60) ** 2 < 80)
    path = tmp_path / "polyhaven-cc0" / "lamp.exr"
    path.parent.mkdir()
    write_image(path, torch.from_numpy(np.stack([img, 0.8 * img, 1.1 * img])).float())
    monkeypatch.setattr(protocols, "DEV_SCENES", tmp_path)
    threads = torch.get_num_threads()
    yield tmp_path
    torch.set_num_threads(threads)  # the scripts set their own


def test_learned_confidence_reports_both_maps(scenes: Path, capsys: pytest.CaptureFixture[str]) -> None:
    learned_confidence.main(["--split", "train", "--scale", "96"])
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("train, all (2 scene-protocol pairs): ROC AUC learned_confidence 0.")
    assert lines[1].startswith("train, under 10% wrong (2 scene-protocol pairs)")


def test_level_errors_reports_a_plane(scenes: Path, capsys: pytest.CaptureFixture[str]) -> None:
    level_errors.main(["--split", "train", "--protocols", "A", "--threads", "1"])
    summary, by_level = capsys.readouterr().out.splitlines()
    assert summary.startswith("A (1 scenes): exact-k ") and "the truth costs more than the result on" in summary
    right = float(summary.split("exact-k ")[1].split(",")[0])
    assert 90 < right < 100  # the ramp is right, the lamp (4% of the values, 15 periods up) is not
    assert by_level.startswith("A by true k (all planes pooled") and "clipped at the peak" in by_level
