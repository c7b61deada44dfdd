"""Tests of torch_modulo/batch/distributed.py: ranks share the work (balanced), agree through a process group that
closes before the jobs run, and rank 0 merges the parts it reads from disk, failing clearly when one never comes."""

from __future__ import annotations

import json
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pytest
import torch
from fakes import make_inputs as _make_inputs
from fakes import names as _names
from fakes import run as _run
from torch.utils.data import DistributedSampler

from torch_modulo.batch import BatchError, DistributedEnv, balance, distributed_env, shard
from torch_modulo.batch import distributed as distributed_module
from torch_modulo.batch import run as run_module


def _environ(rank: int, world: int = 2) -> dict[str, str]:
    """What torchrun sets for one rank (the ranks can form a process group)."""
    return {
        "RANK": str(rank),
        "WORLD_SIZE": str(world),
        "LOCAL_WORLD_SIZE": str(world),
        "MASTER_ADDR": "127.0.0.1",
        "MASTER_PORT": "29500",
    }


class FakeGroup:
    """Stands in for the short-lived process group: rank 0's plan reaches the other ranks."""

    def __init__(self) -> None:
        self.plan: Any = None
        self.ready = threading.Event()
        self.calls = 0

    def agree(self, env: DistributedEnv, plan: Any) -> Any:
        self.calls += 1
        if env.rank == 0:
            self.plan = plan()
            self.ready.set()
        else:
            assert self.ready.wait(10)
        return self.plan


@pytest.fixture
def group(monkeypatch: pytest.MonkeyPatch) -> FakeGroup:
    fake = FakeGroup()
    monkeypatch.setattr(run_module, "agree", fake.agree)
    monkeypatch.setattr(distributed_module, "_WAIT_POLL_S", 0.02)
    return fake


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


class TestSkippedInputs:
    """Inputs the caller leaves out of the run (``skipped=``, as ``tonemap`` does with frames) are counted once in the
    report of every mode: one process, ranks one after the other (the last one merges), ranks under torchrun."""

    SKIPPED = [{"input": "frame.png", "outputs": ["frame.png"], "reason": "not radiance: a frame"}]

    def _check(self, saved: dict[str, Any]) -> None:
        assert saved["counts"] == {"total": 6, "done": 5, "skipped": 1, "failed": 0, "not_finished": 0}
        assert saved["skipped"] == self.SKIPPED

    def test_one_process(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {f"f{i}.txt": f"text {i}" for i in range(5)})
        report = _run(tasks, tmp_path, skipped=self.SKIPPED)
        self._check(report.to_dict())
        self._check(json.loads((tmp_path / "out" / "upper-report.json").read_text()))

    def test_ranks_one_after_the_other(self, tmp_path: Path) -> None:
        # Regression: the command line added the skipped inputs after the run, and only where it saw the merged
        # report; ranks run one after the other merge in the last rank, so they never reached the report.
        tasks = _make_inputs(tmp_path, {f"f{i}.txt": f"text {i}" for i in range(5)})
        for rank in range(2):
            environ = {"RANK": str(rank), "WORLD_SIZE": "2", "LOCAL_WORLD_SIZE": "2"}
            _run(tasks, tmp_path, environ=environ, skipped=self.SKIPPED)
        self._check(json.loads((tmp_path / "out" / "upper-report.json").read_text()))

    def test_torchrun_ranks(self, tmp_path: Path, group: FakeGroup) -> None:
        tasks = _make_inputs(tmp_path, {f"f{i}.txt": f"text {i}" for i in range(5)})
        thread = threading.Thread(target=lambda: _run(tasks, tmp_path, environ=_environ(1), skipped=self.SKIPPED))
        thread.start()
        merged = _run(tasks, tmp_path, environ=_environ(0), merge_timeout=30, skipped=self.SKIPPED)
        thread.join()
        self._check(merged.to_dict())
        self._check(json.loads((tmp_path / "out" / "upper-report.json").read_text()))


