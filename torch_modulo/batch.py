"""A batch engine for folders of files: one job per input, run safely, in parallel, resumably, on one or many machines.

The engine knows nothing about images: a command (``torch-modulo simulate``, ``unwrap``, ``tonemap``) lists its
inputs as :class:`Task` objects (an input and the output paths it produces) and passes a top-level job function;
:func:`run_batch` does the rest.

What it guarantees
    - **Inputs are never written.** :func:`check_folders` refuses an output folder equal to or inside the input
      folder, and a task whose output would land inside the input folder (or replace one of its inputs) fails
      without running.
    - **Atomic outputs.** Jobs write files with :func:`torch_modulo.io.write_image` (temporary file, then
      ``os.replace``) and folders with :func:`atomic_output_dir`, so a crash never leaves a half-written output
      under its final name.
    - **Resume.** After a task succeeds the engine writes a small *done marker* under
      ``OUT/.torch-modulo/<command>/`` (atomically) that records the options, the input's size and modification
      time, and the outputs. A task is *complete*, and skipped by the next run, when its marker exists, matches
      the current options and input, and every output exists. A rerun after a crash or Ctrl-C therefore redoes
      only what is missing; changing an option or the input redoes that task; ``force=True`` redoes everything.
    - **Failures are contained.** An exception in one job is recorded with its message (``"OSError: cannot read
      image ..."``) and the other tasks go on.
    - **A report.** ``done``, ``skipped`` and ``failed`` (with reasons) and, after an interruption, the tasks not
      finished, written atomically as JSON (:class:`BatchReport`).
    - **Ctrl-C** (SIGINT, and SIGTERM as sent by schedulers and ``torchrun``): tasks not yet started are
      cancelled, running ones are allowed to finish (a second Ctrl-C abandons them), completed outputs are kept
      and the report says what was done.

Engines
    - ``"process"`` (default): ``workers`` processes from a ``forkserver`` pool (``spawn`` where there is no
      forkserver), or the calling process itself when one worker is enough. Workers ignore SIGINT (the parent
      coordinates the shutdown) and run torch with one thread each when there are several workers, so that they
      do not oversubscribe the cores.
    - ``"ray"``: one Ray task per input on an existing Ray cluster (``ray.init(address=...)``; the environment
      variable ``RAY_ADDRESS`` or a local Ray when no address is given). Ray is imported only then; install it
      with ``pip install 'torch_modulo[ray]'``. Every Ray node needs torch_modulo installed and the same view of
      the input and output folders (a shared file system).

Several processes or machines (``torchrun``)
    Under ``torchrun`` (or any launcher that sets ``RANK`` and ``WORLD_SIZE``) each rank takes its shard of the
    sorted task list, ``tasks[rank::world_size]``, as ``torch.utils.data.DistributedSampler`` does without
    shuffling (but without padding: no task runs twice). When ``MASTER_ADDR`` and ``MASTER_PORT`` are set (torchrun
    sets them) the ranks join a ``gloo`` process group: rank 0's task list is broadcast, so every rank shards the
    same list, and rank 0 gathers the ranks' reports into one. Each rank also writes its own part,
    ``<report stem>.rank<r>.json``; without a process group the last rank to finish merges the parts it finds.
    Every machine needs the same view of the input and output folders (a shared file system).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import multiprocessing
import os
import pickle
import secrets
import shutil
import signal
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

__all__ = [
    "ENGINES",
    "MARKER_FOLDER",
    "BatchError",
    "BatchReport",
    "DistributedEnv",
    "Task",
    "atomic_output_dir",
    "check_folders",
    "default_workers",
    "discover",
    "distributed_env",
    "merge_reports",
    "require_ray",
    "run_batch",
    "shard",
    "write_json",
]

#: Engines :func:`run_batch` accepts.
ENGINES = ("process", "ray")
#: Hidden folder inside the output folder that holds the done markers.
MARKER_FOLDER = ".torch-modulo"

#: ``job(task, options) -> info``: a top-level (picklable) function that reads ``task.source`` and writes every
#: path in ``task.outputs`` atomically; it may return a small JSON-compatible dict for the report.
JobFunction = Callable[["Task", Mapping[str, Any]], Mapping[str, Any] | None]


class BatchError(Exception):
    """A batch cannot start (bad folders, bad distributed environment, missing engine); the message says why."""


# ------------------------------------------------------------------------------------------------ tasks


@dataclass(frozen=True)
class Task:
    """One unit of work: an input and the outputs it produces.

    Args:
        name: the input's path relative to the input folder, with ``/`` separators (``"sub/scene.exr"``); the
            key in the report and in the done markers.
        source: the input file or folder (absolute path as a string, so tasks pickle cheaply).
        outputs: the paths (files or folders) the job creates, absolute.

    Example:
        >>> Task("a.exr", "/data/in/a.exr", ("/data/out/a.png",)).name
        'a.exr'
    """

    name: str
    source: str
    outputs: tuple[str, ...]

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"Task.name must be a non-empty string; got {self.name!r}")
        if not self.outputs:
            raise ValueError(f"Task {self.name!r} must have at least one output")
        object.__setattr__(self, "source", str(self.source))
        object.__setattr__(self, "outputs", tuple(str(p) for p in self.outputs))


def discover(
    root: str | os.PathLike[str],
    match: Callable[[Path], bool],
    *,
    descend: Callable[[Path], bool] | None = None,
) -> list[tuple[str, Path]]:
    """Every entry under ``root`` that ``match`` accepts, sorted by relative path (deterministic on every machine).

    Hidden entries (names starting with ``.``: temporary files of atomic writes, the done markers) are never
    listed or entered. A matched folder is not entered. If ``root`` is itself a file (or a matching folder), it
    is the only entry, named by its own name.

    Args:
        root: the input folder (or one input).
        match: which files or folders are inputs.
        descend: which unmatched folders to enter (default: all).

    Returns:
        ``(name, path)`` pairs, ``name`` relative to ``root`` with ``/`` separators.

    Raises:
        FileNotFoundError: ``root`` does not exist.

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     for name in ("b.exr", "a.exr", "notes.txt", ".tmp.exr", "sub/c.exr"):
        ...         os.makedirs(os.path.dirname(os.path.join(folder, name)), exist_ok=True)
        ...         open(os.path.join(folder, name), "w").close()
        ...     [name for name, _ in discover(folder, lambda p: p.suffix == ".exr")]
        ['a.exr', 'b.exr', 'sub/c.exr']
    """
    root = Path(root)
    if not root.exists():
        raise FileNotFoundError(f"input not found: {root}")
    if root.is_file() or match(root):
        return [(root.name, root)]
    found: list[tuple[str, Path]] = []

    def walk(folder: Path) -> None:
        try:
            entries = sorted(folder.iterdir(), key=lambda p: p.name)
        except OSError as error:
            raise OSError(f"cannot list {folder}: {error}") from error
        for path in entries:
            if path.name.startswith("."):
                continue
            if match(path):
                found.append((path.relative_to(root).as_posix(), path))
            elif path.is_dir() and (descend is None or descend(path)):
                walk(path)

    walk(root)
    found.sort(key=lambda item: item[0])
    return found


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def check_folders(input_path: str | os.PathLike[str], out_dir: str | os.PathLike[str]) -> tuple[Path, Path]:
    """Validate an input folder (or file) and an output folder before a batch; returns both, resolved.

    Raises:
        BatchError: the input does not exist, the output is an existing file, or the output folder is the input
            folder or inside it (outputs would mix with inputs, and a rerun would take them as inputs).

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     check_folders(folder, os.path.join(folder, "out"))
        Traceback (most recent call last):
        ...
        torch_modulo.batch.BatchError: output folder ... is inside the input folder ...; choose a folder outside it
    """
    source = Path(input_path).expanduser()
    out = Path(out_dir).expanduser()
    if not source.exists():
        raise BatchError(f"input not found: {source}")
    source, out = source.resolve(), out.resolve()
    if out.exists() and not out.is_dir():
        raise BatchError(f"output {out} exists and is not a folder")
    if source.is_dir():
        if out == source:
            raise BatchError(f"output folder {out} is the input folder; choose another one (inputs are never written)")
        if _inside(out, source):
            raise BatchError(f"output folder {out} is inside the input folder {source}; choose a folder outside it")
    return source, out


# ------------------------------------------------------------------------------------------- processes


def _cpu_count() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # macOS, Windows
        return max(1, os.cpu_count() or 1)


def default_workers(local_world_size: int = 1) -> int:
    """The machine's cores (those this process may use), shared between the ranks on this machine.

    Example:
        >>> default_workers() >= 1
        True
    """
    return max(1, _cpu_count() // max(1, local_world_size))


@dataclass(frozen=True)
class DistributedEnv:
    """Where this process stands in a ``torchrun`` (or similar) launch; one process alone is rank 0 of 1."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    local_world_size: int = 1
    master: bool = False  # MASTER_ADDR and MASTER_PORT set: a process group can be formed


