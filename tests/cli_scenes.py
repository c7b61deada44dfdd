"""Scenes and helpers shared by the command line's tests (test_cli.py: options, messages and exit codes;
test_end_to_end.py: the folder commands on small generated scenes)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch

from torch_modulo.cli import main
from torch_modulo.io import write_image

__all__ = ["ROOT", "names", "read_report", "run_cli", "scene", "write_scenes"]

ROOT = Path(__file__).resolve().parent.parent


def scene(seed: int, h: int = 12, w: int = 16, channels: int = 3) -> torch.Tensor:
    """A small HDR scene spanning about 16 stops: a smooth exponential ramp times a random colour, plus texture."""
    g = torch.Generator().manual_seed(seed)
    y = torch.linspace(0, 1, h).view(h, 1)
    x = torch.linspace(0, 1, w).view(1, w)
    ramp = torch.exp2(16 * (0.6 * x + 0.4 * y) - 4)  # 1/16 .. 4096
    colour = 0.5 + torch.rand(channels, 1, 1, generator=g)
    texture = 1 + 0.1 * torch.rand(channels, h, w, generator=g)
    return (ramp * colour * texture).float()


def write_scenes(folder: Path) -> Path:
    """``folder`` with three scenes: a.exr, b.hdr (RGBE) and sub/c.exr (a small negative value, as lossy files
    have), and a text file the commands ignore."""
    (folder / "sub").mkdir(parents=True)
    write_image(folder / "a.exr", scene(1))
    write_image(folder / "b.hdr", scene(2))
    c = scene(3)
    c[0, 0, 0] = -0.01
    write_image(folder / "sub" / "c.exr", c)
    (folder / "notes.txt").write_text("not an image: ignored")
    return folder


def run_cli(*args: Any) -> int:
    """``torch-modulo ARGS --no-progress``; the exit code."""
    return main([str(a) for a in args] + ["--no-progress"])


def read_report(out: Path, command: str) -> dict[str, Any]:
    return json.loads((out / f"{command}-report.json").read_text())


def names(entries: list[dict[str, Any]]) -> list[str]:
    return [e["input"] for e in entries]