class TestBalance:
    @pytest.mark.parametrize("n", [0, 1, 5, 8, 13])
    @pytest.mark.parametrize("world", [1, 2, 3, 4])
    def test_equal_weights_give_the_stride(self, n: int, world: int) -> None:
        ranks = balance([1.0] * n, world)
        assert all([i for i in range(n) if ranks[i] == r] == shard(list(range(n)), r, world) for r in range(world))

    def test_heavy_inputs_do_not_pile_up_on_one_rank(self) -> None:
        weights = [100, 1, 100, 1, 100, 1, 100, 1]  # a fixed stride would give rank 0 all the heavy ones
        ranks = balance(weights, 2)
        loads = [sum(w for w, r in zip(weights, ranks, strict=True) if r == k) for k in (0, 1)]
        assert loads == [202, 202]
        assert [sum(w for w in weights[k::2]) for k in (0, 1)] == [400, 4]

    def test_no_rank_gets_more_than_the_average_plus_the_heaviest(self) -> None:
        g = torch.Generator().manual_seed(0)
        weights = (torch.rand(200, generator=g) ** 4 * 1000).tolist()
        for world in (2, 3, 7):
            ranks = balance(weights, world)
            loads = [sum(w for w, r in zip(weights, ranks, strict=True) if r == k) for k in range(world)]
            assert max(loads) <= sum(weights) / world + max(weights)

    def test_bad_world(self) -> None:
        with pytest.raises(ValueError, match="world_size must be >= 1; got 0"):
            balance([1.0], 0)


class TestTorchrunReports:
    def test_rank_0_waits_for_a_rank_that_finishes_late(self, tmp_path: Path, group: FakeGroup) -> None:
        tasks = _make_inputs(tmp_path, {f"f{i}.txt": f"text {i}" for i in range(5)})
        late: dict[str, Any] = {}

        def rank_1() -> None:
            group.ready.wait(10)
            time.sleep(0.5)  # much later than rank 0
            late["report"] = _run(tasks, tmp_path, environ=_environ(1))

        thread = threading.Thread(target=rank_1)
        thread.start()
        merged = _run(tasks, tmp_path, environ=_environ(0), merge_timeout=30)  # (a bound, should the test fail)
        thread.join()
        assert merged.parts == [0, 1] and merged.exit_code == 0 and not merged.errors
        assert _names(merged.done) == [t.name for t in tasks]
        assert _names(late["report"].done) == ["f1.txt", "f3.txt"] and late["report"].parts is None
        saved = json.loads((tmp_path / "out" / "upper-report.json").read_text())
        assert saved["parts"] == [0, 1] and saved["counts"]["done"] == 5
        assert group.calls == 2  # one agreement per rank, at start-up

    def test_a_part_that_never_arrives_fails_rank_0_clearly(self, tmp_path: Path, group: FakeGroup) -> None:
        tasks = _make_inputs(tmp_path, {f"f{i}.txt": f"text {i}" for i in range(5)})
        messages: list[str] = []
        merged = _run(tasks, tmp_path, environ=_environ(0), merge_timeout=0.3, log=messages.append)
        part = tmp_path / "out" / "upper-report.rank1.json"
        assert merged.exit_code == 1 and not merged.interrupted
        assert merged.errors == [f"rank 1 wrote no report part ({part}) within 0.3 s"]
        assert _names(merged.done) == ["f0.txt", "f2.txt", "f4.txt"]
        assert merged.not_finished == ["f1.txt", "f3.txt"] and merged.total == 5
        saved = json.loads((tmp_path / "out" / "upper-report.json").read_text())
        assert saved["errors"] == merged.errors and saved["counts"]["not_finished"] == 2
        assert any(str(part) in m for m in messages)

    def test_a_part_of_an_earlier_launch_is_not_taken(self, tmp_path: Path, group: FakeGroup) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "beta"})
        old = tmp_path / "out" / "upper-report.rank1.json"
        old.parent.mkdir(parents=True)
        old.write_text(json.dumps({"command": "upper", "input": "", "output": "", "options": {}, "launch": "old"}))
        merged = _run(tasks, tmp_path, environ=_environ(0), merge_timeout=0.2)
        assert merged.exit_code == 1 and "rank 1 wrote no report part" in merged.errors[0]

    def test_rank_0_stopped_while_waiting_writes_the_report(self, tmp_path: Path, group: FakeGroup) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "b.txt": "beta"})

        def log(message: str) -> None:  # once rank 0 waits, torchrun stops it (as after a failure of rank 1)
            if message.startswith("waiting for the report parts"):
                threading.Timer(0.1, os.kill, (os.getpid(), signal.SIGTERM)).start()

        merged = _run(tasks, tmp_path, environ=_environ(0), log=log)
        assert merged.interrupted and merged.exit_code == 130
        part = tmp_path / "out" / "upper-report.rank1.json"
        assert merged.errors == [f"rank 1 wrote no report part ({part}) before rank 0 was stopped"]
        assert json.loads((tmp_path / "out" / "upper-report.json").read_text())["not_finished"] == ["b.txt"]

    def test_a_resumed_launch_shares_out_the_work_that_is_left(self, tmp_path: Path, group: FakeGroup) -> None:
        tasks = _make_inputs(tmp_path, {f"f{i}.txt": f"text {i}" for i in range(6)})
        for task in tasks[::2]:  # a first run completed f0, f2 and f4: a fixed stride would leave rank 0 idle
            _run([task], tmp_path)
        box: dict[str, Any] = {}
        thread = threading.Thread(target=lambda: box.update(rank_1=_run(tasks, tmp_path, environ=_environ(1))))
        thread.start()
        merged = _run(tasks, tmp_path, environ=_environ(0), merge_timeout=30)
        thread.join()
        assert _names(merged.skipped) == ["f0.txt", "f2.txt", "f4.txt"]
        assert _names(merged.done) == ["f1.txt", "f3.txt", "f5.txt"]
        assert _names(box["rank_1"].done) == ["f3.txt"]  # rank 0 did f1 and f5


