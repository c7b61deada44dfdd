"""Several processes or machines (``torchrun``): who takes which inputs, and how the ranks' reports become one.

Under ``torchrun`` (or any launcher that sets ``RANK`` and ``WORLD_SIZE``) every rank runs the same batch on its
share of the inputs, and no process group stays open while the jobs run, so a rank that finishes hours after the
others breaks nothing:

1. **Agree.** When ``MASTER_ADDR`` and ``MASTER_PORT`` are set (torchrun sets them), the ranks join a ``gloo``
   process group for one broadcast at start-up and leave it: rank 0 sends its task list, the share of each rank
   and a token naming this launch. Without them each rank computes the same shares from the same sorted list.
2. **Balance.** The shares balance the work, not the count: each input weighs what the command says it costs
   (the number of values in the file for the command line, its size in bytes by default), and the heaviest
   inputs are dealt first, each to the rank with the least work so far (:func:`balance`). Equal weights give
   the stride ``tasks[rank::world_size]`` of ``DistributedSampler(shuffle=False)``, without its padding.
3. **Report.** Every rank writes its own part, ``<report stem>.rank<r>.json``. Rank 0 then waits for the other
   parts of the same launch on disk (:func:`collect_parts`) and merges them into the report. A part that never
   arrives (its rank died, or ``merge_timeout`` passed, or rank 0 was stopped while waiting) is named in the
   report's ``errors``, its inputs are listed as ``not_finished`` and the exit code is not 0. Without a launch
   token (no ``MASTER_ADDR``: ranks may run one after the other) no rank waits; the last one to finish merges
   the parts it finds.

Every machine needs the same view of the input and output folders (a shared file system).
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from torch_modulo.batch.report import BatchReport, merge_reports
from torch_modulo.batch.tasks import BatchError

__all__ = [
    "DistributedEnv",
    "agree",
    "balance",
    "collect_parts",
    "distributed_env",
    "merge_parts_on_disk",
    "part_path",
    "shard",
]

_WAIT_POLL_S = 0.5


@dataclass(frozen=True)
class DistributedEnv:
    """Where this process stands in a ``torchrun`` (or similar) launch; one process alone is rank 0 of 1."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    local_world_size: int = 1
    master: bool = False  # MASTER_ADDR and MASTER_PORT set: the ranks run together and can agree at start-up


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
    """This rank's share by stride, ``items[rank::world_size]``: the order ``DistributedSampler(shuffle=False)``
    uses (what :func:`balance` gives for equal weights).

    Example:
        >>> shard(list("abcde"), 0, 2), shard(list("abcde"), 1, 2)
        (['a', 'c', 'e'], ['b', 'd'])
    """
    if world_size < 1 or not 0 <= rank < world_size:
        raise ValueError(f"rank must lie in [0, world_size); got rank={rank}, world_size={world_size}")
    return list(items[rank::world_size])


def balance(weights: Sequence[float], world_size: int) -> list[int]:
    """The rank of each item: heaviest first, each to the rank with the least weight so far (ties: lowest rank).

    This is the longest-processing-time rule; no rank ends with more than the average plus the heaviest item.
    Equal weights give the stride ``rank = index % world_size``.

    Example:
        >>> balance([1, 1, 1, 1, 1], 2)
        [0, 1, 0, 1, 0]
        >>> balance([9, 1, 1, 1, 5, 3], 2)  # 9 + 1 against 5 + 3 + 1 + 1
        [0, 1, 0, 1, 1, 1]
    """
    if world_size < 1:
        raise ValueError(f"world_size must be >= 1; got {world_size}")
    loads = [0.0] * world_size
    ranks = [0] * len(weights)
    for index in sorted(range(len(weights)), key=lambda i: (-float(weights[i]), i)):
        rank = min(range(world_size), key=lambda r: (loads[r], r))
        ranks[index] = rank
        loads[rank] += max(0.0, float(weights[index]))
    return ranks


def agree(env: DistributedEnv, plan: Callable[[], Any]) -> Any:
    """``plan()`` as rank 0 computes it, on every rank.

    With a launch that can form a process group (:attr:`DistributedEnv.master`) rank 0 computes it and
    broadcasts it through a short-lived ``gloo`` group (or the caller's own group, left open); otherwise every
    rank computes it itself.
    """
    if not env.master:
        return plan()
    import torch.distributed as dist

    if not dist.is_available():
        return plan()
    owned = not dist.is_initialized()
    if owned:
        dist.init_process_group("gloo", rank=env.rank, world_size=env.world_size)
    try:
        box = [plan() if env.rank == 0 else None]
        dist.broadcast_object_list(box, src=0)
        return box[0]
    finally:
        if owned:
            with contextlib.suppress(Exception):
                dist.destroy_process_group()


def new_launch_token() -> str:
    """A token that names one launch (rank 0 draws it; parts of other launches never carry it)."""
    return secrets.token_hex(8)


def part_path(report_path: Path, rank: int) -> Path:
    """Where rank ``rank`` writes its part of the report."""
    return report_path.with_name(f"{report_path.stem}.rank{rank}{report_path.suffix}")


def _read_part(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def collect_parts(
    report_path: Path,
    world_size: int,
    launch: str,
    *,
    timeout: float | None = None,
    stopped: Callable[[], bool] = lambda: False,
    log: Callable[[str], None] | None = None,
) -> tuple[dict[int, BatchReport], list[int]]:
    """Wait for every rank's part of launch ``launch`` on disk; returns the parts found and the ranks missing.

    Waits until every part is there, ``timeout`` seconds pass (None: no limit), or ``stopped()`` is true (a
    Ctrl-C or SIGTERM: torchrun sends one when another rank fails).
    """
    start = time.monotonic()
    found: dict[int, BatchReport] = {}
    told = False
    while True:
        for rank in range(world_size):
            if rank in found:
                continue
            data = _read_part(part_path(report_path, rank))
            if data is not None and data.get("launch") == launch:
                found[rank] = BatchReport.from_dict(data)
        missing = [r for r in range(world_size) if r not in found]
        if not missing or stopped() or (timeout is not None and time.monotonic() - start >= timeout):
            return found, missing
        if log is not None and not told:
            log(f"waiting for the report parts of rank(s) {', '.join(map(str, missing))}")
            told = True
        time.sleep(_WAIT_POLL_S if timeout is None else min(_WAIT_POLL_S, max(0.01, timeout / 10)))


def merge_with_missing(
    found: Mapping[int, BatchReport],
    missing: Sequence[int],
    shares: Mapping[int, Sequence[str]],
    report_path: Path,
    why: str,
) -> BatchReport:
    """Merge the parts found; each missing rank becomes an error, and its inputs ``not_finished``."""
    merged = merge_reports([found[r] for r in sorted(found)])
    for rank in missing:
        merged.errors.append(f"rank {rank} wrote no report part ({part_path(report_path, rank)}) {why}")
        merged.not_finished.extend(shares.get(rank, ()))
        merged.total += len(shares.get(rank, ()))
    merged.not_finished.sort()
    return merged


def merge_parts_on_disk(report_path: Path, world_size: int, run_key: str) -> BatchReport | None:
    """Without a launch token: the merged report when every rank's part of this run is on disk, else None."""
    parts = []
    for rank in range(world_size):
        data = _read_part(part_path(report_path, rank))
        if data is None or data.get("run_key") != run_key:
            return None
        parts.append(BatchReport.from_dict(data))
    return merge_reports(parts)
