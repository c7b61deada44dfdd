"""Tests of torch_modulo/_task.py: a Task, one input and its outputs, shared by the jobs and the batch engine."""

from __future__ import annotations

import pickle

import pytest

from torch_modulo._task import Task


class TestTask:
    def test_the_batch_engine_and_the_jobs_share_one_task(self) -> None:
        import torch_modulo.batch as batch
        import torch_modulo.batch.tasks as tasks

        assert batch.Task is tasks.Task is Task

    def test_tasks_pickle(self) -> None:
        task = Task("a.exr", "/in/a.exr", ("/out/a.png",))
        assert pickle.loads(pickle.dumps(task)) == task
        assert Task("a", "/in/a", ["/out/a"]).outputs == ("/out/a",)  # type: ignore[arg-type]

    def test_bad_tasks(self) -> None:
        with pytest.raises(ValueError, match="Task 'x' must have at least one output"):
            Task("x", "a", ())
        with pytest.raises(ValueError, match="Task.name must be a non-empty string; got ''"):
            Task("", "a", ("b",))
