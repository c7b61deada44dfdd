""":func:`run_batch`: plan (which tasks are this rank's and which still need doing), execute, finish (report)."""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from torch_modulo._atomic import remove_stale_temporaries, write_json
from torch_modulo._checks import check_int
from torch_modulo.batch.distributed import (
    DistributedEnv,
    agree,
    collect_parts,
    distributed_env,
    merge_parts_on_disk,
    merge_with_missing,
    new_launch_token,
    part_path,
)
from torch_modulo.batch.distributed import balance as balance_weights
from torch_modulo.batch.engines import (
    ENGINES,
    Stop,
    check_picklable,
    default_log,
    default_workers,
    progress_bar,
    require_ray,
    run_inline,
    run_pool,
    run_ray,
)
from torch_modulo.batch.markers import fingerprint, is_complete, marker_path, source_state, write_marker
from torch_modulo.batch.report import BatchReport, now
from torch_modulo.batch.tasks import BatchError, JobFunction, Task, inside

__all__ = ["run_batch", "source_bytes"]


def source_bytes(task: Task) -> float:
    """The default weight of a task when ranks share the work: its input's size in bytes (0 if unreadable)."""
    path = Path(task.source)
    try:
        if not path.is_dir():
            return float(path.stat().st_size)
        return float(sum(size for _, size, _ in source_state(path)))
    except OSError:
        return 0.0


@dataclass
class _Run:
    """Everything the three stages of a batch share."""

    command: str
    job: JobFunction
    options: dict[str, Any]
    out: Path
    source_root: Path | None
    report_file: Path
    env: DistributedEnv
    engine: str
    log: Callable[[str], None]
    key: str = ""
    tasks: list[Task] = field(default_factory=list)
    shares: dict[int, list[str]] = field(default_factory=dict)
    launch: str | None = None
    run_key: str = ""
    todo: list[Task] = field(default_factory=list)
    states: dict[str, Any] = field(default_factory=dict)
    report: BatchReport | None = None
    start: float = field(default_factory=time.perf_counter)


def _relative(path: str | Path, out_dir: Path) -> str:
    try:
        return Path(path).relative_to(out_dir).as_posix()
    except ValueError:
        return str(path)


def _problem(
    task: Task, target: Path, run: _Run, claimed: Mapping[str, str], holders: Mapping[str, set[str]]
) -> str | None:
    """Why ``task`` may not write ``target`` (inside the input, its own input, another task's output, or nested
    with one), or None. ``holders``: the folders above every claimed output, up to the output folder, with the
    tasks whose outputs lie below each."""
    root = run.source_root
    if root is not None and (inside(target, root) if root.is_dir() else target == root):
        return f"output {target} would be written inside the input {root}; inputs are never written"
    try:
        own = Path(task.source).resolve()
    except (OSError, RuntimeError):  # a link that points to itself: its job fails, naming it
        own = Path(os.path.abspath(task.source))
    if target == own:
        return f"output {target} would replace its own input"
    if claimed[str(target)] != task.name:
        return f"output {_relative(target, run.out)} is also the output of {claimed[str(target)]}; rename one input"
    # A scene a.exr beside a folder a/ holding x.exr: the stack folder a/ would hold the stack a/x/.
    other = next(
        (claimed[str(p)] for p in _folders_above(target, run.out) if claimed.get(str(p), task.name) != task.name), None
    )
    if other is None:
        other = next((name for name in sorted(holders.get(str(target), ())) if name != task.name), None)
    if other is not None:
        rel = _relative(target, run.out)
        return f"output {rel} and the output of {other} would lie one inside the other; rename one input"
    return None


def _beside_its_input(run: _Run) -> bool:
    """Whether the input is one file and the output folder is its own folder, where the user's other files are."""
    root = run.source_root
    return root is not None and root.is_file() and run.out == root.parent


