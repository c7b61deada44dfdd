"""Done markers: how a rerun knows which inputs are complete.

After a task succeeds the engine writes ``OUT/.torch-modulo/<command>/<input name>.json`` (atomically) recording
the options, the input's size and modification time, and the outputs. A task is *complete*, and skipped by the
next run, when its marker exists, matches the current options and input, and every output exists.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from torch_modulo._atomic import write_json
from torch_modulo.batch.tasks import Task

__all__ = ["MARKER_FOLDER", "fingerprint", "is_complete", "marker_path", "source_state", "write_marker"]

#: Hidden folder inside the output folder that holds the done markers.
MARKER_FOLDER = ".torch-modulo"


def source_state(path: Path) -> Any:
    """What identifies an input's content cheaply: size and modification time (of every file in a folder).

    Hidden files and linked folders inside an input folder are left out.
    """
    stat = path.stat()
    if not path.is_dir():
        return [stat.st_size, stat.st_mtime_ns]
    state: list[list[Any]] = []
    for folder, dirs, files in os.walk(path):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in sorted(files):
            if name.startswith("."):
                continue
            item = Path(folder, name)
            if not item.is_file():
                continue
            s = item.stat()
            state.append([item.relative_to(path).as_posix(), s.st_size, s.st_mtime_ns])
    state.sort(key=lambda entry: entry[0])
    return state


def fingerprint(command: str, options: Mapping[str, Any]) -> str:
    """A hash of the command and the options that decide the outputs (names starting with ``_`` do not).

    Example:
        >>> fingerprint("tonemap", {"op": "log"}) == fingerprint("tonemap", {"op": "log", "_workers": 4})
        True
    """
    kept = {k: v for k, v in options.items() if not k.startswith("_")}
    text = json.dumps({"command": command, "options": kept}, sort_keys=True, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def marker_path(out_dir: Path, command: str, name: str) -> Path:
    """Where the done marker of input ``name`` goes."""
    return out_dir / MARKER_FOLDER / command / f"{name}.json"


def is_complete(task: Task, marker: Path, key: str, outputs: Sequence[str]) -> bool:
    """Whether ``task``'s marker matches the fingerprint ``key``, its input is unchanged and every output exists."""
    try:
        data = json.loads(marker.read_text())
    except (OSError, ValueError):
        return False
    if not isinstance(data, dict) or data.get("fingerprint") != key:
        return False
    if data.get("outputs") != list(outputs) or not all(Path(p).exists() for p in task.outputs):
        return False
    try:
        return data.get("source_state") == source_state(Path(task.source))
    except OSError:
        return False


def write_marker(
    marker: Path,
    command: str,
    task: Task,
    key: str,
    options: Mapping[str, Any],
    state: Any,
    outputs: Sequence[str],
    finished: str,
) -> None:
    """Write ``task``'s done marker atomically.

    Raises:
        OSError: the marker cannot be written (the message has the system's text and the marker's final path).
    """
    write_json(
        marker,
        {
            "command": command,
            "input": task.name,
            "fingerprint": key,
            "options": dict(options),
            "source_state": state,
            "outputs": list(outputs),
            "finished": finished,
        },
    )
