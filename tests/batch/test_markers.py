"""Tests of torch_modulo/batch/markers.py: done markers decide what a rerun skips; a marker that cannot be written
fails its input."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from typing import Any

import pytest
from fakes import changing_job, fill_disk, quiet, upper_job
from fakes import make_inputs as _make_inputs
from fakes import names as _names
from fakes import run as _run

from torch_modulo.batch import MARKER_FOLDER, Task, run_batch
from torch_modulo.batch.markers import fingerprint, source_state


def filling_job(task: Task, options: dict[str, Any]) -> None:
    """Writes its output, then fills the disk, so that the done marker cannot be written."""
    upper_job(task, options)
    fill_disk(Path(options["disk"]))


class TestResume:
    def test_rerun_skips_complete_and_retries_failed(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "bad", "c.txt": "gamma"})
        _run(tasks, tmp_path)
        mtime = (tmp_path / "out" / "a.txt").stat().st_mtime_ns
        (tmp_path / "in" / "b.txt").write_text("fixed")
        again = _run(tasks, tmp_path)
        assert _names(again.skipped) == ["a.txt", "c.txt"]
        assert _names(again.done) == ["b.txt"] and not again.failed
        assert (tmp_path / "out" / "a.txt").stat().st_mtime_ns == mtime  # not rewritten
        assert (tmp_path / "out" / "b.txt").read_text() == "FIXED"

    def test_what_makes_an_output_incomplete(self, tmp_path: Path) -> None:
        names = {f"{c}.txt": c for c in "abcdef"}
        tasks = _make_inputs(tmp_path, names)
        _run(tasks, tmp_path)
        out, markers = tmp_path / "out", tmp_path / "out" / MARKER_FOLDER / "upper"
        (out / "a.txt").unlink()  # output deleted
        (markers / "b.txt.json").unlink()  # crashed before the marker
        (markers / "c.txt.json").write_text("{not json")  # damaged marker
        (tmp_path / "in" / "d.txt").write_text("changed input")  # input changed
        again = _run(tasks, tmp_path)
        assert _names(again.done) == ["a.txt", "b.txt", "c.txt", "d.txt"]
        assert _names(again.skipped) == ["e.txt", "f.txt"]
        assert (out / "d.txt").read_text() == "CHANGED INPUT"

    def test_input_changed_during_the_job_is_redone(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        assert _names(_run(tasks, tmp_path, job=changing_job).done) == ["a.txt"]
        again = _run(tasks, tmp_path)
        assert _names(again.done) == ["a.txt"]
        assert (tmp_path / "out" / "a.txt").read_text() == "ALPHA AND MORE"

    def test_changed_options_or_force_redo_everything(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "beta"})
        _run(tasks, tmp_path)
        changed = _run(tasks, tmp_path, options={"suffix": "!"})
        assert _names(changed.done) == ["a.txt", "b.txt"]
        assert (tmp_path / "out" / "a.txt").read_text() == "ALPHA!"
        assert _names(_run(tasks, tmp_path, options={"suffix": "!"}).skipped) == ["a.txt", "b.txt"]
        forced = _run(tasks, tmp_path, options={"suffix": "!"}, force=True)
        assert _names(forced.done) == ["a.txt", "b.txt"]

    def test_fingerprint_ignores_private_options(self) -> None:
        assert fingerprint("c", {"a": 1, "_workers": 2}) == fingerprint("c", {"a": 1})
        assert fingerprint("c", {"a": 1}) != fingerprint("c", {"a": 2}) != fingerprint("d", {"a": 2})

    def test_source_state_of_a_folder_skips_hidden_files(self, tmp_path: Path) -> None:
        (tmp_path / "s").mkdir()
        (tmp_path / "s" / "b.exr").write_text("bb")
        (tmp_path / "s" / "a.exr").write_text("a")
        state = source_state(tmp_path / "s")
        (tmp_path / "s" / ".a.1-ff.tmp.exr").write_text("half")
        assert source_state(tmp_path / "s") == state
        assert [entry[:2] for entry in state] == [["a.exr", 1], ["b.exr", 2]]


class TestFullDisk:
    def test_full_disk_while_writing_a_done_marker_fails_that_input(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "beta"})
        real = Path.write_text

        def full_for_markers(self: Path, *args: Any, **kwargs: Any) -> int:
            if MARKER_FOLDER in self.parts and self.name.startswith(".b.txt"):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
            return real(self, *args, **kwargs)

        monkeypatch.setattr(Path, "write_text", full_for_markers)
        report = _run(tasks, tmp_path)
        marker = tmp_path / "out" / MARKER_FOLDER / "upper" / "b.txt.json"
        assert _names(report.done) == ["a.txt"] and _names(report.failed) == ["b.txt"]
        error = report.failed[0]["error"]
        assert error.startswith(f"OSError: [Errno 28] No space left on device: '{marker}'"), error
        assert ".tmp" not in error
        assert report.exit_code == 1
        assert json.loads((tmp_path / "out" / "upper-report.json").read_text())["counts"]["failed"] == 1
        monkeypatch.undo()
        assert _names(_run(tasks, tmp_path).done) == ["b.txt"]  # no marker: the rerun redoes it

    def test_full_tmpfs_while_writing_a_done_marker(self, tmp_path: Path, small_disk: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        out = small_disk / "out"
        tasks = [Task(t.name, t.source, (str(out / t.name),)) for t in tasks]
        report = run_batch(
            "upper",
            tasks,
            filling_job,
            {"disk": str(small_disk)},
            out,
            input_path=tmp_path / "in",
            workers=1,
            progress=False,
            log=quiet,
            report_path=tmp_path / "r.json",
        )
        assert _names(report.failed) == ["a.txt"]
        marker = out / MARKER_FOLDER / "upper" / "a.txt.json"
        assert f"No space left on device: '{marker}'" in report.failed[0]["error"]
        assert json.loads((tmp_path / "r.json").read_text())["failed"][0]["input"] == "a.txt"
        assert not list((out / MARKER_FOLDER / "upper").iterdir())  # no temporary left behind
