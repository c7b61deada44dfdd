"""Atomic writes: files, folders and folder swaps, their temporary names, and the clean-up of what a killed writer left.

Every write goes to a hidden temporary name beside its final name and is renamed into place, so a reader never sees
half a file or a folder that mixes old and new content. This is the one module of the package that renames files;
:func:`torch_modulo.io.write_image`, the batch engine (:mod:`torch_modulo.batch`) and the frame stacks' writer
(:func:`torch_modulo.sensors.write_frames`) all write through it.

The temporary names carry the writing process's id:

- files: ``.<name>.<pid>-<hex>.tmp`` (:func:`write_bytes`, :func:`write_json`), ``.<stem>.<pid>-<hex>.tmp<suffix>``
  (:func:`atomic_file` with ``keep_suffix=True``, as images are written, so the image library picks the format);
- folders: ``.<name>.tmp-<pid>-<hex>`` and, while an old folder is being replaced, ``.<name>.old-<pid>-<hex>``
  (:func:`atomic_output_dir`, :func:`replace_folder`).

A name so long that its temporary name would pass the file system's 255 bytes is spelt shorter in it: its first
bytes, ``~`` and a hash of the whole name (:func:`temporary_stem`).

A process killed outright (``kill -9``, power loss) leaves them behind; :func:`remove_stale_temporaries` deletes
those whose process no longer runs on this machine, after putting back an old folder that a kill left moved aside.
Errors name the final path, never the temporary one.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import secrets
import shutil
from collections.abc import Callable, Collection, Iterable, Iterator
from pathlib import Path
from typing import Any

__all__ = [
    "atomic_file",
    "atomic_output_dir",
    "final_names",
    "free_space_note",
    "remove_stale_temporaries",
    "replace_folder",
    "temporary_file",
    "temporary_stem",
    "write_bytes",
    "write_json",
]

# The longest file name most file systems take (NAME_MAX), in bytes.
_NAME_MAX = 255
# Bytes a hidden temporary name adds to the name it stands for, at most: "." before it, and ".<pid>-<8 hex>.tmp"
# (files) or ".tmp-<pid>-<8 hex>" / ".old-<pid>-<8 hex>" (folders) after it, for a process id of up to 10 digits.
_TEMPORARY_EXTRA = 25

# .<name>.<pid>-<hex>.tmp[<suffix>]: temporary files (JSON, images)
_FILE = re.compile(r"^\.(?P<base>.+)\.(?P<pid>\d+)-[0-9a-f]+\.tmp(?P<suffix>\.[^./]+)?$")
# .<name>.tmp-<pid>-<hex> and .<name>.old-<pid>-<hex>: temporary and replaced folders
_FOLDER = re.compile(r"^\.(?P<base>.+)\.(?P<kind>tmp|old)-(?P<pid>\d+)-[0-9a-f]+$")
# The same names inside a longer text (an error message), after a "/", a quote, a space or at the start. Names may
# hold spaces ("my scene"), not "/" or quotes.
_IN_TEXT = re.compile(
    r"(?:(?<=/)|(?<=[\s'\"(])|^)\.(?P<fbase>[^/'\"]+?)\.\d+-[0-9a-f]+\.tmp(?P<suffix>\.[A-Za-z0-9]+)?"
    r"(?=$|[/\s'\":,;)])"
    r"|(?:(?<=/)|(?<=[\s'\"(])|^)\.(?P<dbase>[^/'\"]+?)\.(?:tmp|old)-\d+-[0-9a-f]+(?=$|[/\s'\":,;)])"
)


# ------------------------------------------------------------------------------------------- temporary names


def _name_bytes(text: str) -> int:
    return len(os.fsencode(text))


def _tag() -> str:
    return f"{os.getpid()}-{secrets.token_hex(4)}"


def temporary_stem(name: str, suffix: str = "") -> str:
    """How the hidden temporary names beside the file or folder ``name`` spell it.

    ``name`` less ``suffix`` (a temporary name that keeps the extension at its end passes it). When the temporary
    name would pass the file system's 255 bytes (``NAME_MAX``, counted in UTF-8 bytes, not characters), the part
    kept is shortened to its first bytes (whole characters), ``~`` and 8 hex digits of a hash of the whole ``name``,
    so a legal final name always has a legal temporary name and the clean-up still tells whose temporary it is.

    Example:
        >>> temporary_stem("scene.exr", ".exr")
        'scene'
        >>> short = temporary_stem("é" * 120 + ".exr", ".exr")
        >>> len(short.encode()), short[-9:-8]
        (225, '~')
    """
    stem = name[: len(name) - len(suffix)] if suffix and name.endswith(suffix) else name
    room = _NAME_MAX - _TEMPORARY_EXTRA - _name_bytes(suffix)
    if _name_bytes(stem) <= room:
        return stem
    digest = hashlib.sha256(os.fsencode(name)).hexdigest()[:8]
    budget, used, kept = max(room - 9, 0), 0, []
    for char in stem:
        size = _name_bytes(char)
        if used + size > budget:
            break
        kept.append(char)
        used += size
    return f"{''.join(kept)}~{digest}"


def temporary_file(path: Path, *, keep_suffix: bool = False) -> Path:
    """A fresh hidden temporary name beside the file ``path``: ``.<name>.<pid>-<hex>.tmp``, or with
    ``keep_suffix`` ``.<stem>.<pid>-<hex>.tmp<suffix>`` (the same extension at the end). Its name is at most 255
    bytes when ``path``'s is (:func:`temporary_stem`).

    Example:
        >>> temporary_file(Path("/out/scene.exr"), keep_suffix=True).name.startswith(".scene.")
        True
    """
    if keep_suffix:
        return path.with_name(f".{temporary_stem(path.name, path.suffix)}.{_tag()}.tmp{path.suffix}")
    return path.with_name(f".{temporary_stem(path.name)}.{_tag()}.tmp")


def _folder_temporaries(final: Path) -> tuple[Path, Path]:
    """The hidden names beside the folder ``final`` that a swap builds it under (``.<name>.tmp-<pid>-<hex>``) and
    moves the old one aside to (``.<name>.old-<pid>-<hex>``, same tag)."""
    tag = _tag()
    stem = temporary_stem(final.name)
    return final.with_name(f".{stem}.tmp-{tag}"), final.with_name(f".{stem}.old-{tag}")


def final_names(text: str) -> str:
    """``text`` with every temporary file or folder name of this module replaced by the final name it stands for.

    Example:
        >>> final_names('cannot write "/out/.a.4242-0f3c9a1b.tmp.exr"; see /out/.scene.tmp-4242-0f3c9a1b/frame.exr')
        'cannot write "/out/a.exr"; see /out/scene/frame.exr'
    """

    def final(match: re.Match[str]) -> str:
        if match.group("fbase") is not None:
            return f"{match.group('fbase')}{match.group('suffix') or ''}"
        return match.group("dbase")

    for _ in range(4):  # a temporary of a temporary (a stack's folder built inside a batch's) takes two passes
        fixed = _IN_TEXT.sub(final, text)
        if fixed == text:
            break
        text = fixed
    return text


# -------------------------------------------------------------------------------------------------- errors


def _naming_final(error: OSError, tmp: Path, path: Path, *, unnamed: Path | None = None) -> OSError:
    """``error`` (same type, errno and text) naming ``path`` wherever it named the temporary file or folder ``tmp``;
    ``error`` itself when it does not name it. With ``unnamed``, always a new error, and one that names no file (a
    write that failed on close, a full disk) names ``unnamed``."""
    if unnamed is None and error.filename != str(tmp) and str(tmp) not in str(error):
        return error

    def fix(text: object) -> object:
        return text.replace(str(tmp), str(path)) if isinstance(text, str) else text

    if error.errno is not None and error.strerror is not None:
        where = str(unnamed) if error.filename is None and unnamed is not None else fix(error.filename)
        return type(error)(error.errno, fix(error.strerror), where)
    return type(error)(*(fix(arg) for arg in error.args))


def _failed_write(error: OSError, final: Path) -> OSError:
    """The error of a failed write of ``final`` (same errno and text), naming ``final`` whatever path it named."""
    if error.errno is None:
        return OSError(f"cannot write {final}: {final_names(str(error))}")
    return OSError(error.errno, error.strerror, str(final))


def _inside(path: str, folder: Path) -> bool:
    try:
        return os.path.commonpath([os.path.abspath(path), os.path.abspath(folder)]) == os.path.abspath(folder)
    except ValueError:
        return False


def _while_writing(error: OSError, folder: Path) -> bool:
    """Whether ``error`` comes from writing an output: it says it could not write, or it names a path in the
    output ``folder`` or a temporary name."""
    text = str(error)
    if "cannot write " in text or _IN_TEXT.search(text):
        return True
    for name in (error.filename, error.filename2):
        if isinstance(name, str | bytes | os.PathLike):
            name = os.fsdecode(name)
            if _inside(name, folder) or _readings(os.path.basename(name)):
                return True
    return False


def free_space_note(error: BaseException, folder: Path) -> str:
    """``"; No space left on device (0 bytes free in FOLDER)"`` when ``error`` comes from writing an output into
    ``folder`` (it says it could not write, or names a path there or a temporary name) and ``folder``'s file system
    is full, else ``""``.

    Writers that report a failed write without the system's reason (image libraries do) leave the cause out of
    their message; the batch adds it where the disk is the likely cause. An error reading an input (a corrupt
    file) is never blamed on the disk, nor is one that already gives the reason (``ENOSPC``, ``EDQUOT``).
    """
    if not isinstance(error, OSError) or error.errno in (errno.ENOSPC, errno.EDQUOT):
        return ""
    if not _while_writing(error, folder):
        return ""
    try:
        stat = os.statvfs(folder)
    except (OSError, AttributeError):
        return ""
    free = stat.f_bavail * stat.f_frsize
    if free >= 1 << 16:
        return ""
    return f"; {os.strerror(errno.ENOSPC)} ({free} bytes free in {folder})"


# --------------------------------------------------------------------------------------------------- files


def _discard_file(tmp: Path) -> None:
    """Remove a temporary file, if there is one; a failure here (a read-only folder) must not hide the error that
    is being handled."""
    with contextlib.suppress(OSError):
        tmp.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_file(path: Path, *, keep_suffix: bool = False) -> Iterator[Path]:
    """Write a file under a hidden temporary name beside ``path``, then rename it into place.

    The ``with`` block writes the temporary file it is given (:func:`temporary_file`; with ``keep_suffix`` it ends
    in ``path``'s extension). When the block ends, the file is renamed to ``path``, replacing any file there. An
    exception inside the block or from the rename removes the temporary file and leaves ``path`` as it was; an
    ``OSError`` that named the temporary file is raised again naming ``path`` (same type, errno and text).

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     with atomic_file(Path(folder, "a.txt")) as tmp:
        ...         _ = tmp.write_text("whole")
        ...     os.listdir(folder), Path(folder, "a.txt").read_text()
        (['a.txt'], 'whole')
    """
    tmp = temporary_file(path, keep_suffix=keep_suffix)
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as error:
        _discard_file(tmp)
        fixed = _naming_final(error, tmp, path)
        if fixed is error:
            raise
        raise fixed from error
    except BaseException:
        _discard_file(tmp)
        raise


def _write_atomic(path: Path, write: Callable[[Path], object]) -> Path:
    """``write(temporary)`` beside ``path``, then rename it to ``path``; on failure nothing is left, and an
    ``OSError`` names ``path``."""
    tmp = temporary_file(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(tmp)
        os.replace(tmp, path)
    except OSError as error:
        _discard_file(tmp)
        raise _failed_write(error, path) from error
    except BaseException:
        _discard_file(tmp)
        raise
    return path


def write_bytes(path: str | os.PathLike[str], data: bytes) -> Path:
    """Write ``data`` atomically (a temporary file in the same folder, renamed into place), creating the folder.

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


# ------------------------------------------------------------------------------------------------- folders


def _swap_folder(tmp: Path, final: Path, old: Path) -> None:
    """Move the existing ``final`` aside to ``old`` and ``tmp`` into its place; if the second rename fails, put the
    old folder back (if that fails too, both stay: the next clean-up of stale temporaries puts ``old`` back) and
    raise the first error."""
    os.replace(final, old)
    try:
        os.replace(tmp, final)
    except BaseException:
        with contextlib.suppress(OSError):
            os.replace(old, final)
        raise


def _discard_folder(tmp: Path, old: Path, final: Path) -> None:
    """Remove the new folder ``tmp`` of a swap that failed, unless the old folder ``old`` could not be put back as
    ``final``: then both stay, for the clean-up of stale temporaries to restore ``old``."""
    if os.path.lexists(old) and not os.path.lexists(final):
        return
    shutil.rmtree(tmp, ignore_errors=True)


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
    tmp, old = _folder_temporaries(final)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp.mkdir()
    except OSError as error:
        raise _failed_write(error, final) from error
    try:
        yield tmp
        if final.exists():
            _swap_folder(tmp, final, old)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, final)
    except OSError as error:
        _discard_folder(tmp, old, final)

        def fix(text: str) -> str:
            return final_names(text.replace(str(tmp), str(final)))

        if error.errno is None:
            raise OSError(fix(str(error))) from error
        where = fix(error.filename) if isinstance(error.filename, str) else str(final)
        raise OSError(error.errno, error.strerror, where) from error
    except BaseException:
        _discard_folder(tmp, old, final)
        raise


