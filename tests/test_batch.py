"""Tests of the batch engine (torch_modulo/batch.py) with small text-file jobs, independent of any image operation."""

from __future__ import annotations

import json
import os
import pickle
import signal
import sys
import time
import types
from pathlib import Path
from typing import Any

import pytest
import torch
from torch.utils.data import DistributedSampler

from torch_modulo.batch import (
    MARKER_FOLDER,
    BatchError,
    BatchReport,
    DistributedEnv,
    Task,
    atomic_output_dir,
    check_folders,
    default_workers,
    discover,
    distributed_env,
    merge_reports,
    run_batch,
    shard,
    write_json,
)

# ----------------------------------------------------------------------------------------- jobs (module level)


def upper_job(task: Task, options: dict[str, Any]) -> dict[str, Any]:
    """Upper-cases the input (plus a suffix option); fails on inputs that say 'bad'."""
    text = Path(task.source).read_text()
    if "bad" in text:
        raise ValueError(f"cannot process {task.source}: it says bad")
    flag = Path(options.get("interrupt_flag", "/nonexistent"))
    if options.get("interrupt_on") == task.name and flag.exists():  # interrupt once: the rerun has the same options
        flag.unlink()
        if options.get("signal_pid"):
            os.kill(options["signal_pid"], signal.SIGINT)
        else:
            raise KeyboardInterrupt
    tmp = Path(task.outputs[0] + ".partial")
    tmp.write_text(text.upper() + options.get("suffix", ""))
    os.replace(tmp, task.outputs[0])
    return {"pid": os.getpid(), "threads": torch.get_num_threads()}


def changing_job(task: Task, options: dict[str, Any]) -> None:
    """Writes its output while someone else rewrites the input (a concurrent writer)."""
    Path(task.outputs[0]).write_text("stale")
    time.sleep(0.01)
    Path(task.source).write_text(Path(task.source).read_text() + " and more")


def lazy_job(task: Task, options: dict[str, Any]) -> None:
    """Claims success without writing its output."""


def _quiet(message: str) -> None:
    pass


def _make_inputs(folder: Path, texts: dict[str, str]) -> list[Task]:
    """Write text inputs under folder/in and return their tasks (outputs under folder/out)."""
    src, out = folder / "in", folder / "out"
    for name, text in texts.items():
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        (src / name).write_text(text)
    return [Task(name, str(src / name), (str(out / name),)) for name in sorted(texts)]


def _run(tasks: list[Task], folder: Path, **kwargs: Any) -> BatchReport:
    kwargs.setdefault("workers", 1)
    kwargs.setdefault("progress", False)
    kwargs.setdefault("log", _quiet)
    options = kwargs.pop("options", {})
    return run_batch(
        "upper", tasks, kwargs.pop("job", upper_job), options, folder / "out", input_path=folder / "in", **kwargs
    )


def _names(entries: list[dict[str, Any]]) -> list[str]:
    return [e["input"] for e in entries]


# ------------------------------------------------------------------------------------------------- discover


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


# ----------------------------------------------------------------------------------------------- sharding


