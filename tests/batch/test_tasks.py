"""Tests of torch_modulo/batch/tasks.py: finding inputs (symbolic links included), checking the folders. The Task
itself is tested in tests/test_task.py."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from fakes import make_inputs as _make_inputs
from fakes import names as _names
from fakes import run as _run

from torch_modulo.batch import BatchError, check_folders, discover


class TestDiscover:
    def test_sorted_recursive_and_hidden_skipped(self, tmp_path: Path) -> None:
        for name in ("b.exr", "a.EXR", "c.txt", ".tmp.exr", ".hidden/d.exr", "sub/z.exr", "sub/deeper/y.exr"):
            (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / name).write_text("x")
        found = discover(tmp_path, lambda p: p.is_file() and p.suffix.lower() == ".exr")
        assert [name for name, _ in found] == ["a.EXR", "b.exr", "sub/deeper/y.exr", "sub/z.exr"]
        assert all(path == tmp_path / name for name, path in found)

    def test_matched_folders_are_not_entered(self, tmp_path: Path) -> None:
        for name in ("s1/frames.json", "s1/inner/frames.json", "group/s2/frames.json", "empty/x.txt"):
            (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / name).write_text("{}")
        found = discover(tmp_path, lambda p: p.is_dir() and (p / "frames.json").is_file())
        assert [name for name, _ in found] == ["group/s2", "s1"]

    def test_root_file_is_the_only_input(self, tmp_path: Path) -> None:
        (tmp_path / "one.exr").write_text("x")
        assert discover(tmp_path / "one.exr", lambda p: False) == [("one.exr", tmp_path / "one.exr")]

    def test_missing_root(self, tmp_path: Path) -> None:
        with pytest.raises(FileNotFoundError, match="nope"):
            discover(tmp_path / "nope", lambda p: True)

    def test_symlink_loop_in_the_input_takes_each_file_once(self, tmp_path: Path) -> None:
        for name in ("a.exr", "sub/b.exr", "sub/deeper/c.exr"):
            (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / name).write_text("x")
        os.symlink(tmp_path, tmp_path / "sub" / "deeper" / "loop")  # back to the top
        os.symlink("..", tmp_path / "sub" / "up")  # one level up
        os.symlink("sub", tmp_path / "again")  # a second name for a folder
        found = discover(tmp_path, lambda p: p.is_file() and p.suffix == ".exr")
        assert [name for name, _ in found] == ["a.exr", "sub/b.exr", "sub/deeper/c.exr"]

    def test_a_file_reached_by_several_names_is_listed_under_its_real_name(self, tmp_path: Path) -> None:
        (tmp_path / "z").mkdir()
        (tmp_path / "z" / "scene.exr").write_text("x")
        os.symlink(tmp_path / "z" / "scene.exr", tmp_path / "a_link.exr")
        os.symlink(tmp_path / "z", tmp_path / "b_linked_folder")
        (tmp_path / "stack").mkdir()
        (tmp_path / "stack" / "frames.json").write_text("{}")
        os.symlink(tmp_path / "stack", tmp_path / "a_stack_link")
        found = discover(tmp_path, lambda p: p.is_file() and p.suffix == ".exr")
        assert [name for name, _ in found] == ["z/scene.exr"]
        stacks = discover(tmp_path, lambda p: p.is_dir() and (p / "frames.json").is_file())
        assert [name for name, _ in stacks] == ["stack"]

    def test_links_to_files_and_folders_elsewhere_are_followed(self, tmp_path: Path) -> None:
        (tmp_path / "elsewhere" / "deep").mkdir(parents=True)
        (tmp_path / "elsewhere" / "deep" / "far.exr").write_text("x")
        (tmp_path / "elsewhere" / "one.exr").write_text("x")
        (tmp_path / "in").mkdir()
        os.symlink(tmp_path / "elsewhere" / "deep", tmp_path / "in" / "linked")
        os.symlink(tmp_path / "elsewhere" / "one.exr", tmp_path / "in" / "one.exr")
        os.symlink(tmp_path / "missing.exr", tmp_path / "in" / "broken.exr")  # a broken link: no input
        found = discover(tmp_path / "in", lambda p: p.is_file() and p.suffix == ".exr")
        assert [name for name, _ in found] == ["linked/far.exr", "one.exr"]

    def test_batch_over_a_symlink_loop_processes_each_input_once(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "sub/b.txt": "beta"})
        os.symlink(tmp_path / "in", tmp_path / "in" / "sub" / "loop")
        found = discover(tmp_path / "in", lambda p: p.is_file() and p.suffix == ".txt")
        assert [name for name, _ in found] == [t.name for t in tasks]
        report = _run(tasks, tmp_path)
        assert _names(report.done) == ["a.txt", "sub/b.txt"]
        assert sorted(p.relative_to(tmp_path / "out").as_posix() for p in (tmp_path / "out").rglob("*.txt")) == [
            "a.txt",
            "sub/b.txt",
        ]


class TestCheckFolders:
    def test_sibling_output_is_fine(self, tmp_path: Path) -> None:
        (tmp_path / "in").mkdir()
        source, out = check_folders(tmp_path / "in", tmp_path / "out")
        assert source == (tmp_path / "in").resolve() and out == (tmp_path / "out").resolve()

    @pytest.mark.parametrize("out", [".", "sub", "sub/deeper"])
    def test_output_in_input_is_refused(self, tmp_path: Path, out: str) -> None:
        (tmp_path / "in").mkdir()
        with pytest.raises(BatchError, match="input folder"):
            check_folders(tmp_path / "in", tmp_path / "in" / out)

    def test_missing_input(self, tmp_path: Path) -> None:
        with pytest.raises(BatchError, match="input not found: .*missing"):
            check_folders(tmp_path / "missing", tmp_path / "out")

    def test_output_is_a_file(self, tmp_path: Path) -> None:
        (tmp_path / "in").mkdir()
        (tmp_path / "out").write_text("x")
        with pytest.raises(BatchError, match="not a folder"):
            check_folders(tmp_path / "in", tmp_path / "out")