def _link_or_copy(source: str, target: str) -> None:
    try:
        os.link(source, target)
    except OSError:
        shutil.copy2(source, target)


def _carry(old: Path, new: Path, replaced: Collection[str]) -> None:
    """Put into ``new`` every entry of ``old`` that ``new`` lacks and that is not in ``replaced``."""
    for entry in os.scandir(old):
        if entry.name in replaced or (new / entry.name).exists() or (new / entry.name).is_symlink():
            continue
        target = new / entry.name
        if entry.is_symlink():
            os.symlink(os.readlink(entry.path), target)
        elif entry.is_dir():
            shutil.copytree(entry.path, target, symlinks=True, copy_function=_link_or_copy)
        else:
            _link_or_copy(entry.path, str(target))


def _cwd() -> Path | None:
    with contextlib.suppress(OSError):
        return Path(os.getcwd())
    return None


def replace_folder(final: Path, build: Callable[[Path], None], replaced: Collection[str] = ()) -> None:
    """Fill a new folder with ``build(tmp)`` and swap it in for ``final``, keeping ``final``'s other entries.

    A failure half-way leaves the previous folder as it was (or no folder at all, if there was none), never a mix
    of old and new content. Entries of the old folder that the new content does not replace and that are not
    listed in ``replaced`` are kept: they are hard-linked (or, where links are not possible, copied) into the new
    folder before the swap, so the old folder stays whole until the rename. When a process is killed between the
    swap's two renames, :func:`remove_stale_temporaries` puts the old folder back.

    Args:
        final: the folder to create or replace; a symbolic link to a folder is followed (the link stays).
        build: writes the new content into the empty temporary folder it is given.
        replaced: names in the old folder that belong to the content being replaced; they are dropped.

    Raises:
        NotADirectoryError: ``final`` exists and is not a folder.
        OSError: a write, link or rename failed, naming the final paths; the old folder (or its absence) is left
            as it was.

    Example:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as folder:
        ...     final = Path(folder, "stack")
        ...     replace_folder(final, lambda tmp: (tmp / "old.txt").write_text("old"))
        ...     _ = (final / "notes.txt").write_text("kept")
        ...     replace_folder(final, lambda tmp: (tmp / "new.txt").write_text("new"), {"old.txt"})
        ...     sorted(os.listdir(final))
        ['new.txt', 'notes.txt']
    """
    final = Path(os.path.realpath(final))
    if final.exists() and not final.is_dir():
        raise NotADirectoryError(f"cannot write a frame stack to {final}: it exists and is not a folder")
    tmp, old = _folder_temporaries(final)
    try:
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp.mkdir()
    except OSError as error:
        raise _naming_final(error, tmp, final, unnamed=final) from error
    try:
        build(tmp)
        if not final.exists():
            os.replace(tmp, final)
            return
        _carry(final, tmp, replaced)
        here = _cwd()
        _swap_folder(tmp, final, old)
        if here == final:
            os.chdir(final)  # the process stood in the old folder, which is about to be deleted
    except OSError as error:
        _discard_folder(tmp, old, final)
        raise _naming_final(error, tmp, final, unnamed=final) from error
    except BaseException:
        _discard_folder(tmp, old, final)
        raise
    shutil.rmtree(old, ignore_errors=True)


