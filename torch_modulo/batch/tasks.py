"""What a batch works on: :class:`Task` (one input and its outputs, from :mod:`torch_modulo._task`), finding inputs,
and checking the folders.

:func:`discover` lists every input of a folder once: hidden entries are skipped, and symbolic links are followed
without ever entering a folder twice, so a link loop or a second link to the same file cannot repeat an input.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from torch_modulo._task import Task

__all__ = ["BatchError", "JobFunction", "Task", "check_folders", "discover", "inside"]


class BatchError(Exception):
    """A batch cannot start (bad folders, bad distributed environment, missing engine); the message says why."""


#: ``job(task, options) -> info``: a top-level (picklable) function that reads ``task.source`` and writes every
#: path in ``task.outputs`` atomically; it may return a small JSON-compatible dict for the report (a list of
#: strings under ``"warnings"`` is also printed as the batch runs).
JobFunction = Callable[[Task, Mapping[str, Any]], Mapping[str, Any] | None]


def _identity(path: Path) -> tuple[int, int] | None:
    """(device, inode) of what ``path`` points to, or None for a broken link."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_dev, st.st_ino


def discover(
    root: str | os.PathLike[str],
    match: Callable[[Path], bool],
    *,
    descend: Callable[[Path], bool] | None = None,
) -> list[tuple[str, Path]]:
    """Every entry under ``root`` that ``match`` accepts, once, sorted by relative path.

    Hidden entries (names starting with ``.``: temporary files of atomic writes, the done markers) are never
    listed or entered. A matched folder is not entered. If ``root`` is itself a file (or a matching folder), it
    is the only entry, named by its own name.

    Symbolic links are followed, but every real file or folder is taken once: a folder already entered is not
    entered again (so a link loop ends), and an input reached by several names is listed under the name that
    passes through no linked folder, else under the first in sorted order. A broken link that ``match`` accepts is
    listed under its own name (its job then fails, naming it, rather than the input vanishing).

    Args:
        root: the input folder (or one input).
        match: which files or folders are inputs.
        descend: which unmatched folders to enter (default: all).

    Returns:
        ``(name, path)`` pairs, ``name`` relative to ``root`` with ``/`` separators.

    Raises:
        FileNotFoundError: ``root`` does not exist.
        OSError: a folder cannot be listed (the message names it).

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     for name in ("b.exr", "a.exr", "notes.txt", ".tmp.exr", "sub/c.exr"):
        ...         os.makedirs(os.path.dirname(os.path.join(folder, name)), exist_ok=True)
        ...         open(os.path.join(folder, name), "w").close()
        ...     os.symlink(folder, os.path.join(folder, "sub", "loop"))  # a link back to the top
        ...     [name for name, _ in discover(folder, lambda p: p.suffix == ".exr")]
        ['a.exr', 'b.exr', 'sub/c.exr']
    """
    root = Path(root)
    if not root.exists():
        raise FileNotFoundError(f"input not found: {root}")
    if root.is_file() or match(root):
        return [(root.name, root)]
    # Real folders first, then the linked folders they hold (breadth of links, each folder entered once).
    entered: set[tuple[int, int] | None] = {_identity(root)}
    best: dict[tuple[int, int], tuple[bool, str, Path]] = {}  # identity -> (through a link, name, path)
    pending: list[tuple[Path, bool]] = []
    broken: list[tuple[str, Path]] = []

    def walk(folder: Path, linked: bool) -> None:
        try:
            entries = sorted(folder.iterdir(), key=lambda p: p.name)
        except OSError as error:
            raise OSError(f"cannot list {folder}: {error}") from error
        for path in entries:
            if path.name.startswith("."):
                continue
            if match(path):
                key = _identity(path)
                if key is None:  # a broken link: an input all the same, whose job fails naming it
                    broken.append((path.relative_to(root).as_posix(), path))
                    continue
                candidate = (linked or path.is_symlink(), path.relative_to(root).as_posix(), path)
                if key not in best or candidate[:2] < best[key][:2]:
                    best[key] = candidate
            elif path.is_dir() and (descend is None or descend(path)):
                if path.is_symlink():
                    pending.append((path, True))
                    continue
                key = _identity(path)
                if key not in entered:
                    entered.add(key)
                    walk(path, linked)

    walk(root, False)
    while pending:
        pending.sort(key=lambda item: item[0].relative_to(root).as_posix())
        folder, linked = pending.pop(0)
        key = _identity(folder)
        if key is not None and key not in entered:
            entered.add(key)
            walk(folder, linked)
    found = [(name, path) for _, name, path in best.values()] + broken
    return sorted(found, key=lambda item: item[0])


def inside(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or lies under it (both resolved)."""
    return path == folder or folder in path.parents


def check_folders(input_path: str | os.PathLike[str], out_dir: str | os.PathLike[str]) -> tuple[Path, Path]:
    """Validate an input folder (or file) and an output folder before a batch; returns both, resolved.

    Raises:
        BatchError: the input does not exist, the output is an existing file, or the output folder is the input
            folder or inside it (outputs would mix with inputs, and a rerun would take them as inputs).

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     try:
        ...         check_folders(folder, os.path.join(folder, "out"))
        ...     except BatchError as error:
        ...         print(str(error).replace(os.path.realpath(folder), "IN"))
        output folder IN/out is inside the input folder IN; choose a folder outside it
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
        if inside(out, source):
            raise BatchError(f"output folder {out} is inside the input folder {source}; choose a folder outside it")
    return source, out