def _foreign(run: _Run, task: Task, outs: Sequence[Path]) -> str | None:
    """In the input's own folder, an output that exists but that no run of this command wrote (no done marker)
    is the user's file: why it may not be replaced, or None (also when the files cannot be looked at: a name too
    long; the job then fails with the system's reason)."""
    try:
        if marker_path(run.out, run.command, task.name).is_file():
            return None
        there = next((p for p in outs if p.exists()), None)
    except OSError:
        return None
    if there is None:
        return None
    return (
        f"output {there} exists and no run of torch-modulo {run.command} wrote it; it is not replaced "
        "(move it, choose another output folder, or use --force)"
    )


def _folders_above(path: Path, out: Path) -> list[Path]:
    """The folders between ``path`` and the output folder ``out`` (excluded); none when ``path`` is not under it."""
    if out not in path.parents:
        return []
    return list(path.parents[: path.parents.index(out)])


def _complete(run: _Run, task: Task) -> bool:
    rel = [_relative(Path(p).resolve(), run.out) for p in task.outputs]
    return is_complete(task, marker_path(run.out, run.command, task.name), run.key, rel)


def _share(run: _Run, tasks: list[Task], weigh: Callable[[Task], float], force: bool, launch: bool) -> dict[str, Any]:
    """The plan every rank follows: the task list, each task's rank, and (with ``launch``) a launch token.

    When rank 0 plans for ranks that run together, complete tasks weigh nothing, so a resumed run shares out
    the work that is left."""
    if run.env.world_size == 1:
        return {"tasks": tasks, "ranks": [0] * len(tasks), "launch": None}
    weights = [0.0 if launch and not force and _complete(run, t) else float(weigh(t)) for t in tasks]
    return {
        "tasks": tasks,
        "ranks": balance_weights(weights, run.env.world_size),
        "launch": new_launch_token() if launch else None,
    }


def _plan(
    run: _Run,
    tasks: Sequence[Task],
    workers: int | None,
    force: bool,
    weigh: Callable[[Task], float],
) -> list[Task]:
    """Agree on the shares, then sort this rank's tasks into failed (bad outputs), skipped (complete) and to do;
    remove what killed runs left beside this rank's outputs. Returns this rank's tasks."""
    env = run.env
    if env.world_size == 1:
        plan = _share(run, list(tasks), weigh, force, False)
    else:
        plan = agree(env, lambda: _share(run, list(tasks), weigh, force, env.master))
    run.tasks, run.launch = list(plan["tasks"]), plan["launch"]
    for task, rank in zip(run.tasks, plan["ranks"], strict=True):
        run.shares.setdefault(rank, []).append(task.name)
    mine = [t for t, r in zip(run.tasks, plan["ranks"], strict=True) if r == env.rank]
    n_workers = (
        workers if workers is not None else (default_workers(env.local_world_size) if run.engine == "process" else None)
    )
    run.report = report = BatchReport(
        run.command,
        str(run.source_root) if run.source_root else "",
        str(run.out),
        run.options,
        run.engine,
        n_workers or 0,
        env.rank,
        env.world_size,
        total=len(mine),
    )
    names = [t.name for t in run.tasks]
    run.run_key = fingerprint(
        run.command, {"options": run.options, "tasks": names, "ranks": plan["ranks"], "world": env.world_size}
    )

    claimed: dict[str, str] = {}
    holders: dict[str, set[str]] = {}
    for task in run.tasks:  # every task (not only this rank's), so each rank sees the same collisions
        for p in task.outputs:
            resolved = Path(p).resolve()
            claimed.setdefault(str(resolved), task.name)
            for folder in _folders_above(resolved, run.out):
                holders.setdefault(str(folder), set()).add(task.name)
    beside = _beside_its_input(run)  # once: it stats the input
    for task in mine:
        outs = [Path(p).resolve() for p in task.outputs]
        rel = [_relative(p, run.out) for p in outs]
        problem = next((why for why in (_problem(task, p, run, claimed, holders) for p in outs) if why), None)
        if problem is None and not force and beside:
            problem = _foreign(run, task, outs)
        if problem:
            report.failed.append({"input": task.name, "outputs": rel, "error": f"BatchError: {problem}"})
            run.log(f"{run.command}: failed {task.name}: BatchError: {problem}")  # as a job's failure is
        elif not force and _complete(run, task):
            reason = "complete: outputs exist and match the options and the input"
            report.skipped.append({"input": task.name, "outputs": rel, "reason": reason})
        else:
            run.todo.append(task)
    if beside:  # a marker before the job: after a kill, its outputs are still this command's
        for task in run.todo:
            with contextlib.suppress(OSError):
                write_json(marker_path(run.out, run.command, task.name), {"command": run.command, "pending": True})
    # The input's state as the job will see it: a change during the job makes the next run redo it.
    for task in run.todo:
        with contextlib.suppress(OSError):  # a missing input fails in the job, with the job's message
            run.states[task.name] = source_state(Path(task.source))

    finals = [run.report_file, part_path(run.report_file, env.rank)]
    for task in mine:
        finals += [Path(p) for p in task.outputs] + [marker_path(run.out, run.command, task.name)]
    removed = remove_stale_temporaries(finals)
    if removed:
        run.log(f"{run.command}: removed {len(removed)} temporary file(s) or folder(s) left by a killed run")
    return mine