def _env_int(environ: Mapping[str, str], key: str, default: int) -> int:
    text = environ.get(key)
    if text is None or text == "":
        return default
    try:
        return int(text)
    except ValueError:
        raise BatchError(f"environment variable {key} must be an integer; got {text!r}") from None


def distributed_env(environ: Mapping[str, str] | None = None) -> DistributedEnv:
    """Read ``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK`` and ``LOCAL_WORLD_SIZE`` (as torchrun sets them).

    Raises:
        BatchError: a value is not an integer, or the rank is outside ``[0, WORLD_SIZE)``.

    Example:
        >>> distributed_env({"RANK": "1", "WORLD_SIZE": "4", "LOCAL_RANK": "1", "LOCAL_WORLD_SIZE": "2"})
        DistributedEnv(rank=1, world_size=4, local_rank=1, local_world_size=2, master=False)
        >>> distributed_env({})
        DistributedEnv(rank=0, world_size=1, local_rank=0, local_world_size=1, master=False)
    """
    environ = os.environ if environ is None else environ
    world = _env_int(environ, "WORLD_SIZE", 1)
    rank = _env_int(environ, "RANK", 0)
    if world < 1:
        raise BatchError(f"WORLD_SIZE must be >= 1; got {world}")
    if not 0 <= rank < world:
        raise BatchError(f"RANK must lie in [0, WORLD_SIZE) = [0, {world}); got {rank}")
    local_world = _env_int(environ, "LOCAL_WORLD_SIZE", 1 if world == 1 else 0)
    local_rank = _env_int(environ, "LOCAL_RANK", 0)
    if local_world < 1:  # a launcher without LOCAL_WORLD_SIZE: assume all ranks share this machine
        local_world = world
    master = bool(environ.get("MASTER_ADDR")) and bool(environ.get("MASTER_PORT"))
    return DistributedEnv(rank, world, local_rank, local_world, master and world > 1)


