"""Edge cases of the atomic-write layer (torch_modulo/batch/atomic.py, torch_modulo/sensors/_swap.py and
write_image's temporary file): a kill between a folder swap's two renames, errors that name no file, disk-full notes
on errors that are not about the disk, clean-up that fails on a read-only folder, names near NAME_MAX, and
temporaries of temporaries. Nothing here needs root: read-only and full file systems are played by monkeypatching."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest
import torch
from fakes import make_inputs as _make_inputs
from fakes import names as _names
from fakes import run as _run

from torch_modulo import io as tmio
from torch_modulo.batch import Task, atomic, atomic_output_dir, remove_stale_temporaries, write_json
from torch_modulo.batch.atomic import final_names, free_space_note, write_bytes
from torch_modulo.batch.engines import _error_text
from torch_modulo.io import read_image, temporary_stem, write_image
from torch_modulo.sensors._swap import replace_folder

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


# ------------------------------------------------------------------------------------------------ finding 4


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

        monkeypatch.setattr(atomic.os, "rename", refused)
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
            import torch_modulo.batch.atomic as atomic
            import torch_modulo.sensors._swap as swap
            real, calls = os.replace, []
            def replace(source, target):
                calls.append(source)
                if len(calls) == 2:  # final -> old is done; tmp -> final is not
                    os._exit(9)
                real(source, target)
            os.replace = replace
            final = Path(sys.argv[1])
            if sys.argv[2] == "replace_folder":
                swap.replace_folder(final, lambda tmp: (tmp / "frames.json").write_text("new stack"), {"frames.json"})
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

    def test_a_rerun_of_the_batch_restores_the_old_folder(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a": "alpha"})
        out = tmp_path / "out"
        dead = _dead_pid()
        _stack(out / f".a.old-{dead}-0f3c9a1b", notes_txt="my notes")
        _stack(out / f".a.tmp-{dead}-0f3c9a1b", notes_txt="my notes")
        messages: list[str] = []
        report = _run(tasks, tmp_path, log=messages.append, job=_folder_job)
        assert _names(report.done) == ["a"]
        assert (out / "a" / "notes.txt").read_text() == "my notes"
        assert (out / "a" / "result.txt").read_text() == "ALPHA"
        assert not [name for name in os.listdir(out) if name.startswith(".a.")]
        assert any("removed 1 temporary" in m for m in messages)

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
        monkeypatch.setattr(atomic, "_running", lambda pid: False)  # as after this process ends
        remove_stale_temporaries([final])
        assert _listing(tmp_path) == ["a"] and (final / "notes.txt").read_text() == "my notes"


def _folder_job(task: Task, options: dict[str, Any]) -> None:
    """Writes a folder output (through replace_folder, as simulate does) holding the upper-cased input."""
    text = Path(task.source).read_text()
    replace_folder(Path(task.outputs[0]), lambda tmp: (tmp / "result.txt").write_text(text.upper()), {"result.txt"})


# ------------------------------------------------------------------------------------------------ finding 7


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

        monkeypatch.setattr(atomic.os, "statvfs", lambda folder: Stat())

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

    def test_a_corrupt_input_is_not_blamed_on_a_full_disk(self, full: None) -> None:
        task = Task("corrupt.exr", "/in/corrupt.exr", ("/out/corrupt",))
        error = OSError("cannot read image /in/corrupt.exr: EXR Error (/in/corrupt.exr): Unable to read magic")
        assert _error_text(error, task) == f"OSError: {error}"
        write_error = OSError("cannot write /out/corrupt/frame.exr: Could not open")
        assert _error_text(write_error, task).endswith("; No space left on device (4096 bytes free in /out)")


# ------------------------------------------------------------------------------------------------ finding 8


def _read_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """Unlinking fails as on a read-only file system (EROFS, even for a file that is not there)."""

    def unlink(self: Path, missing_ok: bool = False) -> None:
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))

    monkeypatch.setattr(Path, "unlink", unlink)


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

        monkeypatch.setattr(tmio.os, "replace", refused)
        path = tmp_path / "a.exr"
        with pytest.raises(PermissionError) as info:
            write_image(path, torch.ones(1, 2, 2))
        assert info.value.filename == str(path)
        monkeypatch.undo()
        assert _listing(tmp_path) == []

    def test_final_names_reads_names_with_spaces(self) -> None:
        text = (
            "[Errno 30] Read-only file system: '/out/.my scene.25895-4d363d48.tmp.png'; "
            "see /out/.my stack.tmp-1-ab/frame 1.exr and ..s 6.tmp-1-ab.tmp-1-cd/frames.json"
        )
        assert final_names(text) == (
            "[Errno 30] Read-only file system: '/out/my scene.png'; see /out/my stack/frame 1.exr and s 6/frames.json"
        )
        assert final_names("'.x.1-ab.tmp.exr' and /out/.hidden dir/a.exr") == "'x.exr' and /out/.hidden dir/a.exr"

    def test_a_batch_names_final_paths_with_spaces(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"my scene.exr": "x"})
        report = _run(tasks, tmp_path, job=_image_job)
        assert _names(report.failed) == ["my scene.exr"]
        error = report.failed[0]["error"]
        assert error == f"OSError: [Errno 30] Read-only file system: '{tmp_path / 'out' / 'my scene.png'}'", error


def _image_job(task: Task, options: dict[str, Any]) -> None:
    """Writes an image whose write fails with the temporary's name in the message."""
    path = Path(task.outputs[0]).with_suffix(".png")
    tmp = tmio._temporary_sibling(path)
    raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(tmp))


