"""The batch report: what was done, skipped and failed, and the exit code a command line returns."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

__all__ = ["BatchReport", "merge_reports", "now"]


def now() -> str:
    """The current UTC time in ISO format, to the second."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")  # noqa: UP017 (keep 3.10 readers happy)


@dataclass
class BatchReport:
    """What a batch did. ``to_dict()`` is the JSON report; ``exit_code`` is what the command line returns.

    Fields ``done``, ``skipped`` and ``failed`` are lists of dicts with the task's ``input`` name and ``outputs``
    (relative to the output folder), plus ``seconds`` and the job's info (done), ``reason`` (skipped) or
    ``error`` (failed). ``not_finished`` lists the inputs not known to be finished: those an interruption left
    undone, and those of a rank whose part of the report never arrived. ``errors`` lists what went wrong with
    the batch itself rather than with one input (a report or a rank's part that could not be written or never
    arrived); it appears in the JSON only when not empty.

    Example:
        >>> report = BatchReport("tonemap", "in", "out", {}, total=2)
        >>> report.done.append({"input": "a.exr"})
        >>> report.failed.append({"input": "b.exr", "error": "OSError: cannot read image b.exr"})
        >>> report.summary(), report.exit_code
        ('tonemap: 1 done, 0 skipped, 1 failed of 2', 1)
    """

    command: str
    input: str
    output: str
    options: dict[str, Any]
    engine: str = "process"
    workers: int = 1
    rank: int = 0
    world_size: int = 1
    started: str = field(default_factory=now)
    finished: str | None = None
    seconds: float = 0.0
    interrupted: bool = False
    total: int = 0
    done: list[dict[str, Any]] = field(default_factory=list)
    skipped: list[dict[str, Any]] = field(default_factory=list)
    failed: list[dict[str, Any]] = field(default_factory=list)
    not_finished: list[str] = field(default_factory=list)
    parts: list[int] | None = None  # ranks merged into this report
    errors: list[str] = field(default_factory=list)

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
        return 1 if self.failed or self.errors or self.not_finished else 0

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
        if self.errors:
            data["errors"] = self.errors
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
        elif c["not_finished"]:
            text += f"; {c['not_finished']} not known to be finished"
        if self.errors:
            text += "; " + "; ".join(self.errors)
        return text

    def sort(self) -> None:
        """Sort every list by input name."""
        for key in ("done", "skipped", "failed"):
            getattr(self, key).sort(key=lambda e: e["input"])
        self.not_finished.sort()


def merge_reports(parts: Sequence[BatchReport]) -> BatchReport:
    """One report from the ranks' parts (sorted by input name; the run spans the earliest start to the last end).

    Example:
        >>> parts = [BatchReport("c", "i", "o", {}, rank=r, world_size=2, total=1) for r in (1, 0)]
        >>> parts[0].done.append({"input": "b"})
        >>> parts[1].done.append({"input": "a"})
        >>> merged = merge_reports(parts)
        >>> [e["input"] for e in merged.done], merged.parts, merged.total
        (['a', 'b'], [0, 1], 2)
    """
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
    merged.errors = [e for p in parts for e in p.errors]
    return merged