# ------------------------------------------------------------------------------------------------ clean-up


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

    Looks in each final path's folder (once per folder) for the temporary names of this module's writers (and so
    of :func:`torch_modulo.io.write_image`) that stand for one of ``finals`` and whose process id is not running
    on this machine. Writers still running (another batch on the same output folder) are left alone. Writers on
    other machines are not seen: do not run two batches into one output folder from several machines at once.

    A temporary of a temporary (``..<name>.tmp-<pid>-<hex>.tmp-<pid>-<hex>``: a stack folder built inside a batch's
    temporary folder) is removed too, once all its writers are gone.

    A writer killed between the two renames of a folder swap leaves the old folder moved aside
    (``.<name>.old-<pid>-<hex>``), the new one beside it (``.<name>.tmp-<pid>-<hex>``) and no ``<name>``: the old
    folder is then renamed back to ``<name>`` (nothing of it is lost) and the new one removed.

    Returns:
        The paths removed, sorted (an old folder put back is not among them).

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
        if os.path.islink(final):  # a folder swapped through a link is swapped beside its target
            target = Path(os.path.realpath(final))
            wanted.setdefault(target.parent, set()).add(target.name)
    removed: list[Path] = []
    for folder, names in wanted.items():
        try:
            entries = [entry for entry in os.scandir(folder) if entry.name.startswith(".")]
        except OSError:  # no folder yet (a first run), or unreadable: nothing to clean there
            continue
        # How temporary names spell each name they may stand for: a final name, or (for a temporary of a
        # temporary) the name of another hidden entry here; long names are spelt shorter (temporary_stem).
        spelt: dict[str, str] = {}
        for name in [entry.name for entry in entries] + sorted(names):
            spelt[name] = name
            for suffix in {"", Path(name).suffix}:
                spelt.setdefault(temporary_stem(name, suffix) + suffix, name)
        stale: list[tuple[os.DirEntry[str], str, bool]] = []  # (entry, final name, it is a folder moved aside)
        for entry in entries:
            found = _stands_for(entry.name, names, spelt)
            if found is not None and not any(_running(pid) for pid in found[1]):
                stale.append((entry, found[0], found[2]))
        present = {entry.name for entry in entries}
        keep = _restore_old_folders(folder, stale, present)
        for entry, _, _ in stale:
            if entry.name in keep:
                continue
            path = Path(entry.path)
            with contextlib.suppress(FileNotFoundError):
                if entry.is_dir(follow_symlinks=False):
                    shutil.rmtree(path)
                else:
                    path.unlink()
                removed.append(path)
    return sorted(removed)


