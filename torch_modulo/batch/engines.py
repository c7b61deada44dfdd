"""Where the jobs run: in this process, in a local process pool, or as Ray tasks; and how Ctrl-C stops them.

- ``"process"``: ``workers`` processes from a ``forkserver`` pool (``spawn`` where there is no forkserver), or the
  calling process itself when one worker is enough. Workers ignore SIGINT from the start (the parent coordinates
  the shutdown, so a Ctrl-C while the pool is still starting stops the batch cleanly too) and run torch with one
  thread each when there are several workers, so that they do not oversubscribe the cores.
- ``"ray"``: one Ray task per input on an existing Ray cluster (``ray.init(address=...)``; the environment
  variable ``RAY_ADDRESS`` or a local Ray when no address is given). Ray is imported only then.

Every engine calls ``on_result(task, result)`` in the calling process for each finished task, where ``result`` is
what :func:`execute` returns: ``{"ok": True, "seconds": ..., "info": {...}}`` or ``{"ok": False, "seconds": ...,
"error": "OSError: ..."}``.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

from torch_modulo._atomic import final_names, free_space_note
from torch_modulo.batch.tasks import BatchError, JobFunction, Task

__all__ = [
    "ENGINES",
    "Stop",
    "check_picklable",
    "default_log",
    "default_workers",
    "execute",
    "progress_bar",
    "require_ray",
    "run_inline",
    "run_pool",
    "run_ray",
]

#: Engines :func:`~torch_modulo.batch.run_batch` accepts.
ENGINES = ("process", "ray")

ResultCallback = Callable[[Task, dict[str, Any]], None]
_POLL_S = 0.2


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


# ------------------------------------------------------------------------------------------- messages


def default_log(message: str) -> None:
    """Print a message on stderr, above the progress bar when there is one."""
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


def progress_bar(command: str, total: int, initial: int, show: bool | None) -> Any:
    """A tqdm bar on stderr (``show=None``: only when stderr is a terminal), or a stand-in that shows nothing."""
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


def check_picklable(job: JobFunction, task: Task, options: Mapping[str, Any]) -> None:
    """Raise :class:`BatchError` unless the job, a task and the options can be sent to worker processes."""
    try:
        pickle.dumps((job, task, options))
    except (pickle.PicklingError, AttributeError, TypeError) as error:
        raise BatchError(
            f"the job {getattr(job, '__qualname__', job)!r} cannot be sent to worker processes ({error}); define it "
            "at module level"
        ) from error


# ------------------------------------------------------------------------------------------- stopping


class Stop:
    """Ctrl-C (SIGINT) and SIGTERM during a batch: the first asks the batch to stop after the running tasks (a flag
    the loops poll, so no result is ever lost half-recorded); the second raises KeyboardInterrupt to abandon them."""

    def __init__(self, log: Callable[[str], None]) -> None:
        self.requested = 0
        self.log = log
        self.message = "interrupted: finishing the running task(s), starting no more (Ctrl-C again to abandon them)"

    def __call__(self, signum: int, frame: Any) -> None:
        self.requested += 1
        if self.requested > 1:
            raise KeyboardInterrupt
        self.log(self.message)

    @contextlib.contextmanager
    def installed(self) -> Iterator[Stop]:
        if threading.current_thread() is not threading.main_thread():  # signals reach the main thread only
            yield self
            return
        previous = {sig: signal.signal(sig, self) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield self
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)


@contextlib.contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Ignore SIGINT while starting helper processes: they inherit the setting and ignore Ctrl-C from birth."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


# ------------------------------------------------------------------------------------------- running one


def _init_worker(threads: int | None) -> None:
    """Pool initializer: leave Ctrl-C to the parent, and keep torch to ``threads`` threads."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if threads is not None:
        import torch

        torch.set_num_threads(threads)


def _error_text(error: BaseException, task: Task) -> str:
    """``"Type: message"`` naming final paths (not temporary ones), with the disk's state when it is full."""
    message = final_names(str(error) or repr(error))
    if task.outputs:
        message += free_space_note(error, Path(task.outputs[0]).parent)
    return f"{type(error).__name__}: {message}"


def execute(job: JobFunction, task: Task, options: Mapping[str, Any], threads: int | None = None) -> dict[str, Any]:
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
        return {"ok": False, "seconds": time.perf_counter() - start, "error": _error_text(error, task)}
    return {"ok": True, "seconds": time.perf_counter() - start, "info": dict(info or {})}


# ------------------------------------------------------------------------------------------- engines


def run_inline(
    tasks: Sequence[Task],
    job: JobFunction,
    options: Mapping[str, Any],
    threads: int | None,
    on_result: ResultCallback,
    stop: Stop,
) -> None:
    """Run in this process, one task after the other, until done or asked to stop."""
    for task in tasks:
        if stop.requested:
            return
        on_result(task, execute(job, task, options, threads))


def _pool_context(preload: Sequence[str]) -> multiprocessing.context.BaseContext:
    methods = multiprocessing.get_all_start_methods()
    ctx = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
    if ctx.get_start_method() == "forkserver":
        # Import the heavy modules once in the fork server rather than in every worker. Never the main module
        # itself (python -m ...): each worker runs it again as __mp_main__, which warns if it was imported before.
        main = getattr(getattr(sys.modules.get("__main__"), "__spec__", None), "name", None)
        modules = ["torch", "torch_modulo.batch", *preload]
        ctx.set_forkserver_preload([m for m in dict.fromkeys(modules) if m != main])
        # Start the fork server now, ignoring Ctrl-C: it imports the modules above (seconds), and a Ctrl-C then
        # would kill it and break the pool; the workers it forks inherit the setting.
        from multiprocessing import forkserver

        with _sigint_ignored():
            forkserver.ensure_running()
    return ctx


