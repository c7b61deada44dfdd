"""Replace a folder's content as a whole: build the new content beside it, then rename it into place.

:func:`torch_modulo.sensors.write_frames` writes a stack this way, so a failure half-way leaves the previous
stack as it was (or no folder at all, if there was none) and never a mix of old and new frames. Entries of the old
folder that the new content does not replace and that are not listed as ``replaced`` are kept: they are hard-linked
(or, where links are not possible, copied) into the new folder before the swap, so the old folder stays whole
until the rename.

The temporary names follow :mod:`torch_modulo.batch.atomic`: ``.<name>.tmp-<pid>-<hex>`` for the folder being
built and ``.<name>.old-<pid>-<hex>`` for the old one while it is replaced (a long name spelt shorter, as
:func:`torch_modulo.io.temporary_stem` says), so a clean-up of stale temporaries finds both; when a process is
killed between the two renames, the clean-up puts the old folder back.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Callable, Collection
from pathlib import Path

from torch_modulo.io import _discard_folder, _folder_temporaries, _naming_final, _swap_folder

__all__ = ["replace_folder"]


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


def replace_folder(final: Path, build: Callable[[Path], None], replaced: Collection[str] = ()) -> None:
    """Fill a new folder with ``build(tmp)`` and swap it in for ``final``, keeping ``final``'s other entries.

    Args:
        final: the folder to create or replace; a symbolic link to a folder is followed (the link stays).
        build: writes the new content into the empty temporary folder it is given.
        replaced: names in the old folder that belong to the content being replaced; they are dropped.

    Raises:
        NotADirectoryError: ``final`` exists and is not a folder.
        OSError: a write, link or rename failed, naming the final paths; the old folder (or its absence) is left
            as it was.
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


def _cwd() -> Path | None:
    with contextlib.suppress(OSError):
        return Path(os.getcwd())
    return None