def _execute(
    run: _Run,
    mine: Sequence[Task],
    workers: int | None,
    progress: bool | None,
    ray_address: str | None,
    preload: Sequence[str],
) -> None:
    """Run the tasks to do with the chosen engine; record each result (and its done marker) as it arrives."""
    report, env = run.report, run.env
    assert report is not None
    n_workers: int | None = report.workers or None
    if n_workers is not None:
        n_workers = min(n_workers, max(1, len(run.todo)))
    threads = (
        1 if (n_workers or 2) > 1 else (default_workers(env.local_world_size) if env.local_world_size > 1 else None)
    )
    bar = progress_bar(run.command, len(mine), len(mine) - len(run.todo), progress if env.rank == 0 else False)

    def on_result(task: Task, result: dict[str, Any]) -> None:
        _record(run, task, result)
        bar.update(1)

    try:
        if not run.todo:
            return
        if run.engine == "ray" or (n_workers or 1) > 1:
            check_picklable(run.job, run.todo[0], run.options)
        with Stop(run.log).installed() as stop:
            try:
                if run.engine == "ray":
                    report.workers = run_ray(
                        run.todo, run.job, run.options, workers, threads, on_result, ray_address, stop
                    )
                elif n_workers == 1:
                    run_inline(run.todo, run.job, run.options, threads, on_result, stop)
                else:
                    run_pool(run.todo, run.job, run.options, int(n_workers or 1), threads, on_result, preload, stop)
            except KeyboardInterrupt:
                stop.requested = max(stop.requested, 1)
            if stop.requested:
                report.interrupted = True
                finished = {e["input"] for e in report.done} | {e["input"] for e in report.failed}
                report.not_finished = [t.name for t in run.todo if t.name not in finished]
                run.log(f"{run.command}: interrupted; completed outputs are kept, rerun the same command to resume")
    finally:
        bar.close()


def _record(run: _Run, task: Task, result: dict[str, Any]) -> None:
    report = run.report
    assert report is not None
    rel = [_relative(p, run.out) for p in task.outputs]
    if result["ok"]:
        marker = marker_path(run.out, run.command, task.name)
        try:
            write_marker(marker, run.command, task, run.key, run.options, run.states.get(task.name), rel, now())
        except OSError as error:
            result = {
                "ok": False,
                "error": f"{type(error).__name__}: {error} (the outputs were written but their done marker was not; "
                "the next run redoes this input)",
            }
    if result["ok"]:
        info = dict(result.get("info", {}))
        for warning in info.get("warnings", ()):
            run.log(f"{run.command}: {task.name}: {warning}")
        report.done.append({"input": task.name, "outputs": rel, "seconds": round(result["seconds"], 4), **info})
    else:
        report.failed.append({"input": task.name, "outputs": rel, "error": result["error"]})
        run.log(f"{run.command}: failed {task.name}: {result['error']}")


def _write(run: _Run, path: Path, data: Mapping[str, Any], report: BatchReport) -> None:
    """Write a report file; a failure becomes one of ``report.errors`` (the exit code is then not 0)."""
    try:
        write_json(path, data)
    except OSError as error:
        message = f"the report could not be written: {type(error).__name__}: {error}"
        report.errors.append(message)
        run.log(f"{run.command}: error: {message}")