def _readings(name: str) -> list[tuple[str, int, str]]:
    """Each way ``name`` reads as a temporary name: (the name it spells, the writer's process id, ``"file"``,
    ``"tmp"`` or ``"old"``)."""
    readings = []
    match = _FILE.match(name)
    if match is not None:
        readings.append((match.group("base") + (match.group("suffix") or ""), int(match.group("pid")), "file"))
    match = _FOLDER.match(name)
    if match is not None:
        readings.append((match.group("base"), int(match.group("pid")), match.group("kind")))
    return readings


def _stands_for(
    name: str, finals: set[str], spelt: dict[str, str], depth: int = 0
) -> tuple[str, list[int], bool] | None:
    """The final name (one of ``finals``) that the temporary name ``name`` stands for, directly or through
    temporaries of temporaries; the process ids of its writers; and whether it is a folder moved aside
    (``.<final>.old-...``, directly). ``None`` when ``name`` stands for none of ``finals``."""
    for base, pid, kind in _readings(name):
        targets = [spelt[base]] if base in spelt else []
        if base not in targets:
            targets.append(base)  # a temporary name spelt out, whose entry is gone already
        for target in targets:
            if target in finals:
                return target, [pid], kind == "old"
            if depth < 4 and target.startswith("."):
                inner = _stands_for(target, finals, spelt, depth + 1)
                if inner is not None:
                    return inner[0], [pid, *inner[1]], False
    return None


def _restore_old_folders(folder: Path, stale: list[tuple[os.DirEntry[str], str, bool]], present: set[str]) -> set[str]:
    """Rename back to its final name each old folder a writer killed between the two renames of a folder swap left
    moved aside (the final name is missing and the writer's new folder, same tag, is still there).

    Returns:
        The names of the entries to keep: those put back, and both folders of a swap whose old folder could not be
        put back (a later run tries again).
    """
    keep: set[str] = set()
    candidates = []
    for entry, final, moved_aside in stale:
        if not moved_aside or not entry.is_dir(follow_symlinks=False):
            continue
        cut = entry.name.rfind(".old-")
        partner = f"{entry.name[:cut]}.tmp-{entry.name[cut + 5 :]}"
        if partner in present:
            with contextlib.suppress(OSError):
                candidates.append((entry.stat(follow_symlinks=False).st_mtime_ns, entry, final, partner))
    for _, entry, final, partner in sorted(candidates, key=lambda c: c[0], reverse=True):  # the newest first
        target = folder / final
        if os.path.lexists(target):
            continue
        try:
            os.rename(entry.path, target)
        except OSError:
            keep.add(partner)
        keep.add(entry.name)
    return keep
