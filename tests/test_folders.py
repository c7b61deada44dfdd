"""Tests of torch_modulo/folders.py: the tasks each folder command finds in a folder, and what a task weighs."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from torch_modulo._task import Task
from torch_modulo.folders import count_values, folder_tasks
from torch_modulo.io import write_image


def _write(path: Path, image: torch.Tensor) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, image, normalized=False if path.suffix == ".png" else None)
    return path


class TestTasks:
    @pytest.fixture
    def folder(self, tmp_path: Path) -> Path:
        for name in ("a.exr", "sub/b.hdr", "notes.txt", "m.png"):
            _write(tmp_path / "in" / name, torch.ones(3, 4, 6)) if name != "notes.txt" else None
        (tmp_path / "in" / "notes.txt").write_text("x")
        (tmp_path / "in" / "stack").mkdir()
        (tmp_path / "in" / "stack" / "frames.json").write_text("{}")
        return tmp_path

    def test_folder_tasks(self, folder: Path) -> None:
        source, out = folder / "in", folder / "out"
        tasks, wanted = folder_tasks("tonemap", source, out)
        assert [(t.name, t.outputs) for t in tasks] == [
            ("a.exr", (str(out / "a.png"),)),
            ("sub/b.hdr", (str(out / "sub" / "b.png"),)),
        ]
        assert wanted.startswith("radiance files (.exr")
        tasks, _ = folder_tasks("simulate", source, out)
        assert [t.outputs for t in tasks] == [(str(out / "a"),), (str(out / "sub" / "b"),)]
        tasks, wanted = folder_tasks("unwrap", source, out, single=True, confidence=True)
        # single shot: modulus images and frame stacks (as simulate writes single-shot stacks), not the files inside
        assert [t.name for t in tasks] == ["a.exr", "m.png", "stack"]
        assert tasks[1].outputs == (str(out / "m.exr"), str(out / "m.confidence.exr"))
        assert tasks[2].outputs == (str(out / "stack.exr"), str(out / "stack.confidence.exr"))
        assert wanted.startswith("frame stacks or modulus images (")
        tasks, wanted = folder_tasks("unwrap", source, out)
        assert [(t.name, t.outputs) for t in tasks] == [("stack", (str(out / "stack.exr"),))]
        assert wanted == "frame stacks (folders with a frames.json manifest)"

    def test_count_values_weighs_by_pixels_not_bytes(self, folder: Path) -> None:
        assert count_values(Task("a.exr", str(folder / "in" / "a.exr"), ("o",))) == 3 * 4 * 6
        _write(folder / "in" / "stack" / "f0.exr", torch.zeros(1, 10, 10))
        _write(folder / "in" / "stack" / "f1.png", torch.zeros(1, 10, 10))
        assert count_values(Task("stack", str(folder / "in" / "stack"), ("o",))) == 200
        (folder / "in" / "broken.exr").write_bytes(b"nope")
        assert count_values(Task("broken.exr", str(folder / "in" / "broken.exr"), ("o",))) == 0

    def test_each_input_once_and_broken_links_kept(self, folder: Path) -> None:
        source = folder / "in"
        (source / "sub" / "loop").symlink_to(source)  # the input folder inside itself
        (source / "also_a.exr").symlink_to(source / "a.exr")  # a second name for one file
        (source / "gone.exr").symlink_to(folder / "nowhere.exr")  # its job fails naming it
        tasks, _ = folder_tasks("tonemap", source, folder / "out")
        assert [t.name for t in tasks] == ["a.exr", "gone.exr", "sub/b.hdr"]