def _finish(run: _Run, merge_timeout: float | None, skipped: Sequence[Mapping[str, Any]] = ()) -> BatchReport:
    """Write the report (one process) or this rank's part, and merge the parts (see the distributed module).

    ``skipped``: inputs the caller left out of the run, with the reason, counted in rank 0's part (so once in the
    merged report)."""
    report, env = run.report, run.env
    assert report is not None
    if skipped and env.rank == 0:
        report.skipped.extend(dict(entry) for entry in skipped)
        report.total += len(skipped)
    report.finished = now()
    report.seconds = time.perf_counter() - run.start
    report.sort()
    if env.world_size == 1:
        _write(run, run.report_file, report.to_dict(), report)
        return report
    own = part_path(run.report_file, env.rank)
    _write(run, own, {**report.to_dict(), "run_key": run.run_key, "launch": run.launch}, report)
    if run.launch is None:  # ranks that may run one after the other: the last one merges
        merged = merge_parts_on_disk(run.report_file, env.world_size, run.run_key)
        if merged is not None:
            _write(run, run.report_file, merged.to_dict(), report)
        return report
    if env.rank != 0:
        return report
    with Stop(run.log).installed() as stop:
        stop.message = "interrupted while waiting for the other ranks' report parts"
        found, missing = collect_parts(
            run.report_file,
            env.world_size,
            run.launch,
            timeout=merge_timeout,
            stopped=lambda: bool(stop.requested),
            log=run.log,
        )
    found[0] = report  # this rank's own part, even if it could not be written
    why = "before rank 0 was stopped" if stop.requested or merge_timeout is None else f"within {merge_timeout:g} s"
    merged = merge_with_missing(found, [r for r in missing if r != 0], run.shares, run.report_file, why)
    merged.interrupted = merged.interrupted or bool(stop.requested)
    for error in merged.errors:
        if error.startswith("rank "):
            run.log(f"{run.command}: error: {error}")
    _write(run, run.report_file, merged.to_dict(), merged)
    return merged


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
    weigh: Callable[[Task], float] = source_bytes,
    merge_timeout: float | None = None,
    skipped: Sequence[Mapping[str, Any]] = (),
) -> BatchReport:
    """Run ``job`` once per task that is not complete yet; write the done markers and the JSON report.

    Args:
        command: the command's name (report, done markers; ``"tonemap"``).
        tasks: every input of the batch (all ranks pass the same list; see :mod:`torch_modulo.batch.distributed`).
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
        weigh: what a task costs, to share the tasks between ranks (default: the input's size in bytes).
        merge_timeout: seconds rank 0 waits for the other ranks' report parts after its own work (default: as
            long as they run; torchrun stops rank 0 when another rank fails).
        skipped: report entries (``input``, ``outputs``, ``reason``) of inputs the caller left out of ``tasks``
            (``tonemap``: frames, confidence maps): counted as skipped in the report, once (in rank 0's part).

    Returns:
        The report (on rank 0 of a torchrun launch, the merged report of every rank).

    Raises:
        BatchError: unknown engine, a job that cannot be sent to worker processes, Ray missing, bad ranks.
        TypeError, ValueError: bad ``workers``.

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
    if workers is not None:
        workers = check_int(workers, "workers", 1, what="an int >= 1 or None")
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
    if source_root is not None and source_root.is_dir() and inside(report_file, source_root):
        raise BatchError(f"report {report_file} would be written inside the input folder {source_root}")
    clean = json.loads(json.dumps(dict(options), allow_nan=True))  # a JSON-clean copy
    run = _Run(command, job, clean, out, source_root, report_file, env, engine, log or default_log)
    run.key = fingerprint(command, clean)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as error:  # a file in the way, a read-only mount: a usage error, not a traceback
        raise BatchError(f"cannot create the output folder {out}: {error.strerror or error}") from error

    mine = _plan(run, tasks, workers, force, weigh)
    _execute(run, mine, workers, progress, ray_address, preload)
    return _finish(run, merge_timeout, skipped)
