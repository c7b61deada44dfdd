"""Tests of torch_modulo/_atomic.py: atomic files, JSON and folders, folder swaps, errors that name final paths,
temporary names near NAME_MAX, temporaries of temporaries, and the clean-up of what a killed writer left behind
(a kill between a folder swap's two renames included). Nothing here needs root: read-only and full file systems
are played by monkeypatching."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import torch

from torch_modulo import _atomic
from torch_modulo import io as tmio
from torch_modulo._atomic import (
    atomic_file,
    atomic_output_dir,
    final_names,
    free_space_note,
    remove_stale_temporaries,
    replace_folder,
    temporary_file,
    temporary_stem,
    write_bytes,
    write_json,
)
from torch_modulo.io import read_image, write_image

NAME_MAX = 255
# The widest tag a temporary name can carry: a 10-digit process id and 8 hex digits.
WIDE_TAG = "4294967295-0f3c9a1b"


def _dead_pid() -> int:
    """The id of a process that has exited."""
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def _bytes(name: str) -> int:
    return len(os.fsencode(name))


def _killed(script: str, *args: object) -> None:
    """Run ``script`` in a fresh Python that ends itself with ``os._exit(9)`` (as a ``kill -9`` would: no clean-up
    runs); its process id is then that of a dead process."""
    code = "import os, sys\nfrom pathlib import Path\n" + textwrap.dedent(script)
    result = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True)
    assert result.returncode == 9, result.stderr


def _listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def _stack(folder: Path, **files: str) -> None:
    folder.mkdir(parents=True)
    for name, text in files.items():
        (folder / name.replace("_", ".", 1)).write_text(text)


def _read_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """Unlinking fails as on a read-only file system (EROFS, even for a file that is not there)."""

    def unlink(self: Path, missing_ok: bool = False) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))

    monkeypatch.setattr(Path, "unlink", unlink)


# ------------------------------------------------------------------------------------------------- writes


class TestAtomicWrites:
    def test_atomic_output_dir_replaces_on_success(self, tmp_path: Path) -> None:
        final = tmp_path / "scene"
        final.mkdir()
        (final / "old.txt").write_text("old")
        with atomic_output_dir(final) as tmp:
            (tmp / "new.txt").write_text("new")
            assert not (final / "new.txt").exists()  # nothing visible under the final name before the end
        assert sorted(p.name for p in final.iterdir()) == ["new.txt"]
        assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]

    def test_atomic_output_dir_keeps_the_old_folder_on_error(self, tmp_path: Path) -> None:
        final = tmp_path / "scene"
        final.mkdir()
        (final / "old.txt").write_text("old")
        with pytest.raises(RuntimeError, match="boom"), atomic_output_dir(final) as tmp:
            (tmp / "half.txt").write_text("half")
            raise RuntimeError("boom")
        assert sorted(p.name for p in final.iterdir()) == ["old.txt"]
        assert sorted(p.name for p in tmp_path.iterdir()) == ["scene"]

    def test_write_json_leaves_no_temporary(self, tmp_path: Path) -> None:
        write_json(tmp_path / "a" / "r.json", {"x": [1, 2]})
        assert json.loads((tmp_path / "a" / "r.json").read_text()) == {"x": [1, 2]}
        assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["r.json"]

    @pytest.mark.parametrize(
        ("method", "write"),
        [("write_text", lambda p: write_json(p, {"x": 1})), ("write_bytes", lambda p: write_bytes(p, b"x"))],
    )
    def test_writes_on_a_full_disk_name_the_final_path(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, method: str, write: Callable[[Path], Path]
    ) -> None:
        def full(self: Path, *args: object, **kwargs: object) -> int:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self))

        monkeypatch.setattr(Path, method, full)
        with pytest.raises(OSError) as info:
            write(tmp_path / "r.json")
        assert info.value.errno == errno.ENOSPC
        assert str(info.value) == f"[Errno 28] No space left on device: '{tmp_path / 'r.json'}'"
        assert os.listdir(tmp_path) == []

    def test_atomic_output_dir_errors_name_the_final_folder(self, tmp_path: Path) -> None:
        final = tmp_path / "scene"
        with pytest.raises(OSError) as info, atomic_output_dir(final) as tmp:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp / "frame.exr"))
        assert str(info.value) == f"[Errno 28] No space left on device: '{final / 'frame.exr'}'"
        with (
            pytest.raises(OSError, match=f"cannot write {final}/frame.exr: disk full") as info,
            atomic_output_dir(final) as tmp,
        ):
            raise OSError(f"cannot write {tmp}/frame.exr: disk full")
        assert os.listdir(tmp_path) == []

    def test_atomic_file_renames_into_place_or_leaves_nothing(self, tmp_path: Path) -> None:
        path = tmp_path / "a.exr"
        path.write_text("old")
        with atomic_file(path, keep_suffix=True) as tmp:
            assert tmp.parent == tmp_path and tmp.name.startswith(".a.") and tmp.name.endswith(".tmp.exr")
            tmp.write_text("new")
            assert path.read_text() == "old"  # nothing under the final name before the end
        assert _listing(tmp_path) == ["a.exr"] and path.read_text() == "new"
        with pytest.raises(RuntimeError, match="boom"), atomic_file(path) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
        assert _listing(tmp_path) == ["a.exr"] and path.read_text() == "new"

    def test_atomic_file_errors_name_the_final_path_and_keep_their_type(self, tmp_path: Path) -> None:
        path = tmp_path / "a.png"
        with pytest.raises(PermissionError) as info, atomic_file(path, keep_suffix=True) as tmp:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(tmp))
        assert info.value.filename == str(path) and isinstance(info.value.__cause__, PermissionError)
        with pytest.raises(OSError) as info, atomic_file(path, keep_suffix=True) as tmp:
            raise OSError(f'cannot write {path}: Could not open "{tmp}"')
        assert str(info.value) == f'cannot write {path}: Could not open "{path}"'
        unrelated = OSError(errno.EIO, os.strerror(errno.EIO), "/elsewhere/b.png")
        with pytest.raises(OSError) as info, atomic_file(path):
            raise unrelated
        assert info.value is unrelated  # an error that does not name the temporary file is raised as it is
        assert _listing(tmp_path) == []


class TestFinalNames:
    def test_final_names(self) -> None:
        text = 'Failed to write "/out/.a.123-0f3c9a1b.tmp.exr"; /out/.s.tmp-123-ab/frames.json, /m/.x.exr.json.1-ff.tmp'
        assert final_names(text) == 'Failed to write "/out/a.exr"; /out/s/frames.json, /m/x.exr.json'
        assert final_names("/out/.hidden/a.exr and /out/.b.exr") == "/out/.hidden/a.exr and /out/.b.exr"

    def test_final_names_reads_names_with_spaces(self) -> None:
        text = (
            "[Errno 30] Read-only file system: '/out/.my scene.25895-4d363d48.tmp.png'; "
            "see /out/.my stack.tmp-1-ab/frame 1.exr and ..s 6.tmp-1-ab.tmp-1-cd/frames.json"
        )
        assert final_names(text) == (
            "[Errno 30] Read-only file system: '/out/my scene.png'; see /out/my stack/frame 1.exr and s 6/frames.json"
        )
        assert final_names("'.x.1-ab.tmp.exr' and /out/.hidden dir/a.exr") == "'x.exr' and /out/.hidden dir/a.exr"


# ------------------------------------------------------------------------------------------------ clean-up


class TestStaleTemporaries:
    def test_remove_stale_temporaries_only_touches_the_given_outputs(self, tmp_path: Path) -> None:
        dead = _dead_pid()
        (tmp_path / f".a.png.old-{dead}-ab").mkdir()
        (tmp_path / f".a.{dead}-ab.tmp.png").write_text("x")
        (tmp_path / f".b.{dead}-ab.tmp.png").write_text("x")
        removed = remove_stale_temporaries([tmp_path / "a.png", tmp_path / "missing" / "c.png"])
        assert [p.name for p in removed] == sorted([f".a.png.old-{dead}-ab", f".a.{dead}-ab.tmp.png"])
        assert sorted(p.name for p in tmp_path.iterdir()) == [f".b.{dead}-ab.tmp.png"]

    def test_a_folder_swapped_through_a_link_is_restored_beside_its_target(self, tmp_path: Path) -> None:
        elsewhere, out = tmp_path / "elsewhere", tmp_path / "out"
        old = elsewhere / ".scene.old-999999999-0f3c9a1b"  # a writer (no such process) killed between the renames
        old.mkdir(parents=True)
        (old / "notes.txt").write_text("the user's")
        (elsewhere / ".scene.tmp-999999999-0f3c9a1b").mkdir()
        out.mkdir()
        (out / "scene").symlink_to(elsewhere / "scene")  # dangling until the old folder is back
        removed = remove_stale_temporaries([out / "scene"])
        assert [p.name for p in removed] == [".scene.tmp-999999999-0f3c9a1b"]
        assert (out / "scene" / "notes.txt").read_text() == "the user's"


class TestKillBetweenTheRenames:
    def test_the_old_folder_is_put_back_and_the_new_one_removed(self, tmp_path: Path) -> None:
        dead = _dead_pid()
        old, new = tmp_path / f".a.old-{dead}-0f3c9a1b", tmp_path / f".a.tmp-{dead}-0f3c9a1b"
        _stack(old, frames_json="old stack", notes_txt="my notes")
        _stack(new, frames_json="new stack", notes_txt="my notes")
        removed = remove_stale_temporaries([tmp_path / "a"])
        assert removed == [new]
        assert _listing(tmp_path) == ["a"]
        assert (tmp_path / "a" / "frames.json").read_text() == "old stack"
        assert (tmp_path / "a" / "notes.txt").read_text() == "my notes"

    def test_the_newest_of_several_old_folders_is_put_back(self, tmp_path: Path) -> None:
        dead = _dead_pid()
        for tag, when in (("0000000a", 1_000_000_000), ("0000000b", 2_000_000_000)):
            _stack(tmp_path / f".a.old-{dead}-{tag}", frames_json=tag)
            _stack(tmp_path / f".a.tmp-{dead}-{tag}", frames_json="new")
            os.utime(tmp_path / f".a.old-{dead}-{tag}", (when, when))
        remove_stale_temporaries([tmp_path / "a"])
        assert _listing(tmp_path) == ["a"]
        assert (tmp_path / "a" / "frames.json").read_text() == "0000000b"

    def test_an_old_folder_that_cannot_be_put_back_is_kept_with_its_partner(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        dead = _dead_pid()
        names = [f".a.old-{dead}-0f3c9a1b", f".a.tmp-{dead}-0f3c9a1b"]
        for name in names:
            _stack(tmp_path / name, notes_txt="my notes")

        def refused(source: Any, target: Any) -> None:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(source))

        monkeypatch.setattr(_atomic.os, "rename", refused)
        assert remove_stale_temporaries([tmp_path / "a"]) == []
        assert _listing(tmp_path) == names  # a later run tries again
        monkeypatch.undo()
        remove_stale_temporaries([tmp_path / "a"])
        assert _listing(tmp_path) == ["a"] and (tmp_path / "a" / "notes.txt").read_text() == "my notes"

    def test_an_old_folder_beside_its_final_folder_is_deleted(self, tmp_path: Path) -> None:
        # killed after the second rename, while deleting the old folder: the new folder is in place
        dead = _dead_pid()
        _stack(tmp_path / "a", frames_json="new stack")
        _stack(tmp_path / f".a.old-{dead}-0f3c9a1b", frames_json="old stack")
        assert [p.name for p in remove_stale_temporaries([tmp_path / "a"])] == [f".a.old-{dead}-0f3c9a1b"]
        assert _listing(tmp_path) == ["a"] and (tmp_path / "a" / "frames.json").read_text() == "new stack"

    def test_an_old_folder_of_a_running_writer_is_left_alone(self, tmp_path: Path) -> None:
        pid = os.getpid()
        _stack(tmp_path / f".a.old-{pid}-0f3c9a1b", frames_json="old")
        _stack(tmp_path / f".a.tmp-{pid}-0f3c9a1b", frames_json="new")
        assert remove_stale_temporaries([tmp_path / "a"]) == []
        assert _listing(tmp_path) == [f".a.old-{pid}-0f3c9a1b", f".a.tmp-{pid}-0f3c9a1b"]

    @pytest.mark.parametrize("writer", ["replace_folder", "atomic_output_dir"])
    def test_a_real_kill_between_the_renames_loses_nothing(self, tmp_path: Path, writer: str) -> None:
        final = tmp_path / "a"
        _stack(final, frames_json="old stack", notes_txt="my notes")
        _killed(
            """
            import torch_modulo._atomic as atomic
            real, calls = os.replace, []
            def replace(source, target):
                calls.append(source)
                if len(calls) == 2:  # final -> old is done; tmp -> final is not
                    os._exit(9)
                real(source, target)
            os.replace = replace
            final = Path(sys.argv[1])
            if sys.argv[2] == "replace_folder":
                atomic.replace_folder(final, lambda tmp: (tmp / "frames.json").write_text("new stack"), {"frames.json"})
            else:
                with atomic.atomic_output_dir(final) as tmp:
                    (tmp / "frames.json").write_text("new stack")
            """,
            final,
            writer,
        )
        assert not final.exists() and len(_listing(tmp_path)) == 2  # .a.old-... and .a.tmp-...
        remove_stale_temporaries([final])
        assert _listing(tmp_path) == ["a"]
        assert (final / "frames.json").read_text() == "old stack"
        assert (final / "notes.txt").read_text() == "my notes"

    @pytest.mark.parametrize("writer", ["replace_folder", "atomic_output_dir"])
    def test_a_failed_rollback_keeps_both_folders_for_the_clean_up(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, writer: str
    ) -> None:
        final = tmp_path / "a"
        _stack(final, frames_json="old stack", notes_txt="my notes")
        real = os.replace
        calls: list[str] = []

        def replace(source: Any, target: Any) -> None:
            calls.append(str(source))
            if len(calls) >= 2:  # tmp -> final fails, and so does putting the old folder back
                raise OSError(errno.EIO, os.strerror(errno.EIO), str(source))
            real(source, target)

        monkeypatch.setattr(os, "replace", replace)
        with pytest.raises(OSError) as info:
            if writer == "replace_folder":
                replace_folder(final, lambda tmp: (tmp / "frames.json").write_text("new"), {"frames.json"})
            else:
                with atomic_output_dir(final) as tmp:
                    (tmp / "frames.json").write_text("new")
        assert ".tmp-" not in str(info.value) and ".old-" not in str(info.value)
        monkeypatch.undo()
        assert len(_listing(tmp_path)) == 2 and not final.exists()  # nothing deleted
        monkeypatch.setattr(_atomic, "_running", lambda pid: False)  # as after this process ends
        remove_stale_temporaries([final])
        assert _listing(tmp_path) == ["a"] and (final / "notes.txt").read_text() == "my notes"


# --------------------------------------------------------------------------------------------- error names


class TestFullDiskErrors:
    def test_an_error_without_a_file_name_names_the_final_folder(self, tmp_path: Path) -> None:
        def build(tmp: Path) -> None:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))  # as write_text failing on close

        with pytest.raises(OSError) as info:
            replace_folder(tmp_path / "a", build)
        assert info.value.errno == errno.ENOSPC
        assert info.value.filename == str((tmp_path / "a").resolve())
        assert _listing(tmp_path) == []

    def test_a_stack_built_in_a_temporary_folder_names_the_final_folder(self, tmp_path: Path) -> None:
        # simulate: write_frames' replace_folder runs on simulate's own temporary folder
        def inner(tmp: Path) -> None:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        with pytest.raises(OSError) as info:
            replace_folder(tmp_path / "a", lambda tmp: replace_folder(tmp, inner))
        assert info.value.filename == str((tmp_path / "a").resolve())
        assert _listing(tmp_path) == []

    @pytest.fixture
    def full(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """The output folder's file system has 4096 bytes free."""

        class Stat:
            f_bavail, f_frsize, f_blocks, f_bfree = 1, 4096, 100, 1

        monkeypatch.setattr(_atomic.os, "statvfs", lambda folder: Stat())

    @pytest.mark.parametrize(
        ("error", "noted"),
        [
            (OSError("cannot read image /in/corrupt.exr: EXR Error: Unable to read magic"), False),
            (OSError(errno.EIO, os.strerror(errno.EIO), "/in/a.exr"), False),
            (ValueError("cannot write /out/a.png: values >= 0 only"), False),
            (OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "/out/a.png"), False),  # says it already
            (OSError(errno.EDQUOT, os.strerror(errno.EDQUOT), "/out/a.png"), False),
            (OSError("cannot write /out/a.png: Could not open file"), True),
            (OSError(errno.EIO, "cannot write /out/a.png: the file is empty"), True),
            (OSError(errno.EIO, os.strerror(errno.EIO), "/out/sub/a.png"), True),
            (OSError('Failed to write "/elsewhere/.a.123-0f3c9a1b.tmp.png"'), True),
        ],
    )
    def test_the_disk_is_blamed_only_for_errors_writing_outputs(
        self, full: None, error: Exception, noted: bool
    ) -> None:
        note = free_space_note(error, Path("/out"))
        assert note == ("; No space left on device (4096 bytes free in /out)" if noted else "")


