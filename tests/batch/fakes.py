"""Jobs and stand-ins shared by the batch engine's tests: small text-file jobs, independent of any image operation.

The jobs are module-level functions so that worker processes can import them (this folder is on ``sys.path``).
"""

from __future__ import annotations

import errno
import os
import signal
import time
import types
from pathlib import Path
from typing import Any

import torch

from torch_modulo.batch import BatchReport, Task, run_batch

__all__ = ["changing_job", "fake_ray", "fill_disk", "lazy_job", "make_inputs", "names", "quiet", "run", "upper_job"]


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


def quiet(message: str) -> None:
    """A log that shows nothing."""


def fill_disk(folder: Path) -> None:
    """Fill the file system holding ``folder`` (a file of zeros, ``filler.bin``, until no space is left)."""
    try:
        with open(folder / "filler.bin", "wb", buffering=0) as handle:
            while True:
                handle.write(b"\0" * 65536)
    except OSError as error:
        if error.errno != errno.ENOSPC:
            raise


def make_inputs(folder: Path, texts: dict[str, str]) -> list[Task]:
    """Write text inputs under folder/in and return their tasks (outputs under folder/out)."""
    src, out = folder / "in", folder / "out"
    for name, text in texts.items():
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        (src / name).write_text(text)
    return [Task(name, str(src / name), (str(out / name),)) for name in sorted(texts)]


def run(tasks: list[Task], folder: Path, **kwargs: Any) -> BatchReport:
    """run_batch of ``upper`` from folder/in to folder/out, one worker and quiet unless told otherwise."""
    kwargs.setdefault("workers", 1)
    kwargs.setdefault("progress", False)
    kwargs.setdefault("log", quiet)
    options = kwargs.pop("options", {})
    return run_batch(
        "upper", tasks, kwargs.pop("job", upper_job), options, folder / "out", input_path=folder / "in", **kwargs
    )


def names(entries: list[dict[str, Any]]) -> list[str]:
    """The input names of report entries."""
    return [e["input"] for e in entries]


def fake_ray(calls: list[str]) -> types.ModuleType:
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
