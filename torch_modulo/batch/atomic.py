"""Atomic writes for the batch engine: files (bytes, JSON), output folders, and the clean-up of what a killed run left.

Every write goes to a hidden temporary name beside its final name and is renamed into place (``os.replace``), so a
reader never sees half a file. The temporary names carry the writing process's id:

- files: ``.<name>.<pid>-<hex>.tmp`` (:func:`write_bytes`, :func:`write_json`), ``.<stem>.<pid>-<hex>.tmp<suffix>``
  (images written by :func:`torch_modulo.io.write_image`);
- folders: ``.<name>.tmp-<pid>-<hex>`` and, while an old folder is being replaced, ``.<name>.old-<pid>-<hex>``
  (:func:`atomic_output_dir`).

A process killed outright (``kill -9``, power loss) leaves them behind; :func:`remove_stale_temporaries` deletes
those whose process no longer runs on this machine. Errors name the final path, never the temporary one.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import secrets
import shutil
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

__all__ = [
    "atomic_output_dir",
    "final_names",
    "free_space_note",
    "remove_stale_temporaries",
    "write_bytes",
    "write_json",
]

# .<name>.<pid>-<hex>.tmp[<suffix>]: temporary files (JSON, images)
_FILE = re.compile(r"^\.(?P<base>.+)\.(?P<pid>\d+)-[0-9a-f]+\.tmp(?P<suffix>\.[^./]+)?$")
# .<name>.tmp-<pid>-<hex> and .<name>.old-<pid>-<hex>: temporary and replaced folders
_FOLDER = re.compile(r"^\.(?P<base>.+)\.(?:tmp|old)-(?P<pid>\d+)-[0-9a-f]+$")
# The same names inside a longer text (an error message): the folder part, then the name.
_IN_TEXT = re.compile(
    r"/\.(?P<fbase>[^/\s'\"]+?)\.\d+-[0-9a-f]+\.tmp(?P<suffix>\.[A-Za-z0-9]+)?(?=$|[/\s'\":,)])"
    r"|/\.(?P<dbase>[^/\s'\"]+?)\.(?:tmp|old)-\d+-[0-9a-f]+(?=$|[/\s'\":,)])"
)


def _tag() -> str:
    return f"{os.getpid()}-{secrets.token_hex(4)}"


def _naming_final(error: OSError, final: Path) -> OSError:
    """The same error (same errno and text) naming ``final`` instead of a temporary path."""
    if error.errno is None:
        return OSError(f"cannot write {final}: {final_names(str(error))}")
    return OSError(error.errno, error.strerror, str(final))


def _write_atomic(path: Path, write: Callable[[Path], object]) -> Path:
    """``write(temporary)`` beside ``path``, then rename it to ``path``; on failure nothing is left, and an
    ``OSError`` names ``path``."""
    tmp = path.with_name(f".{path.name}.{_tag()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(tmp)
        os.replace(tmp, path)
    except OSError as error:
        tmp.unlink(missing_ok=True)
        raise _naming_final(error, path) from error
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` atomically (temporary file in the same folder, then ``os.replace``), creating the folder.

    Raises:
        OSError: the file cannot be written, with the system's text (``No space left on device``) and the
            final path; nothing is left under the final or a temporary name.

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = write_bytes(os.path.join(folder, "a", "b.bin"), b"ok")
        ...     path.read_bytes(), os.listdir(path.parent)
        (b'ok', ['b.bin'])
    """
    return _write_atomic(Path(path), lambda tmp: tmp.write_bytes(data))


def write_json(path: str | os.PathLike[str], data: Any) -> Path:
    """Write ``data`` as indented JSON atomically, as :func:`write_bytes` writes bytes (and raises alike).

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     path = write_json(os.path.join(folder, "r.json"), {"done": 2})
        ...     json.loads(path.read_text()), os.listdir(folder)
        ({'done': 2}, ['r.json'])
    """
    return _write_atomic(Path(path), lambda tmp: tmp.write_text(json.dumps(data, indent=1, allow_nan=True) + "\n"))