#: What a pool that could not start (or broke while starting) raises in the parent.
_START_ERRORS = (BrokenProcessPool, EOFError, ConnectionError, OSError)

#: The error of a task whose worker process died when the pool broke, and again when the task ran alone.
_WORKER_DIED = "BrokenProcessPool: the worker process died (killed, or out of memory), also when this input ran alone"


def _new_pool(workers: int, threads: int | None, preload: Sequence[str]) -> ProcessPoolExecutor:
    executor = ProcessPoolExecutor(
        workers, mp_context=_pool_context(preload), initializer=_init_worker, initargs=(threads,)
    )
    # Start the workers, then the pool's thread, now (as the pool does with "fork") rather than one worker per
    # submit: on Python 3.11 a worker that a submit starts while another dies is never stopped, and the broken pool
    # waits for it forever.
    if hasattr(executor, "_launch_processes") and hasattr(executor, "_start_executor_manager_thread"):
        try:
            executor._launch_processes()
        finally:  # the thread also stops the workers already started
            executor._start_executor_manager_thread()
    return executor


def run_pool(
    tasks: Sequence[Task],
    job: JobFunction,
    options: Mapping[str, Any],
    workers: int,
    threads: int | None,
    on_result: ResultCallback,
    preload: Sequence[str],
    stop: Stop,
) -> None:
    """Run in ``workers`` processes, at most two tasks per worker queued, until done or asked to stop.

    A worker process that dies (killed, out of memory, a crash in a reader) breaks the pool and every task in
    flight with it: those tasks run again in a new pool, one at a time, and one that kills its worker again is
    reported failed; then the rest of the queue goes on.
    """
    queue = list(tasks)
    queue.reverse()
    running: dict[Future[dict[str, Any]], Task] = {}
    alone: list[Task] = []  # in flight when a worker died: run again one at a time (on top of the queue)
    executor: ProcessPoolExecutor | None = None
    try:
        executor = _new_pool(workers, threads, preload)
        while queue or running:
            if stop.requested:
                queue.clear()
                for future in list(running):
                    if future.cancel():  # not started yet
                        running.pop(future)
                if not running:
                    break
            try:
                while queue and len(running) < (1 if alone else 2 * workers):
                    future = executor.submit(execute, job, queue[-1], options, threads)
                    running[future] = queue.pop()
                finished, _ = wait(list(running), timeout=_POLL_S, return_when=FIRST_COMPLETED)
                broken = any(isinstance(f.exception(), BrokenProcessPool) for f in finished)
            except BrokenProcessPool:  # from submit: a worker died since the last wait
                broken = True
            if broken:  # the pool fails every task in flight: wait for them all
                finished, _ = wait(list(running))
            lost: list[Task] = []
            for future in [f for f in running if f in finished]:
                task = running.pop(future)
                try:
                    result = future.result()
                except BrokenProcessPool:
                    lost.append(task)
                    continue
                except Exception as error:  # the result could not come back
                    result = {"ok": False, "seconds": 0.0, "error": f"{type(error).__name__}: {error}"}
                if task in alone:
                    alone.remove(task)
                on_result(task, result)
            if broken and not stop.requested:  # (after a stop, the tasks lost are not finished, as after any stop)
                if lost and lost[0] in alone:  # it ran alone: it is the one that kills its worker
                    alone.remove(lost[0])
                    on_result(lost[0], {"ok": False, "seconds": 0.0, "error": _WORKER_DIED})
                elif lost:
                    stop.log(
                        f"a worker process died (killed, or out of memory): the {len(lost)} task(s) in flight run "
                        "again, one at a time"
                    )
                    alone = lost
                    queue.extend(reversed(lost))
                executor.shutdown(wait=True)
                executor = _new_pool(workers, threads, preload)
                # A pool whose workers die as they start fails this no-op (BrokenProcessPool): a real error, raised
                # below, not an input to blame.
                executor.submit(os.getpid).result()
    except _START_ERRORS:
        if not stop.requested:  # a pool that cannot start without being asked to stop: a real error
            raise
        # Ctrl-C while the pool was starting: the tasks not recorded stay not finished, as after any stop.
    except KeyboardInterrupt:  # asked twice: abandon the running tasks
        if executor is not None:
            for process in list((getattr(executor, "_processes", None) or {}).values()):
                process.terminate()
            executor.shutdown(wait=False, cancel_futures=True)
        raise
    finally:
        if executor is not None:
            with contextlib.suppress(*_START_ERRORS):
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


def run_ray(
    tasks: Sequence[Task],
    job: JobFunction,
    options: Mapping[str, Any],
    workers: int | None,
    threads: int | None,
    on_result: ResultCallback,
    address: str | None,
    stop: Stop,
) -> int:
    """Run one Ray task per input, at most ``workers`` (default: the cluster's CPUs) in flight; returns that
    number."""
    ray = require_ray()
    started_here = False
    if not ray.is_initialized():
        ray.init(address=address)
        started_here = True
    try:
        window = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        remote = ray.remote(num_cpus=1, max_retries=0)(execute)
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