# ------------------------------------------------------------------------------------------------ finding 9

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

    def test_short_names_are_spelt_out(self) -> None:
        assert temporary_stem("scene.exr", ".exr") == "scene"
        assert temporary_stem("scene.exr") == "scene.exr"
        assert tmio._temporary_sibling(Path("/out/scene.exr")).name.startswith(".scene.")

    def test_utf8_bytes_not_characters_are_counted(self) -> None:
        name = "日" * 83 + ".exr"  # 87 characters, 253 bytes: its temporary name would pass 255 bytes
        short = temporary_stem(name, ".exr")
        assert short != "日" * 84 and short.startswith("日" * 60)
        assert _bytes(f".{short}.{WIDE_TAG}.tmp.exr") <= NAME_MAX
        short.encode("utf-8")  # whole characters only

    @pytest.mark.parametrize("name", ["y" * 251 + ".exr", "é" * 125 + ".png"])
    def test_write_image_writes_a_name_of_255_bytes(self, tmp_path: Path, name: str) -> None:
        path = write_image(tmp_path / name, torch.ones(1, 2, 2))
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

    def test_a_batch_on_an_input_of_240_bytes(self, tmp_path: Path) -> None:
        name = "x" * 236 + ".txt"  # its done marker <name>.json is 245 bytes: its temporary name would be 270
        tasks = _make_inputs(tmp_path, {name: "alpha"})
        report = _run(tasks, tmp_path)
        assert _names(report.done) == [name], report.failed
        assert (tmp_path / "out" / name).read_text() == "ALPHA"
        assert _names(_run(tasks, tmp_path).skipped) == [name]


# ------------------------------------------------------------------------------------------------ finding 10


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
            import torch_modulo.sensors._swap as swap
            def frames(tmp):
                (tmp / "frame.exr").write_text("half")
                os._exit(9)
            swap.replace_folder(Path(sys.argv[1]), lambda tmp: swap.replace_folder(tmp, frames), {"frames.json"})
            """,
            final,
        )
        assert len(_listing(tmp_path)) == 3  # s06, .s06.tmp-... and ..s06.tmp-....tmp-...
        remove_stale_temporaries([final])
        assert _listing(tmp_path) == ["s06"]
        assert _listing(final) == ["frames.json", "notes.txt"]
