"""Tests of torch_modulo/batch/engines.py when a worker process dies (the OOM killer, a crash in a reader): the
tasks in flight run again one at a time in a new pool, the one that kills its worker again fails, the rest goes on
and the report is written."""

from __future__ import annotations

import json
import os
import signal
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import pytest
from fakes import make_inputs as _make_inputs
from fakes import names as _names
from fakes import run as _run
from fakes import upper_job

from torch_modulo.batch import Task, engines


def killing_job(task: Task, options: dict[str, Any]) -> dict[str, Any]:
    """Kills its own worker process (as the OOM killer would) on inputs that say 'kill', every time or, when the
    option ``once`` names a flag file that exists, only once; otherwise :func:`upper_job`."""
    if "kill" in Path(task.source).read_text():
        flag = Path(options.get("once", "/nonexistent"))
        if "once" not in options or flag.exists():
            flag.unlink(missing_ok=True)
            os.kill(os.getpid(), signal.SIGKILL)
    return upper_job(task, options)


def dying_initializer(threads: int | None) -> None:
    """A pool initializer with which no worker can start."""
    os._exit(1)


TEXTS = {f"f{i:02d}.txt": f"text {i}" + (" kill" if i == 2 else "") for i in range(10)}


class TestWorkerDeath:
    def test_a_task_that_kills_its_worker_fails_and_the_others_go_on(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, TEXTS)
        messages: list[str] = []
        report = _run(tasks, tmp_path, job=killing_job, workers=2, log=messages.append)
        assert _names(report.done) == sorted(n for n in TEXTS if n != "f02.txt")
        assert _names(report.failed) == ["f02.txt"]
        assert "worker process died (killed, or out of memory)" in report.failed[0]["error"]
        assert report.exit_code == 1 and not report.interrupted and not report.not_finished
        assert any("a worker process died" in m and "run again, one at a time" in m for m in messages)
        saved = json.loads((tmp_path / "out" / "upper-report.json").read_text())
        assert saved["counts"]["done"] == 9 and saved["counts"]["failed"] == 1
        for task in tasks:
            if task.name != "f02.txt":
                assert Path(task.outputs[0]).read_text() == Path(task.source).read_text().upper()
        (tmp_path / "in" / "f02.txt").write_text("text 2")  # fixed: the rerun does only that input
        resumed = _run(tasks, tmp_path, job=killing_job, workers=2)
        assert _names(resumed.done) == ["f02.txt"] and len(resumed.skipped) == 9

    def test_a_worker_killed_once_loses_nothing(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, TEXTS)
        (tmp_path / "flag").touch()
        report = _run(tasks, tmp_path, job=killing_job, workers=2, options={"once": str(tmp_path / "flag")})
        assert _names(report.done) == sorted(TEXTS) and not report.failed and report.exit_code == 0
        assert not (tmp_path / "flag").exists()  # the worker did die

    def test_several_tasks_that_kill_their_workers(self, tmp_path: Path) -> None:
        texts = {f"f{i:02d}.txt": f"text {i}" + (" kill" if i in (0, 5, 6, 9) else "") for i in range(12)}
        tasks = _make_inputs(tmp_path, texts)
        report = _run(tasks, tmp_path, job=killing_job, workers=2)
        assert _names(report.failed) == ["f00.txt", "f05.txt", "f06.txt", "f09.txt"]
        assert len(report.done) == 8 and report.exit_code == 1

    def test_the_first_inputs_killing_their_workers_do_not_stop_the_batch(self, tmp_path: Path) -> None:
        texts = {f"f{i:02d}.txt": f"text {i}" + (" kill" if i in (0, 1) else "") for i in range(6)}
        report = _run(_make_inputs(tmp_path, texts), tmp_path, job=killing_job, workers=2)
        assert _names(report.failed) == ["f00.txt", "f01.txt"] and len(report.done) == 4

    def test_a_pool_whose_workers_cannot_start_is_still_an_error(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        monkeypatch.setattr(engines, "_init_worker", dying_initializer)
        tasks = _make_inputs(tmp_path, {f"f{i}.txt": f"text {i}" for i in range(6)})
        with pytest.raises(BrokenProcessPool):
            _run(tasks, tmp_path, workers=2)