class TestReadOnlyFolder:
    @pytest.mark.parametrize(
        ("method", "write"),
        [("write_text", lambda p: write_json(p, {"x": 1})), ("write_bytes", lambda p: write_bytes(p, b"x"))],
    )
    def test_atomic_writes_name_the_final_path(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, method: str, write: Any
    ) -> None:
        def refused(self: Path, *args: object, **kwargs: object) -> int:
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))

        monkeypatch.setattr(Path, method, refused)
        _read_only(monkeypatch)
        with pytest.raises(OSError) as info:
            write(tmp_path / "my report.json")
        assert info.value.errno == errno.EROFS
        assert str(info.value) == f"[Errno 30] Read-only file system: '{tmp_path / 'my report.json'}'"

    def test_write_image_keeps_its_own_error_and_names_the_final_path(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        def refused(tmp: Path, spec: object, array: object, fmt: object, path: Path) -> None:
            raise OSError(f'cannot write {path}: Could not open "{tmp}" (Read-only file system)')

        monkeypatch.setattr(tmio, "_write_checked", refused)
        _read_only(monkeypatch)
        path = tmp_path / "my scene.exr"
        with pytest.raises(OSError) as info:
            write_image(path, torch.ones(1, 2, 2))
        assert str(info.value) == f'cannot write {path}: Could not open "{path}" (Read-only file system)'

    def test_write_image_errors_with_an_errno_name_the_final_path(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        def refused(source: Any, target: Any) -> None:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(source))

        monkeypatch.setattr(os, "replace", refused)
        path = tmp_path / "a.exr"
        with pytest.raises(PermissionError) as info:
            write_image(path, torch.ones(1, 2, 2))
        assert info.value.filename == str(path)
        monkeypatch.undo()
        assert _listing(tmp_path) == []


# ------------------------------------------------------------------------------------------ temporary names

LONG_NAMES = ["x" * 251 + ".png", "é" * 125 + ".exr", "日本" * 41 + "語.tif", "y" * 250 + ".json", "z" * 255]


class TestNamesNearNameMax:
    @pytest.mark.parametrize("name", LONG_NAMES)
    def test_temporary_names_fit_in_name_max(self, name: str) -> None:
        assert _bytes(name) <= NAME_MAX
        suffix = Path(name).suffix
        candidates = [
            f".{temporary_stem(name, suffix)}.{WIDE_TAG}.tmp{suffix}",  # write_image
            f".{temporary_stem(name)}.{WIDE_TAG}.tmp",  # write_json, write_bytes
            f".{temporary_stem(name)}.tmp-{WIDE_TAG}",  # folders
            f".{temporary_stem(name)}.old-{WIDE_TAG}",
        ]
        assert all(_bytes(candidate) <= NAME_MAX for candidate in candidates), [_bytes(c) for c in candidates]
        assert temporary_stem(name).startswith(name[:40])
        assert temporary_stem(name) != temporary_stem(name[:-1] + "q")  # the hash tells similar names apart
        for keep_suffix in (False, True):
            assert _bytes(temporary_file(Path("/out") / name, keep_suffix=keep_suffix).name) <= NAME_MAX

    def test_short_names_are_spelt_out(self) -> None:
        assert temporary_stem("scene.exr", ".exr") == "scene"
        assert temporary_stem("scene.exr") == "scene.exr"
        assert temporary_file(Path("/out/scene.exr"), keep_suffix=True).name.startswith(".scene.")
        assert temporary_file(Path("/out/scene.exr")).name.startswith(".scene.exr.")

    def test_utf8_bytes_not_characters_are_counted(self) -> None:
        name = "日" * 83 + ".exr"  # 87 characters, 253 bytes: its temporary name would pass 255 bytes
        short = temporary_stem(name, ".exr")
        assert short != "日" * 84 and short.startswith("日" * 60)
        assert _bytes(f".{short}.{WIDE_TAG}.tmp.exr") <= NAME_MAX
        short.encode("utf-8")  # whole characters only

    @pytest.mark.parametrize("name", ["y" * 251 + ".exr", "é" * 125 + ".png"])
    def test_write_image_writes_a_name_of_255_bytes(self, tmp_path: Path, name: str) -> None:
        path = write_image(tmp_path / name, torch.ones(1, 2, 2), normalized=False)
        assert torch.equal(read_image(path), torch.ones(1, 2, 2))
        assert _listing(tmp_path) == [name]

    def test_atomic_writes_of_names_of_255_bytes(self, tmp_path: Path) -> None:
        write_json(tmp_path / ("j" * 250 + ".json"), {"a": 1})
        write_bytes(tmp_path / ("b" * 255), b"x")
        with atomic_output_dir(tmp_path / ("d" * 255)) as tmp:
            (tmp / "f.txt").write_text("x")
        replace_folder(tmp_path / ("d" * 255), lambda tmp: (tmp / "g.txt").write_text("y"))
        assert _listing(tmp_path) == sorted(["j" * 250 + ".json", "b" * 255, "d" * 255])
        assert _listing(tmp_path / ("d" * 255)) == ["f.txt", "g.txt"]

    def test_stale_temporaries_of_long_names_are_removed(self, tmp_path: Path) -> None:
        dead = _dead_pid()
        image, marker, folder, other = "x" * 251 + ".png", "y" * 250 + ".json", "é" * 127, "w" * 251 + ".png"
        stale = [
            f".{temporary_stem(image, '.png')}.{dead}-0f3c9a1b.tmp.png",
            f".{temporary_stem(marker)}.{dead}-0f3c9a1b.tmp",
            f".{temporary_stem(folder)}.tmp-{dead}-0f3c9a1b",
        ]
        kept = [f".{temporary_stem(other, '.png')}.{dead}-0f3c9a1b.tmp.png"]  # not an output of this batch
        for name in stale + kept:
            (tmp_path / name).mkdir() if ".tmp-" in name else (tmp_path / name).write_text("half")
        removed = remove_stale_temporaries([tmp_path / image, tmp_path / marker, tmp_path / folder])
        assert sorted(p.name for p in removed) == sorted(stale)
        assert _listing(tmp_path) == kept


class TestTemporariesOfTemporaries:
    def test_a_nested_temporary_folder_is_removed(self, tmp_path: Path) -> None:
        dead = _dead_pid()
        outer = f".s06.tmp-{dead}-0f3c9a1b"
        nested = [f".{outer}.tmp-{dead}-93aaaf44", f".{outer}.old-{dead}-93aaaf44", f".{outer}.{dead}-93aaaf44.tmp"]
        for name in [outer, *nested[:2]]:
            (tmp_path / name).mkdir()
        (tmp_path / nested[2]).write_text("half")
        removed = remove_stale_temporaries([tmp_path / "s06"])
        assert sorted(p.name for p in removed) == sorted([outer, *nested])
        assert _listing(tmp_path) == []

    def test_a_nested_temporary_left_alone_is_removed(self, tmp_path: Path) -> None:
        # what an earlier run left: it removed .s06.tmp-... but not the temporary beside it
        dead = _dead_pid()
        nested = f"..s06.tmp-{dead}-cda01c0f.tmp-{dead}-93aaaf44"
        (tmp_path / nested).mkdir()
        assert [p.name for p in remove_stale_temporaries([tmp_path / "s06"])] == [nested]

    def test_nested_temporaries_of_running_writers_or_other_names_are_kept(self, tmp_path: Path) -> None:
        dead, alive = _dead_pid(), os.getpid()
        kept = [
            f"..s06.tmp-{alive}-cda01c0f.tmp-{dead}-93aaaf44",  # the inner writer runs
            f"..s06.tmp-{dead}-cda01c0f.tmp-{alive}-93aaaf44",  # the outer writer runs
            f"..s07.tmp-{dead}-cda01c0f.tmp-{dead}-93aaaf44",  # not an output of this batch
            f"..s06.tmp-{dead}-cda01c0f",  # the name of a temporary, not a temporary of one
        ]
        for name in kept:
            (tmp_path / name).mkdir()
        assert remove_stale_temporaries([tmp_path / "s06"]) == []
        assert _listing(tmp_path) == sorted(kept)

    def test_a_nested_temporary_of_a_long_name_is_removed(self, tmp_path: Path) -> None:
        dead = _dead_pid()
        scene = "s" * 240
        outer = f".{temporary_stem(scene)}.tmp-{dead}-0f3c9a1b"
        nested = f".{temporary_stem(outer)}.tmp-{dead}-93aaaf44"
        assert _bytes(nested) <= NAME_MAX
        (tmp_path / outer).mkdir()
        (tmp_path / nested).mkdir()
        removed = remove_stale_temporaries([tmp_path / scene])
        assert sorted(p.name for p in removed) == sorted([outer, nested])

    def test_a_stack_killed_while_built_in_a_temporary_folder_is_cleaned_up(self, tmp_path: Path) -> None:
        final = tmp_path / "s06"
        _stack(final, frames_json="old stack", notes_txt="my notes")
        _killed(
            """
            from torch_modulo._atomic import replace_folder
            def frames(tmp):
                (tmp / "frame.exr").write_text("half")
                os._exit(9)
            replace_folder(Path(sys.argv[1]), lambda tmp: replace_folder(tmp, frames), {"frames.json"})
            """,
            final,
        )
        assert len(_listing(tmp_path)) == 3  # s06, .s06.tmp-... and ..s06.tmp-....tmp-...
        remove_stale_temporaries([final])
        assert _listing(tmp_path) == ["s06"]
        assert _listing(final) == ["frames.json", "notes.txt"]


def test_the_package_renames_files_in_this_module_only() -> None:
    """Every rename of the package goes through here, so every write follows the rules above."""
    root = Path(_atomic.__file__).parent
    renaming = sorted(
        path.relative_to(root).as_posix()
        for path in root.rglob("*.py")
        if "os.replace(" in path.read_text() or "os.rename(" in path.read_text()
    )
    assert renaming == ["_atomic.py"]
