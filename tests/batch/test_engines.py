"""Tests of torch_modulo/batch/engines.py: inline, process pool and Ray engines, Ctrl-C (also while the pool
starts), and the error text of a failed job."""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import pytest
from fakes import fake_ray as _fake_ray
from fakes import fill_disk
from fakes import make_inputs as _make_inputs
from fakes import names as _names
from fakes import run as _run

from torch_modulo.batch import BatchError, Task, default_workers, engines, run_batch

FAKES = Path(__file__).resolve().parent


def exr_job(task: Task, options: dict[str, Any]) -> None:
    """Writes a small EXR with torch_modulo.io.write_image (temporary file, then rename)."""
    import torch

    from torch_modulo.io import write_image

    write_image(task.outputs[0], torch.rand(3, 64, 64) * 100)


def temporary_error_job(task: Task, options: dict[str, Any]) -> None:
    """Fails the way an image library does: naming the hidden temporary file, without the system's reason."""
    out = Path(task.outputs[0])
    raise OSError(f'cannot write {out}: Failed to write pixel data to "{out.parent}/.{out.stem}.123-0f3c9a1b.tmp.exr"')


class StartUpInterrupted:
    """A process pool whose start-up a Ctrl-C cuts short: the fork server dies and the parent reads end-of-file."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        pass

    def submit(self, *args: Any, **kwargs: Any) -> Any:
        os.kill(os.getpid(), signal.SIGINT)  # the Ctrl-C reaches the parent's handler too
        time.sleep(0.05)
        raise EOFError

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        pass


class BrokenStart(StartUpInterrupted):
    def submit(self, *args: Any, **kwargs: Any) -> Any:
        raise EOFError


class TestProcessPool:
    def test_process_pool_matches_inline(self, tmp_path: Path) -> None:
        texts = {f"f{i}.txt": f"text {i}" + (" bad" if i == 3 else "") for i in range(6)}
        tasks = _make_inputs(tmp_path, texts)
        report = _run(tasks, tmp_path, workers=2)
        assert _names(report.done) == [f"f{i}.txt" for i in range(6) if i != 3]
        assert _names(report.failed) == ["f3.txt"]
        pids = {e["pid"] for e in report.done}
        assert os.getpid() not in pids  # ran in worker processes
        assert {e["threads"] for e in report.done} == {1}  # no oversubscription
        for task in tasks:
            if "bad" not in Path(task.source).read_text():
                assert Path(task.outputs[0]).read_text() == Path(task.source).read_text().upper()

    def test_process_pool_ctrl_c(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {f"f{i:02d}.txt": f"text {i}" for i in range(40)})
        # The job of f05 sends SIGINT to this process, as Ctrl-C in a terminal would.
        (tmp_path / "flag").touch()
        options = {"interrupt_on": "f05.txt", "interrupt_flag": str(tmp_path / "flag"), "signal_pid": os.getpid()}
        report = _run(tasks, tmp_path, workers=2, options=options)
        assert report.interrupted and report.exit_code == 130
        done, nf = _names(report.done), report.not_finished
        assert "f05.txt" in done and nf and not report.failed
        assert sorted(done + nf) == [t.name for t in tasks]  # every task accounted for exactly once
        assert sorted(p.name for p in (tmp_path / "out").glob("*.txt")) == sorted(done)
        resumed = _run(tasks, tmp_path, workers=2, options=options)
        assert _names(resumed.done) == sorted(nf) and _names(resumed.skipped) == sorted(done)

    def test_unpicklable_job_with_workers(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "beta"})
        with pytest.raises(BatchError, match="define it at module level"):
            _run(tasks, tmp_path, job=lambda task, options: None, workers=2)

    def test_progress_bar_only_when_asked_or_on_a_terminal(
        self, tmp_path: Path, capsys: pytest.CaptureFixture[str]
    ) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "beta"})
        _run(tasks, tmp_path, progress=None, force=True)  # stderr is not a terminal under pytest: quiet
        assert "upper" not in capsys.readouterr().err
        _run(tasks, tmp_path, progress=True, force=True)
        err = capsys.readouterr().err
        assert "upper: 100%" in err and "2/2" in err

    def test_default_workers_are_the_cores(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        assert _run(tasks, tmp_path, workers=None).workers == default_workers()

    def test_default_workers_shares_the_cores(self) -> None:
        cores = default_workers(1)
        assert cores >= 1
        assert default_workers(cores * 4) == 1
        assert default_workers(2) == max(1, cores // 2)


class TestCtrlCWhileThePoolStarts:
    def test_ctrl_c_during_pool_start_up_exits_130_with_a_report(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        monkeypatch.setattr(engines, "ProcessPoolExecutor", StartUpInterrupted)
        monkeypatch.setattr(engines, "_pool_context", lambda preload: None)
        tasks = _make_inputs(tmp_path, {f"f{i}.txt": f"text {i}" for i in range(4)})
        report = _run(tasks, tmp_path, workers=2)
        assert report.interrupted and report.exit_code == 130
        assert report.not_finished == [t.name for t in tasks] and not report.done and not report.failed
        saved = json.loads((tmp_path / "out" / "upper-report.json").read_text())
        assert saved["interrupted"] and saved["counts"]["not_finished"] == 4
        assert _names(_run(tasks, tmp_path).done) == [t.name for t in tasks]  # and the rerun resumes

    def test_a_pool_that_cannot_start_without_ctrl_c_is_an_error(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        monkeypatch.setattr(engines, "ProcessPoolExecutor", BrokenStart)
        monkeypatch.setattr(engines, "_pool_context", lambda preload: None)
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "beta"})
        with pytest.raises(EOFError):
            _run(tasks, tmp_path, workers=2)

    @pytest.mark.skipif("forkserver" not in multiprocessing.get_all_start_methods(), reason="no forkserver")
    def test_the_fork_server_starts_ignoring_ctrl_c(self, monkeypatch: pytest.MonkeyPatch) -> None:
        from multiprocessing import forkserver

        seen: list[Any] = []
        monkeypatch.setattr(forkserver, "ensure_running", lambda: seen.append(signal.getsignal(signal.SIGINT)))
        before = signal.getsignal(signal.SIGINT)
        engines._pool_context(())
        assert seen == [signal.SIG_IGN]
        assert signal.getsignal(signal.SIGINT) is before

    @pytest.mark.slow
    def test_ctrl_c_in_a_terminal_while_the_pool_starts(self, tmp_path: Path) -> None:
        """A real Ctrl-C (SIGINT to the whole process group) while the fork server imports its modules."""
        (tmp_path / "slow_preload.py").write_text(
            "import os, pathlib, time\npathlib.Path(os.environ['PRELOAD_FLAG']).touch()\ntime.sleep(3)\n"
        )
        script = textwrap.dedent(
            f"""
            import sys
            from pathlib import Path
            sys.path[:0] = [{str(FAKES)!r}, {str(tmp_path)!r}]
            from fakes import make_inputs, upper_job
            from torch_modulo.batch import run_batch
            tasks = make_inputs(Path({str(tmp_path)!r}), {{f"f{{i}}.txt": "text" for i in range(6)}})
            report = run_batch("upper", tasks, upper_job, {{}}, Path({str(tmp_path)!r}) / "out", workers=2,
                               progress=False, preload=("slow_preload",))
            sys.exit(report.exit_code)
            """
        )
        flag = tmp_path / "flag"
        # The fork server imports its modules from the default path (it does not take the parent's sys.path).
        path = os.pathsep.join(p for p in (str(tmp_path), os.environ.get("PYTHONPATH", "")) if p)
        env = {**os.environ, "PRELOAD_FLAG": str(flag), "PYTHONPATH": path}
        process = subprocess.Popen(
            [sys.executable, "-c", script], stderr=subprocess.PIPE, text=True, env=env, start_new_session=True
        )
        deadline = time.monotonic() + 60
        while not flag.exists() and time.monotonic() < deadline and process.poll() is None:
            time.sleep(0.02)
        assert flag.exists(), "the fork server never imported its modules"
        os.killpg(process.pid, signal.SIGINT)
        _, stderr = process.communicate(timeout=60)
        assert process.returncode == 130, stderr
        assert "Traceback" not in stderr and "EOFError" not in stderr
        report = json.loads((tmp_path / "out" / "upper-report.json").read_text())
        assert report["interrupted"]
        assert sorted(_names(report["done"]) + report["not_finished"]) == [f"f{i}.txt" for i in range(6)]


class TestJobErrors:
    def test_job_errors_name_final_paths(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        report = _run(tasks, tmp_path, job=temporary_error_job)
        error = report.failed[0]["error"]
        out = tmp_path / "out"
        assert error == f'OSError: cannot write {out}/a.txt: Failed to write pixel data to "{out}/a.exr"'

    def test_full_disk_while_a_job_writes_an_image(self, tmp_path: Path, small_disk: Path) -> None:
        (tmp_path / "in").mkdir()
        (tmp_path / "in" / "a.txt").write_text("alpha")
        fill_disk(small_disk)
        task = Task("a.txt", str(tmp_path / "in" / "a.txt"), (str(small_disk / "a.exr"),))
        report = run_batch(
            "exr",
            [task],
            exr_job,
            {},
            small_disk,
            workers=1,
            progress=False,
            log=lambda m: None,
            report_path=tmp_path / "report.json",
        )
        error = report.failed[0]["error"]
        assert error.startswith(f"OSError: cannot write {small_disk / 'a.exr'}") and ".tmp" not in error
        assert "No space left on device" in error
        assert not [p for p in small_disk.iterdir() if p.name != "filler.bin"]


class TestRayEngine:
    def test_missing_ray_says_how_to_install(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        with pytest.raises(BatchError, match=r"pip install 'torch_modulo\[ray\]'"):
            _run(tasks, tmp_path, engine="ray")
        assert not (tmp_path / "out" / "a.txt").exists()

    def test_ray_engine_runs_every_task_as_a_ray_task(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        calls: list[str] = []
        monkeypatch.setitem(sys.modules, "ray", _fake_ray(calls))
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "bad", "c.txt": "gamma", "d.txt": "delta"})
        report = _run(tasks, tmp_path, engine="ray", workers=None, ray_address="auto")
        assert _names(report.done) == ["a.txt", "c.txt", "d.txt"] and _names(report.failed) == ["b.txt"]
        assert (tmp_path / "out" / "c.txt").read_text() == "GAMMA"
        assert calls[0] == "init:auto" and calls[-1] == "shutdown"
        assert "remote:[('max_retries', 0), ('num_cpus', 1)]" in calls
        assert calls.count("submit") == 4
        # at most the cluster's 3 CPUs in flight
        assert max(int(c.split(":")[1]) for c in calls if c.startswith("wait:")) == 3
        assert report.engine == "ray" and report.workers == 3

    def test_ray_engine_refuses_torchrun(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        monkeypatch.setitem(sys.modules, "ray", _fake_ray([]))
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        with pytest.raises(BatchError, match="do not combine it with torchrun"):
            _run(tasks, tmp_path, engine="ray", environ={"RANK": "0", "WORLD_SIZE": "2"})