@contextlib.contextmanager
def atomic_output_dir(final: str | os.PathLike[str]) -> Iterator[Path]:
    """Build an output folder under a hidden temporary name, then move it into place in one rename.

    A crash or an exception inside the ``with`` block removes the temporary folder and leaves any previous
    ``final`` untouched; on success a previous ``final`` is replaced (moved aside, the new one renamed into
    place, the old one deleted). An ``OSError`` raised inside the block or by the renames is raised again
    naming ``final`` and the files inside it by their final paths.

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     with atomic_output_dir(os.path.join(folder, "scene")) as tmp:
        ...         _ = (tmp / "frame.txt").write_text("x")
        ...     sorted(os.listdir(folder)), os.listdir(os.path.join(folder, "scene"))
        (['scene'], ['frame.txt'])
    """
    final = Path(final)
    tag = _tag()
    tmp = final.with_name(f".{final.name}.tmp-{tag}")
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp.mkdir()
    except OSError as error:
        raise _naming_final(error, final) from error
    try:
        yield tmp
        if final.exists():
            old = final.with_name(f".{final.name}.old-{tag}")
            os.replace(final, old)
            os.replace(tmp, final)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, final)
    except OSError as error:
        shutil.rmtree(tmp, ignore_errors=True)
        if error.errno is None:
            raise OSError(final_names(str(error))) from error
        where = final_names(error.filename) if isinstance(error.filename, str) else str(final)
        raise OSError(error.errno, error.strerror, where) from error
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def final_names(text: str) -> str:
    """``text`` with every temporary file or folder name of this module (and of ``write_image``) replaced by the
    final name it stands for.

    Example:
        >>> final_names('cannot write "/out/.a.4242-0f3c9a1b.tmp.exr"; see /out/.scene.tmp-4242-0f3c9a1b/frame.exr')
        'cannot write "/out/a.exr"; see /out/scene/frame.exr'
    """

    def final(match: re.Match[str]) -> str:
        if match.group("fbase") is not None:
            return f"/{match.group('fbase')}{match.group('suffix') or ''}"
        return f"/{match.group('dbase')}"

    return _IN_TEXT.sub(final, text)


def _running(pid: int) -> bool:
    """Whether a process with this id runs on this machine (a process of another user counts)."""
    if pid <= 0:
        return False
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OSError:
        return True
    return True


def remove_stale_temporaries(finals: Iterable[str | os.PathLike[str]]) -> list[Path]:
    """Delete the temporary files and folders left beside ``finals`` by writers that no longer run.

    Looks in each final path's folder (once per folder) for the temporary names of :func:`write_json`,
    :func:`atomic_output_dir` and :func:`torch_modulo.io.write_image` that stand for one of ``finals`` and whose
    process id is not running on this machine. Writers still running (another batch on the same output folder)
    are left alone. Writers on other machines are not seen: do not run two batches into one output folder from
    several machines at once.

    Returns:
        The paths removed, sorted.

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     os.mkdir(os.path.join(folder, ".scene.tmp-999999999-0f3c9a1b"))  # no such process
        ...     [p.name for p in remove_stale_temporaries([os.path.join(folder, "scene")])], os.listdir(folder)
        (['.scene.tmp-999999999-0f3c9a1b'], [])
    """
    wanted: dict[Path, set[str]] = {}
    for final in finals:
        final = Path(final)
        wanted.setdefault(final.parent, set()).add(final.name)
    removed: list[Path] = []
    for folder, names in wanted.items():
        try:
            entries = list(os.scandir(folder))
        except OSError:  # no folder yet (a first run), or unreadable: nothing to clean there
            continue
        for entry in entries:
            if not entry.name.startswith("."):
                continue
            match = _FILE.match(entry.name) or _FOLDER.match(entry.name)
            if match is None:
                continue
            base = match.group("base") + (match.groupdict().get("suffix") or "")
            if base not in names or _running(int(match.group("pid"))):
                continue
            path = Path(entry.path)
            with contextlib.suppress(FileNotFoundError):
                if entry.is_dir(follow_symlinks=False):
                    shutil.rmtree(path)
                else:
                    path.unlink()
                removed.append(path)
    return sorted(removed)


def free_space_note(error: BaseException, folder: Path) -> str:
    """``"; No space left on device (0 bytes free in FOLDER)"`` when ``folder``'s file system is full, else ``""``.

    Writers that report a failed write without the system's reason (image libraries do) leave the cause out of
    their message; the batch adds it where the disk is the likely cause.
    """
    if not isinstance(error, OSError) or error.errno == errno.ENOSPC:
        return ""
    try:
        stat = os.statvfs(folder)
    except (OSError, AttributeError):
        return ""
    free = stat.f_bavail * stat.f_frsize
    if free >= 1 << 16:
        return ""
    return f"; {os.strerror(errno.ENOSPC)} ({free} bytes free in {folder})"