class TestAgree:
    def test_the_process_group_closes_before_the_jobs(self, monkeypatch: pytest.MonkeyPatch) -> None:
        import torch.distributed as dist

        events: list[str] = []
        monkeypatch.setattr(dist, "is_available", lambda: True)
        monkeypatch.setattr(dist, "is_initialized", lambda: False)
        monkeypatch.setattr(dist, "init_process_group", lambda *a, **k: events.append("init"))

        def broadcast(box: list[Any], src: int) -> None:
            events.append(f"broadcast from {src}")

        monkeypatch.setattr(dist, "broadcast_object_list", broadcast)
        monkeypatch.setattr(dist, "destroy_process_group", lambda: events.append("destroy"))
        env = DistributedEnv(0, 2, 0, 2, master=True)
        assert distributed_module.agree(env, lambda: "plan") == "plan"
        assert events == ["init", "broadcast from 0", "destroy"]

    def test_without_a_master_every_rank_plans_alone(self) -> None:
        assert distributed_module.agree(DistributedEnv(1, 2, 1, 2, master=False), lambda: "mine") == "mine"

    def test_an_existing_process_group_is_left_open(self, monkeypatch: pytest.MonkeyPatch) -> None:
        import torch.distributed as dist

        events: list[str] = []
        monkeypatch.setattr(dist, "is_available", lambda: True)
        monkeypatch.setattr(dist, "is_initialized", lambda: True)
        monkeypatch.setattr(dist, "broadcast_object_list", lambda box, src: events.append("broadcast"))
        monkeypatch.setattr(dist, "destroy_process_group", lambda: events.append("destroy"))
        distributed_module.agree(DistributedEnv(0, 2, 0, 2, master=True), lambda: "plan")
        assert events == ["broadcast"]


def test_bad_rank_environment_is_a_batch_error() -> None:
    with pytest.raises(BatchError, match="RANK must lie in"):
        distributed_env({"RANK": "5", "WORLD_SIZE": "2"})
