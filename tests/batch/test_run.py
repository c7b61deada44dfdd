"""Tests of torch_modulo/batch/run.py: run_batch from plan to report, with small text-file jobs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from fakes import lazy_job, upper_job
from fakes import make_inputs as _make_inputs
from fakes import names as _names
from fakes import run as _run

from torch_modulo.batch import MARKER_FOLDER, BatchError, Task


def warning_job(task: Task, options: dict) -> dict:
    """upper_job, plus a warning in its info."""
    upper_job(task, options)
    return {"warnings": ["replaced 2 values"]}


class TestRunBatch:
    def test_inputs_are_never_modified(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "bad"})
        before = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in (tmp_path / "in").rglob("*")}
        _run(tasks, tmp_path)
        assert {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in (tmp_path / "in").rglob("*")} == before

    def test_one_bad_input_is_reported_and_the_rest_finish(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "this is bad", "c.txt": "gamma"})
        report = _run(tasks, tmp_path)
        assert _names(report.done) == ["a.txt", "c.txt"]
        assert _names(report.failed) == ["b.txt"]
        assert report.failed[0]["error"].startswith("ValueError: cannot process ")
        assert "b.txt" in report.failed[0]["error"]
        assert report.exit_code == 1
        assert not (tmp_path / "out" / "b.txt").exists()

    def test_job_that_writes_nothing_fails(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        report = _run(tasks, tmp_path, job=lazy_job)
        assert report.failed[0]["error"].startswith("RuntimeError: the job finished without writing ")
        assert not (tmp_path / "out" / MARKER_FOLDER / "upper" / "a.txt.json").exists()

    def test_outputs_claimed_twice(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "beta"})
        clash = [tasks[0], Task("b.txt", tasks[1].source, tasks[0].outputs)]
        report = _run(clash, tmp_path)
        assert _names(report.done) == ["a.txt"]
        assert "is also the output of a.txt" in report.failed[0]["error"]
        assert (tmp_path / "out" / "a.txt").read_text() == "ALPHA"

    def test_outputs_inside_the_input_are_refused(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "beta"})
        inside = [
            tasks[0],
            Task("b.txt", tasks[1].source, (str(tmp_path / "in" / "B.txt"),)),
            Task("a2", tasks[0].source, (tasks[0].source,)),
        ]
        report = _run(inside, tmp_path)
        assert _names(report.done) == ["a.txt"]
        assert all("inputs are never written" in e["error"] for e in report.failed)
        assert sorted(p.name for p in (tmp_path / "in").iterdir()) == ["a.txt", "b.txt"]
        assert (tmp_path / "in" / "a.txt").read_text() == "alpha"

    def test_interrupt_keeps_completed_outputs_and_resumes(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {f"{c}.txt": c for c in "abcde"})
        (tmp_path / "flag").touch()
        options = {"interrupt_on": "c.txt", "interrupt_flag": str(tmp_path / "flag")}
        report = _run(tasks, tmp_path, options=options)
        assert report.interrupted and report.exit_code == 130
        assert _names(report.done) == ["a.txt", "b.txt"]
        assert report.not_finished == ["c.txt", "d.txt", "e.txt"]
        saved = json.loads((tmp_path / "out" / "upper-report.json").read_text())
        assert saved["interrupted"] and saved["not_finished"] == ["c.txt", "d.txt", "e.txt"]
        assert sorted(p.name for p in (tmp_path / "out").glob("*.txt")) == ["a.txt", "b.txt"]
        resumed = _run(tasks, tmp_path, options=options)
        assert _names(resumed.skipped) == ["a.txt", "b.txt"]
        assert _names(resumed.done) == ["c.txt", "d.txt", "e.txt"]

    def test_bad_arguments(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        with pytest.raises(BatchError, match="engine must be one of .*got 'dask'"):
            _run(tasks, tmp_path, engine="dask")
        with pytest.raises(ValueError, match="workers must be an int >= 1 or None; got 0"):
            _run(tasks, tmp_path, workers=0)
        with pytest.raises(ValueError, match="Task 'x' must have at least one output"):
            Task("x", "a", ())

    def test_report_inside_the_input_is_refused(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        with pytest.raises(BatchError, match="inside the input folder"):
            _run(tasks, tmp_path, report_path=tmp_path / "in" / "report.json")
        assert sorted(p.name for p in (tmp_path / "in").iterdir()) == ["a.txt"]

    def test_workers_must_be_an_int(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        with pytest.raises(TypeError, match="workers must be an integer; got '2'"):
            _run(tasks, tmp_path, workers="2")
        with pytest.raises(TypeError, match="workers must be an integer; got True"):
            _run(tasks, tmp_path, workers=True)

    def test_job_warnings_are_logged_and_reported(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        messages: list[str] = []
        report = _run(tasks, tmp_path, job=warning_job, log=messages.append)
        assert report.done[0]["warnings"] == ["replaced 2 values"]
        assert "upper: a.txt: replaced 2 values" in messages
        data = json.loads((tmp_path / "out" / "upper-report.json").read_text())
        assert data["done"][0]["warnings"] == ["replaced 2 values"]
