"""Tests of torch_modulo/batch/report.py: the JSON report, merging the ranks' parts, and a report that cannot be
written."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from typing import Any

import pytest
from fakes import fill_disk
from fakes import make_inputs as _make_inputs
from fakes import names as _names
from fakes import run as _run

from torch_modulo.batch import MARKER_FOLDER, BatchReport, merge_reports


class TestReport:
    def test_smoke_and_report(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "sub/b.txt": "beta"})
        report = _run(tasks, tmp_path)
        assert report.exit_code == 0
        assert _names(report.done) == ["a.txt", "sub/b.txt"]
        assert (tmp_path / "out" / "sub" / "b.txt").read_text() == "BETA"
        data = json.loads((tmp_path / "out" / "upper-report.json").read_text())
        assert data["counts"] == {"total": 2, "done": 2, "skipped": 0, "failed": 0, "not_finished": 0}
        assert data["done"][1]["outputs"] == ["sub/b.txt"] and data["done"][1]["seconds"] >= 0
        assert (tmp_path / "out" / MARKER_FOLDER / "upper" / "sub" / "b.txt.json").is_file()

    def test_merge_reports(self) -> None:
        parts = [BatchReport("c", "i", "o", {}, rank=r, world_size=2, total=t) for r, t in ((1, 1), (0, 2))]
        parts[0].done.append({"input": "b"})
        parts[1].done.append({"input": "a"})
        parts[1].failed.append({"input": "c", "error": "E"})
        merged = merge_reports(parts)
        assert _names(merged.done) == ["a", "b"] and merged.total == 3 and merged.parts == [0, 1]
        assert merged.exit_code == 1

    def test_errors_appear_only_when_there_are_some(self) -> None:
        report = BatchReport("c", "i", "o", {}, total=0)
        assert "errors" not in report.to_dict() and report.exit_code == 0
        report.errors.append("the report could not be written")
        assert report.to_dict()["errors"] == ["the report could not be written"] and report.exit_code == 1
        assert BatchReport.from_dict(report.to_dict()).errors == report.errors
        assert report.summary().endswith("; the report could not be written")


class TestFullDisk:
    def test_full_disk_while_writing_the_report_says_so_and_exits_1(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        real = Path.write_text

        def full_for_reports(self: Path, *args: Any, **kwargs: Any) -> int:
            if self.name.startswith(".upper-report.json"):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))
            return real(self, *args, **kwargs)

        monkeypatch.setattr(Path, "write_text", full_for_reports)
        messages: list[str] = []
        report = _run(tasks, tmp_path, log=messages.append)
        target = tmp_path / "out" / "upper-report.json"
        assert _names(report.done) == ["a.txt"] and report.exit_code == 1
        assert report.errors == [
            f"the report could not be written: OSError: [Errno 28] No space left on device: '{target}'"
        ]
        assert any("No space left on device" in m and str(target) in m for m in messages)
        assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [MARKER_FOLDER, "a.txt"]

    def test_full_tmpfs_while_writing_the_report(self, tmp_path: Path, small_disk: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        fill_disk(small_disk)
        report = _run(tasks, tmp_path, report_path=small_disk / "report.json")
        assert _names(report.done) == ["a.txt"] and report.exit_code == 1
        assert f"No space left on device: '{small_disk / 'report.json'}'" in report.errors[0]
        assert sorted(p.name for p in small_disk.iterdir()) == ["filler.bin"]
        assert json.loads((tmp_path / "out" / MARKER_FOLDER / "upper" / "a.txt.json").read_text())["input"] == "a.txt"