class TestSharding:
    @pytest.mark.parametrize("n", [0, 1, 5, 8, 13])
    @pytest.mark.parametrize("world", [1, 2, 3, 4])
    def test_shard_matches_distributed_sampler(self, n: int, world: int) -> None:
        items = list(range(n))
        shards = [shard(items, r, world) for r in range(world)]
        # every item exactly once
        assert sorted(i for s in shards for i in s) == items
        for r in range(world):
            sampler = list(DistributedSampler(items, num_replicas=world, rank=r, shuffle=False)) if n else []
            # DistributedSampler pads to a multiple of world by repeating the first items; without the padding
            # the shards agree exactly.
            assert shards[r] == [i for k, i in enumerate(sampler) if k * world + r < n]

    def test_bad_rank(self) -> None:
        with pytest.raises(ValueError, match="rank=2"):
            shard([1, 2], 2, 2)

    def test_distributed_env(self) -> None:
        env = distributed_env(
            {
                "RANK": "3",
                "WORLD_SIZE": "4",
                "LOCAL_RANK": "1",
                "LOCAL_WORLD_SIZE": "2",
                "MASTER_ADDR": "h",
                "MASTER_PORT": "1",
            }
        )
        assert env == DistributedEnv(3, 4, 1, 2, True)
        assert distributed_env({"RANK": "1", "WORLD_SIZE": "2"}).local_world_size == 2
        assert distributed_env({}) == DistributedEnv()

    @pytest.mark.parametrize(
        ("environ", "message"),
        [
            ({"RANK": "2", "WORLD_SIZE": "2"}, "RANK must lie in \\[0, WORLD_SIZE\\) = \\[0, 2\\); got 2"),
            ({"RANK": "x", "WORLD_SIZE": "2"}, "RANK must be an integer; got 'x'"),
            ({"WORLD_SIZE": "0"}, "WORLD_SIZE must be >= 1; got 0"),
        ],
    )
    def test_bad_environment(self, environ: dict[str, str], message: str) -> None:
        with pytest.raises(BatchError, match=message):
            distributed_env(environ)

    def test_default_workers_shares_the_cores(self) -> None:
        cores = default_workers(1)
        assert cores >= 1
        assert default_workers(cores * 4) == 1
        assert default_workers(2) == max(1, cores // 2)

    def test_ranks_without_process_group_cover_everything_and_merge(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {f"f{i}.txt": f"text {i}" for i in range(5)})
        reports = []
        for rank in range(2):
            environ = {"RANK": str(rank), "WORLD_SIZE": "2", "LOCAL_WORLD_SIZE": "2"}
            reports.append(_run(tasks, tmp_path, environ=environ))
        assert _names(reports[0].done) == ["f0.txt", "f2.txt", "f4.txt"]
        assert _names(reports[1].done) == ["f1.txt", "f3.txt"]
        for task in tasks:
            assert Path(task.outputs[0]).read_text() == Path(task.source).read_text().upper()
        merged = json.loads((tmp_path / "out" / "upper-report.json").read_text())
        assert merged["parts"] == [0, 1]
        assert merged["counts"] == {"total": 5, "done": 5, "skipped": 0, "failed": 0, "not_finished": 0}
        assert [e["input"] for e in merged["done"]] == [f"f{i}.txt" for i in range(5)]
        for rank in range(2):
            assert (tmp_path / "out" / f"upper-report.rank{rank}.json").is_file()


# ------------------------------------------------------------------------------------------------ writing


class TestAtomicWrites:
    def test_atomic_output_dir_replaces_on_success(self, tmp_path: Path) -> None:
        final = tmp_path / "scene"
        final.mkdir()
        (final / "old.txt").write_text("old")
        with atomic_output_dir(final) as tmp:
            (tmp / "new.txt").write_text("new")
            assert not (final / "new.txt").exists()  # nothing visible under the final name before the end
        assert sorted(p.name for p in final.iterdir()) == ["new.txt"]
        assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]

    def test_atomic_output_dir_keeps_the_old_folder_on_error(self, tmp_path: Path) -> None:
        final = tmp_path / "scene"
        final.mkdir()
        (final / "old.txt").write_text("old")
        with pytest.raises(RuntimeError, match="boom"), atomic_output_dir(final) as tmp:
            (tmp / "half.txt").write_text("half")
            raise RuntimeError("boom")
        assert sorted(p.name for p in final.iterdir()) == ["old.txt"]
        assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]

    def test_write_json_leaves_no_temporary(self, tmp_path: Path) -> None:
        write_json(tmp_path / "a" / "r.json", {"x": [1, 2]})
        assert json.loads((tmp_path / "a" / "r.json").read_text()) == {"x": [1, 2]}
        assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["r.json"]


# --------------------------------------------------------------------------------------------- run_batch


class TestRunBatch:
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

    def test_bad_arguments(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        with pytest.raises(BatchError, match="engine must be one of .*got 'dask'"):
            _run(tasks, tmp_path, engine="dask")
        with pytest.raises(ValueError, match="workers must be an int >= 1 or None; got 0"):
            _run(tasks, tmp_path, workers=0)
        with pytest.raises(ValueError, match="Task 'x' must have at least one output"):
            Task("x", "a", ())

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

    def test_report_inside_the_input_is_refused(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha"})
        with pytest.raises(BatchError, match="inside the input folder"):
            _run(tasks, tmp_path, report_path=tmp_path / "in" / "report.json")
        assert sorted(p.name for p in (tmp_path / "in").iterdir()) == ["a.txt"]

    def test_tasks_pickle(self) -> None:
        task = Task("a.exr", "/in/a.exr", ("/out/a.png",))
        assert pickle.loads(pickle.dumps(task)) == task

    def test_merge_reports(self) -> None:
        parts = [BatchReport("c", "i", "o", {}, rank=r, world_size=2, total=t) for r, t in ((1, 1), (0, 2))]
        parts[0].done.append({"input": "b"})
        parts[1].done.append({"input": "a"})
        parts[1].failed.append({"input": "c", "error": "E"})
        merged = merge_reports(parts)
        assert _names(merged.done) == ["a", "b"] and merged.total == 3 and merged.parts == [0, 1]
        assert merged.exit_code == 1


# ---------------------------------------------------------------------------------------------------- Ray


def _fake_ray(calls: list[str]) -> types.ModuleType:
    """A stand-in for the ray module that runs remote tasks eagerly, recording how the engine drives it."""
    ray = types.ModuleType("ray")
    state = {"initialized": False}

    class Ref:
        def __init__(self, value: Any) -> None:
            self.value = value

    def init(address: str | None = None, **kwargs: Any) -> None:
        calls.append(f"init:{address}")
        state["initialized"] = True

    def remote(**resources: Any) -> Any:
        calls.append(f"remote:{sorted(resources.items())}")

        def wrap(function: Any) -> Any:
            return types.SimpleNamespace(remote=lambda *args: (calls.append("submit"), Ref(function(*args)))[1])

        return wrap

    def wait(refs: list[Ref], *, num_returns: int = 1, timeout: float | None = None) -> tuple[list[Ref], list[Ref]]:
        calls.append(f"wait:{len(refs)}")
        return refs[:num_returns], refs[num_returns:]

    ray.init = init
    ray.is_initialized = lambda: state["initialized"]
    ray.remote = remote
    ray.wait = wait
    ray.get = lambda ref: ref.value
    ray.cancel = lambda ref: calls.append("cancel")
    ray.cluster_resources = lambda: {"CPU": 3.0}
    ray.shutdown = lambda: (calls.append("shutdown"), state.update(initialized=False))
    return ray


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