def shard(items: Sequence[Any], rank: int, world_size: int) -> list[Any]:
    """This rank's share, ``items[rank::world_size]``: the order ``DistributedSampler(shuffle=False)`` uses.

    Example:
        >>> shard(list("abcde"), 0, 2), shard(list("abcde"), 1, 2)
        (['a', 'c', 'e'], ['b', 'd'])
    """
    if world_size < 1 or not 0 <= rank < world_size:
        raise ValueError(f"rank must lie in [0, world_size); got rank={rank}, world_size={world_size}")
    return list(items[rank::world_size])


# --------------------------------------------------------------------------------------------- writing


def write_json(path: str | os.PathLike[str], data: Any) -> Path:
    """Write ``data`` as indented JSON atomically (temporary file in the same folder, then ``os.replace``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{secrets.token_hex(4)}.tmp")
    try:
        tmp.write_text(json.dumps(data, indent=1, allow_nan=True) + "\n")
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


@contextlib.contextmanager
def atomic_output_dir(final: str | os.PathLike[str]) -> Iterator[Path]:
    """Build an output folder under a hidden temporary name, then move it into place in one rename.

    A crash or an exception inside the ``with`` block removes the temporary folder and leaves any previous
    ``final`` untouched; on success a previous ``final`` is replaced (moved aside, the new one renamed into
    place, the old one deleted).

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     with atomic_output_dir(os.path.join(folder, "scene")) as tmp:
        ...         _ = (tmp / "frame.txt").write_text("x")
        ...     sorted(os.listdir(folder)), os.listdir(os.path.join(folder, "scene"))
        (['scene'], ['frame.txt'])
    """
    final = Path(final)
    final.parent.mkdir(parents=True, exist_ok=True)
    tag = f"{os.getpid()}-{secrets.token_hex(4)}"
    tmp = final.with_name(f".{final.name}.tmp-{tag}")
    tmp.mkdir()
    try:
        yield tmp
        if final.exists():
            old = final.with_name(f".{final.name}.old-{tag}")
            os.replace(final, old)
            os.replace(tmp, final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _source_state(path: Path) -> Any:
    """What identifies an input's content cheaply: size and modification time (of every file in a folder)."""
    stat = path.stat()
    if not path.is_dir():
        return [stat.st_size, stat.st_mtime_ns]
    state = []
    for item in sorted(path.rglob("*")):
        rel = item.relative_to(path)
        if any(part.startswith(".") for part in rel.parts) or not item.is_file():
            continue
        s = item.stat()
        state.append([rel.as_posix(), s.st_size, s.st_mtime_ns])
    return state


def _fingerprint(command: str, options: Mapping[str, Any]) -> str:
    """A hash of the command and the options that decide the outputs (names starting with ``_`` do not)."""
    kept = {k: v for k, v in options.items() if not k.startswith("_")}
    text = json.dumps({"command": command, "options": kept}, sort_keys=True, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _marker_path(out_dir: Path, command: str, name: str) -> Path:
    return out_dir / MARKER_FOLDER / command / f"{name}.json"


def _is_complete(task: Task, marker: Path, fingerprint: str, outputs: list[str]) -> bool:
    try:
        data = json.loads(marker.read_text())
    except (OSError, ValueError):
        return False
    if not isinstance(data, dict) or data.get("fingerprint") != fingerprint:
        return False
    if data.get("outputs") != outputs or not all(Path(p).exists() for p in task.outputs):
        return False
    try:
        return data.get("source_state") == _source_state(Path(task.source))
    except OSError:
        return False


# ---------------------------------------------------------------------------------------------- report


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")  # noqa: UP017 (keep 3.10 readers happy)


@dataclass
class BatchReport:
    """What a batch did. ``to_dict()`` is the JSON report; ``exit_code`` is what the command line returns.

    Fields ``done``, ``skipped`` and ``failed`` are lists of dicts with the task's ``input`` name and ``outputs``
    (relative to the output folder), plus ``seconds`` and the job's info (done), ``reason`` (skipped) or
    ``error`` (failed). ``not_finished`` lists the inputs an interruption left undone.
    """

    command: str
    input: str
    output: str
    options: dict[str, Any]
    engine: str = "process"
    workers: int = 1
    rank: int = 0
    world_size: int = 1
    started: str = field(default_factory=_now)
    finished: str | None = None
    seconds: float = 0.0
    interrupted: bool = False
    total: int = 0
    done: list[dict[str, Any]] = field(default_factory=list)
    skipped: list[dict[str, Any]] = field(default_factory=list)
    failed: list[dict[str, Any]] = field(default_factory=list)
    not_finished: list[str] = field(default_factory=list)
    parts: list[int] | None = None  # ranks merged into this report

    @property
    def counts(self) -> dict[str, int]:
        return {
            "total": self.total,
            "done": len(self.done),
            "skipped": len(self.skipped),
            "failed": len(self.failed),
            "not_finished": len(self.not_finished),
        }

    @property
    def exit_code(self) -> int:
        """0 when everything is done or skipped; 1 when anything failed; 130 after an interruption."""
        if self.interrupted:
            return 130
        return 1 if self.failed else 0

    def to_dict(self) -> dict[str, Any]:
        data = {
            "command": self.command,
            "input": self.input,
            "output": self.output,
            "options": self.options,
            "engine": self.engine,
            "workers": self.workers,
            "rank": self.rank,
            "world_size": self.world_size,
            "started": self.started,
            "finished": self.finished,
            "seconds": round(self.seconds, 3),
            "interrupted": self.interrupted,
            "counts": self.counts,
            "done": self.done,
            "skipped": self.skipped,
            "failed": self.failed,
            "not_finished": self.not_finished,
        }
        if self.parts is not None:
            data["parts"] = self.parts
        return data

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> BatchReport:
        keys = {f for f in cls.__dataclass_fields__}
        kwargs = {k: v for k, v in data.items() if k in keys}
        kwargs["total"] = int(data.get("counts", {}).get("total", data.get("total", 0)))
        return cls(**kwargs)

    def summary(self) -> str:
        c = self.counts
        text = f"{self.command}: {c['done']} done, {c['skipped']} skipped, {c['failed']} failed of {c['total']}"
        if self.interrupted:
            text += f"; interrupted, {c['not_finished']} not finished"
        return text


def merge_reports(parts: Sequence[BatchReport]) -> BatchReport:
    """One report from the ranks' parts (sorted by input name; the run spans the earliest start to the last end)."""
    first = parts[0]
    merged = BatchReport(
        command=first.command,
        input=first.input,
        output=first.output,
        options=first.options,
        engine=first.engine,
        workers=first.workers,
        rank=0,
        world_size=first.world_size,
        started=min(p.started for p in parts),
        finished=max((p.finished or "") for p in parts) or None,
        seconds=max(p.seconds for p in parts),
        interrupted=any(p.interrupted for p in parts),
        total=sum(p.total for p in parts),
        parts=sorted(p.rank for p in parts),
    )
    for key in ("done", "skipped", "failed"):
        getattr(merged, key).extend(sorted((e for p in parts for e in getattr(p, key)), key=lambda e: e["input"]))
    merged.not_finished = sorted(n for p in parts for n in p.not_finished)
    return merged


# ---------------------------------------------------------------------------------------- worker side


def _init_worker(threads: int | None) -> None:
    """Pool initializer: leave Ctrl-C to the parent, and keep torch to ``threads`` threads."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if threads is not None:
        import torch

        torch.set_num_threads(threads)


def _execute(job: JobFunction, task: Task, options: Mapping[str, Any], threads: int | None = None) -> dict[str, Any]:
    """Run one job and never raise an ``Exception``: returns ``{"ok": ..., "seconds": ..., "info"/"error": ...}``."""
    if threads is not None:
        import torch

        if torch.get_num_threads() != threads:
            torch.set_num_threads(threads)
    start = time.perf_counter()
    try:
        for output in task.outputs:  # outputs mirror the input's subfolders
            Path(output).parent.mkdir(parents=True, exist_ok=True)
        info = job(task, options)
        missing = [p for p in task.outputs if not Path(p).exists()]
        if missing:
            raise RuntimeError(f"the job finished without writing {', '.join(missing)}")
    except Exception as error:  # one bad input must not stop the batch: report it
        message = str(error) or repr(error)
        return {"ok": False, "seconds": time.perf_counter() - start, "error": f"{type(error).__name__}: {message}"}
    return {"ok": True, "seconds": time.perf_counter() - start, "info": dict(info or {})}


# ------------------------------------------------------------------------------------------- engines


class _Stop:
    """Ctrl-C (SIGINT) and SIGTERM during a batch: the first asks the batch to stop after the running tasks (a flag
    the loops poll, so no result is ever lost half-recorded); the second raises KeyboardInterrupt to abandon them."""

    def __init__(self, log: Callable[[str], None]) -> None:
        self.requested = 0
        self.log = log

    def __call__(self, signum: int, frame: Any) -> None:
        self.requested += 1
        if self.requested > 1:
            raise KeyboardInterrupt
        self.log("interrupted: finishing the running task(s), starting no more (Ctrl-C again to abandon them)")

    @contextlib.contextmanager
    def installed(self) -> Iterator[_Stop]:
        import threading

        if threading.current_thread() is not threading.main_thread():  # signals reach the main thread only
            yield self
            return
        previous = {sig: signal.signal(sig, self) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield self
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


_Callback = Callable[[Task, dict[str, Any]], None]
_POLL_S = 0.2


def _run_inline(
    tasks: Sequence[Task],
    job: JobFunction,
    options: Mapping[str, Any],
    threads: int | None,
    on_result: _Callback,
    stop: _Stop,
) -> None:
    """Run in this process, one task after the other, until done or asked to stop."""
    for task in tasks:
        if stop.requested:
            return
        on_result(task, _execute(job, task, options, threads))


def _pool_context(preload: Sequence[str]) -> multiprocessing.context.BaseContext:
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    if ctx.get_start_method() == "forkserver":
        # Import the heavy modules once in the fork server rather than in every worker. Never the main module
        # itself (python -m ...): each worker runs it again as __mp_main__, which warns if it was imported before.
        main = getattr(getattr(sys.modules.get("__main__"), "__spec__", None), "name", None)
        modules = ["torch", "torch_modulo.batch", *preload]
        ctx.set_forkserver_preload([m for m in dict.fromkeys(modules) if m != main])  # type: ignore[attr-defined]
    return ctx


def _run_pool(
    tasks: Sequence[Task],
    job: JobFunction,
    options: Mapping[str, Any],
    workers: int,
    threads: int | None,
    on_result: _Callback,
    log: Callable[[str], None],
    preload: Sequence[str],
    stop: _Stop,
) -> None:
    queue = list(tasks)
    queue.reverse()
    running: dict[Future[dict[str, Any]], Task] = {}
    executor = ProcessPoolExecutor(
        workers, mp_context=_pool_context(preload), initializer=_init_worker, initargs=(threads,)
    )
    try:
        while queue or running:
            if stop.requested:
                queue.clear()
                for future in list(running):
                    if future.cancel():  # not started yet
                        running.pop(future)
                if not running:
                    break
            while queue and len(running) < 2 * workers:
                task = queue.pop()
                running[executor.submit(_execute, job, task, options, threads)] = task
            finished, _ = wait(list(running), timeout=_POLL_S, return_when=FIRST_COMPLETED)
            for future in finished:
                task = running.pop(future)
                try:
                    result = future.result()
                except Exception as error:  # the worker process died (killed, out of memory, ...)
                    result = {"ok": False, "seconds": 0.0, "error": f"{type(error).__name__}: {error}"}
                on_result(task, result)
    except KeyboardInterrupt:  # asked twice: abandon the running tasks
        for process in list((getattr(executor, "_processes", None) or {}).values()):
            process.terminate()
        executor.shutdown(wait=False, cancel_futures=True)
        raise
    finally:
        executor.shutdown(wait=True, cancel_futures=True)


def require_ray() -> Any:
    """Import Ray for ``engine="ray"``, or raise :class:`BatchError` telling how to install it."""
    try:
        import ray
    except ImportError as error:
        raise BatchError(
            "--engine ray needs Ray, which is not installed here; install it with: pip install 'torch_modulo[ray]'"
        ) from error
    return ray


def _run_ray(
    tasks: Sequence[Task],
    job: JobFunction,
    options: Mapping[str, Any],
    workers: int | None,
    threads: int | None,
    on_result: _Callback,
    address: str | None,
    stop: _Stop,
) -> int:
    ray = require_ray()
    started_here = False
    if not ray.is_initialized():
        ray.init(address=address)
        started_here = True
    try:
        window = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        remote = ray.remote(num_cpus=1, max_retries=0)(_execute)
        queue = list(tasks)
        queue.reverse()
        running: dict[Any, Task] = {}
        try:
            while queue or running:
                if stop.requested:
                    queue.clear()
                    if not running:
                        break
                while queue and len(running) < window:
                    task = queue.pop()
                    running[remote.remote(job, task, options, threads)] = task
                ready, _ = ray.wait(list(running), num_returns=1, timeout=_POLL_S)
                for ref in ready:
                    task = running.pop(ref)
                    try:
                        result = ray.get(ref)
                    except Exception as error:  # the Ray worker died or the task was cancelled
                        result = {"ok": False, "seconds": 0.0, "error": f"{type(error).__name__}: {error}"}
                    on_result(task, result)
        except KeyboardInterrupt:
            for ref in running:
                ray.cancel(ref)
            raise
        return window
    finally:
        if started_here:
            ray.shutdown()


# ------------------------------------------------------------------------------------- process group


class _Group:
    """A gloo process group among the ranks (torchrun), or nothing when there is none to join."""

    def __init__(self, env: DistributedEnv) -> None:
        self.active = False
        if env.world_size > 1 and env.master:
            import torch.distributed as dist

            if dist.is_available():
                if not dist.is_initialized():
                    dist.init_process_group("gloo", rank=env.rank, world_size=env.world_size)
                    self.owned = True
                else:
                    self.owned = False
                self.active = True

    def broadcast(self, value: Any) -> Any:
        import torch.distributed as dist

        box = [value]
        dist.broadcast_object_list(box, src=0)
        return box[0]

    def gather(self, value: Any, rank: int, world_size: int) -> list[Any] | None:
        import torch.distributed as dist

        out: list[Any] | None = [None] * world_size if rank == 0 else None
        dist.gather_object(value, out, dst=0)
        return out

    def close(self) -> None:
        if self.active and self.owned:
            import torch.distributed as dist

            with contextlib.suppress(Exception):
                dist.destroy_process_group()
        self.active = False


def _part_path(report_path: Path, rank: int) -> Path:
    return report_path.with_name(f"{report_path.stem}.rank{rank}{report_path.suffix}")


def _merge_parts_on_disk(report_path: Path, report: BatchReport, run_key: str) -> BatchReport | None:
    """Without a process group: merge when every rank's part of this run is on disk (the last rank does it)."""
    parts = []
    for r in range(report.world_size):
        try:
            data = json.loads(_part_path(report_path, r).read_text())
        except (OSError, ValueError):
            return None
        if data.get("run_key") != run_key:
            return None
        parts.append(BatchReport.from_dict(data))
    return merge_reports(parts)


# ------------------------------------------------------------------------------------------- the batch


def _relative(path: str, out_dir: Path) -> str:
    try:
        return Path(path).relative_to(out_dir).as_posix()
    except ValueError:
        return path


def run_batch(
    command: str,
    tasks: Sequence[Task],
    job: JobFunction,
    options: Mapping[str, Any],
    out_dir: str | os.PathLike[str],
    *,
    input_path: str | os.PathLike[str] | None = None,
    workers: int | None = None,
    engine: str = "process",
    force: bool = False,
    progress: bool | None = None,
    report_path: str | os.PathLike[str] | None = None,
    ray_address: str | None = None,
    environ: Mapping[str, str] | None = None,
    log: Callable[[str], None] | None = None,
    preload: Sequence[str] = (),
) -> BatchReport:
    """Run ``job`` once per task that is not complete yet; write the done markers and the JSON report.

    Args:
        command: the command's name (report, done markers; ``"tonemap"``).
        tasks: every input of the batch (all ranks pass the same list; see the module docstring).
        job: top-level function ``job(task, options) -> dict | None`` that writes ``task.outputs`` atomically
            (their folders exist when it starts).
        options: JSON-compatible settings passed to every job; part of what makes an output "complete", except
            names starting with ``_`` (settings that do not change the outputs, such as a job's own processes).
        out_dir: the output folder (created); done markers go to ``out_dir/.torch-modulo/<command>/``.
        input_path: the input folder or file; no task may write inside it (recorded in the report).
        workers: processes (``"process"``) or tasks in flight (``"ray"``); default :func:`default_workers`
            (``"process"``) or the Ray cluster's CPUs (``"ray"``).
        engine: ``"process"`` or ``"ray"``.
        force: redo complete tasks too.
        progress: show a progress bar; None (default) shows it on rank 0 when stderr is a terminal.
        report_path: where the JSON report goes (default ``out_dir/<command>-report.json``).
        ray_address: the Ray cluster to join (default ``RAY_ADDRESS`` or a local Ray).
        environ: the environment to read the rank from (default ``os.environ``).
        log: where messages go (default: stderr, above the progress bar).
        preload: modules the worker processes import once, up front (a forkserver imports them before forking).

    Returns:
        The report (on rank 0 of a process group, the merged report of every rank).

    Raises:
        BatchError: unknown engine, a job that cannot be sent to worker processes, Ray missing, bad ranks.
        ValueError: bad ``workers``.

    Example:
        >>> import tempfile
        >>> def copy_job(task, options):          # a real job must be a module-level function
        ...     Path(task.outputs[0]).write_text(Path(task.source).read_text().upper())
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     src, out = Path(folder, "in"), Path(folder, "out")
        ...     src.mkdir()
        ...     _ = (src / "a.txt").write_text("hello")
        ...     tasks = [Task("a.txt", str(src / "a.txt"), (str(out / "a.txt"),))]
        ...     first = run_batch("upper", tasks, copy_job, {}, out, workers=1, progress=False, log=lambda m: None)
        ...     again = run_batch("upper", tasks, copy_job, {}, out, workers=1, progress=False, log=lambda m: None)
        ...     (first.counts["done"], again.counts["skipped"], (out / "a.txt").read_text())
        (1, 1, 'HELLO')
    """
    if engine not in ENGINES:
        raise BatchError(f"engine must be one of {ENGINES}; got {engine!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers must be an int >= 1 or None; got {workers!r}")
    if log is None:
        log = _default_log
    out = Path(out_dir).resolve()
    source_root = Path(input_path).resolve() if input_path is not None else None
    env = distributed_env(environ)
    if engine == "ray" and env.world_size > 1:
        raise BatchError(
            "--engine ray runs one driver that spreads the tasks over the Ray cluster: do not combine it "
            f"with torchrun (WORLD_SIZE={env.world_size})"
        )
    if engine == "ray":
        require_ray()  # fail before doing anything when Ray is missing
    report_file = Path(report_path).resolve() if report_path is not None else out / f"{command}-report.json"
    if source_root is not None and source_root.is_dir() and _inside(report_file, source_root):
        raise BatchError(f"report {report_file} would be written inside the input folder {source_root}")
    options = json.loads(json.dumps(dict(options), allow_nan=True))  # a JSON-clean copy
    fingerprint = _fingerprint(command, options)
    out.mkdir(parents=True, exist_ok=True)

    group = _Group(env)
    try:
        if group.active:
            tasks = group.broadcast(list(tasks))
        mine = shard(list(tasks), env.rank, env.world_size)
        n_workers = (
            workers if workers is not None else (default_workers(env.local_world_size) if engine == "process" else None)
        )
        report = BatchReport(
            command,
            str(source_root) if source_root else "",
            str(out),
            options,
            engine,
            n_workers or 0,
            env.rank,
            env.world_size,
            total=len(mine),
        )
        run_key = _fingerprint(command, {"options": options, "tasks": [t.name for t in tasks], "world": env.world_size})
        start = time.perf_counter()

        # Plan: refuse outputs inside the input, outputs claimed twice; skip what is complete.
        todo: list[Task] = []
        claimed: dict[str, str] = {}
        for task in tasks:  # every task (not only this rank's), so each rank sees the same collisions
            for p in task.outputs:
                claimed.setdefault(str(Path(p).resolve()), task.name)
        for task in mine:
            outs = [Path(p).resolve() for p in task.outputs]
            rel = [_relative(str(p), out) for p in outs]
            problem = None
            for p in outs:
                if source_root is not None and (_inside(p, source_root) if source_root.is_dir() else p == source_root):
                    problem = f"output {p} would be written inside the input {source_root}; inputs are never written"
                elif p == Path(task.source).resolve():
                    problem = f"output {p} would replace its own input"
                elif claimed[str(p)] != task.name:
                    problem = f"output {rel[outs.index(p)]} is also the output of {claimed[str(p)]}; rename one input"
                if problem:
                    break
            if problem:
                report.failed.append({"input": task.name, "outputs": rel, "error": f"BatchError: {problem}"})
            elif not force and _is_complete(task, _marker_path(out, command, task.name), fingerprint, rel):
                report.skipped.append(
                    {
                        "input": task.name,
                        "outputs": rel,
                        "reason": "complete: outputs exist and match the options and the input",
                    }
                )
            else:
                todo.append(task)
        # The input's state as the job will see it: a change during the job makes the next run redo it.
        states: dict[str, Any] = {}
        for task in todo:
            with contextlib.suppress(OSError):  # a missing input fails in the job, with the job's message
                states[task.name] = _source_state(Path(task.source))

        show = progress if env.rank == 0 else False
        bar = _progress_bar(command, len(mine), len(mine) - len(todo), show)
        if n_workers is not None:
            n_workers = min(n_workers, max(1, len(todo)))
        threads = (
            1 if (n_workers or 2) > 1 else (default_workers(env.local_world_size) if env.local_world_size > 1 else None)
        )

        def on_result(task: Task, result: dict[str, Any]) -> None:
            record(task, result)
            bar.update(1)

        def record(task: Task, result: dict[str, Any]) -> None:
            rel = [_relative(p, out) for p in task.outputs]
            if result["ok"]:
                write_json(
                    _marker_path(out, command, task.name),
                    {
                        "command": command,
                        "input": task.name,
                        "fingerprint": fingerprint,
                        "options": options,
                        "source_state": states.get(task.name),
                        "outputs": rel,
                        "finished": _now(),
                    },
                )
                report.done.append(
                    {
                        "input": task.name,
                        "outputs": rel,
                        "seconds": round(result["seconds"], 4),
                        **result.get("info", {}),
                    }
                )
            if not result["ok"]:
                report.failed.append({"input": task.name, "outputs": rel, "error": result["error"]})
                log(f"{command}: failed {task.name}: {result['error']}")

        if todo:
            if engine == "ray" or (n_workers or 1) > 1:
                _check_picklable(job, todo[0], options)
            with _Stop(log).installed() as stop:
                try:
                    if engine == "ray":
                        report.workers = _run_ray(todo, job, options, workers, threads, on_result, ray_address, stop)
                    elif n_workers == 1:
                        _run_inline(todo, job, options, threads, on_result, stop)
                    else:
                        _run_pool(todo, job, options, int(n_workers or 1), threads, on_result, log, preload, stop)
                except KeyboardInterrupt:
                    stop.requested = max(stop.requested, 1)
                if stop.requested:
                    report.interrupted = True
                    finished = {e["input"] for e in report.done} | {e["input"] for e in report.failed}
                    report.not_finished = [t.name for t in todo if t.name not in finished]
                    log(f"{command}: interrupted; completed outputs are kept, rerun the same command to resume")
        bar.close()
        report.finished = _now()
        report.seconds = time.perf_counter() - start
        for key in ("done", "skipped", "failed"):
            getattr(report, key).sort(key=lambda e: e["input"])

        if env.world_size == 1:
            write_json(report_file, report.to_dict())
            return report
        write_json(_part_path(report_file, env.rank), {**report.to_dict(), "run_key": run_key})
        if group.active:
            try:
                parts = group.gather(report.to_dict(), env.rank, env.world_size)
            except Exception as error:  # another rank died: keep this rank's part
                log(f"{command}: could not gather the other ranks' reports ({error}); see {_part_path(report_file, 0)}")
                return report
            if env.rank == 0 and parts is not None:
                merged = merge_reports([BatchReport.from_dict(p) for p in parts])
                write_json(report_file, merged.to_dict())
                return merged
            return report
        merged = _merge_parts_on_disk(report_file, report, run_key)
        if merged is not None:
            write_json(report_file, merged.to_dict())
        return report
    finally:
        group.close()


def _default_log(message: str) -> None:
    try:
        from tqdm import tqdm

        tqdm.write(message, file=sys.stderr)
    except ImportError:
        print(message, file=sys.stderr)


class _NoBar:
    def update(self, n: int) -> None:
        pass

    def close(self) -> None:
        pass


def _progress_bar(command: str, total: int, initial: int, show: bool | None) -> Any:
    if show is False:
        return _NoBar()
    try:
        from tqdm import tqdm
    except ImportError:
        return _NoBar()
    # disable=None: tqdm turns itself off when stderr is not a terminal (logs, CI, pipes).
    return tqdm(
        total=total,
        initial=initial,
        desc=command,
        unit="file",
        disable=None if show is None else not show,
        dynamic_ncols=True,
        file=sys.stderr,
    )


def _check_picklable(job: JobFunction, task: Task, options: Mapping[str, Any]) -> None:
    try:
        pickle.dumps((job, task, options))
    except (pickle.PicklingError, AttributeError, TypeError) as error:
        raise BatchError(
            f"the job {getattr(job, '__qualname__', job)!r} cannot be sent to worker processes ({error}); define it "
            "at module level"
        ) from error
