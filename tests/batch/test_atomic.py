"""Tests of torch_modulo/batch/atomic.py: atomic JSON files and folders, errors that name final paths, and the
clean-up of what a killed run left behind."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from fakes import make_inputs as _make_inputs
from fakes import names as _names
from fakes import run as _run

from torch_modulo.batch import MARKER_FOLDER, atomic_output_dir, remove_stale_temporaries, write_json
from torch_modulo.batch.atomic import final_names, write_bytes


def _dead_pid() -> int:
    """The id of a process that has exited."""
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


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

    def test_final_names(self) -> None:
        text = 'Failed to write "/out/.a.123-0f3c9a1b.tmp.exr"; /out/.s.tmp-123-ab/frames.json, /m/.x.exr.json.1-ff.tmp'
        assert final_names(text) == 'Failed to write "/out/a.exr"; /out/s/frames.json, /m/x.exr.json'
        assert final_names("/out/.hidden/a.exr and /out/.b.exr") == "/out/.hidden/a.exr and /out/.b.exr"


class TestStaleTemporaries:
    def test_stale_temporaries_from_a_killed_run_are_removed(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"a.txt": "alpha", "sub/b.txt": "beta"})
        out = tmp_path / "out"
        (out / "sub").mkdir(parents=True)
        dead = _dead_pid()
        stale = [
            out / f".a.{dead}-0f3c9a1b.tmp.txt",  # an image or text file written by write_image
            out / "sub" / f".b.txt.tmp-{dead}-0f3c9a1b",  # a folder of atomic_output_dir
            out / f".upper-report.json.{dead}-0f3c9a1b.tmp",  # the report
            out / MARKER_FOLDER / "upper" / f".a.txt.json.{dead}-0f3c9a1b.tmp",  # a done marker
        ]
        kept = [
            out / f".a.{os.getpid()}-0f3c9a1b.tmp.txt",  # its writer still runs
            out / f".other.{dead}-0f3c9a1b.tmp.txt",  # not the temporary of an output of this batch
            out / ".notes",
        ]
        for path in stale + kept:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.mkdir() if path.name.startswith(".b.txt.tmp-") else path.write_text("half")
        messages: list[str] = []
        report = _run(tasks, tmp_path, log=messages.append)
        assert _names(report.done) == ["a.txt", "sub/b.txt"]
        assert not any(p.exists() for p in stale)
        assert all(p.exists() for p in kept)
        assert any("removed 4 temporary" in m for m in messages)

    def test_kill_9_leftovers_are_cleaned_up_by_the_rerun(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"scene.txt": "alpha"})
        out = tmp_path / "out"
        out.mkdir()
        script = (
            "import os, sys, time\n"
            "os.mkdir(os.path.join(sys.argv[1], '.scene.txt.tmp-%d-0f3c9a1b' % os.getpid()))\n"
            "open(os.path.join(sys.argv[1], '.scene.%d-0f3c9a1b.tmp.txt' % os.getpid()), 'w').write('half')\n"
            "print('ready', flush=True)\n"
            "time.sleep(60)\n"
        )
        process = subprocess.Popen([sys.executable, "-c", script, str(out)], stdout=subprocess.PIPE, text=True)
        assert process.stdout is not None and process.stdout.readline().strip() == "ready"
        left = sorted(p.name for p in out.iterdir())
        assert len(left) == 2
        assert _names(_run(tasks, tmp_path).done) == ["scene.txt"]  # a run while the writer lives keeps them
        assert sorted(p.name for p in out.iterdir() if p.name.startswith(".scene")) == left
        process.send_signal(signal.SIGKILL)
        process.wait()
        again = _run(tasks, tmp_path)
        assert _names(again.skipped) == ["scene.txt"]
        assert not [p.name for p in out.iterdir() if p.name.startswith(".scene")]

    def test_remove_stale_temporaries_only_touches_the_given_outputs(self, tmp_path: Path) -> None:
        dead = _dead_pid()
        (tmp_path / f".a.png.old-{dead}-ab").mkdir()
        (tmp_path / f".a.{dead}-ab.tmp.png").write_text("x")
        (tmp_path / f".b.{dead}-ab.tmp.png").write_text("x")
        removed = remove_stale_temporaries([tmp_path / "a.png", tmp_path / "missing" / "c.png"])
        assert [p.name for p in removed] == sorted([f".a.png.old-{dead}-ab", f".a.{dead}-ab.tmp.png"])
        assert sorted(p.name for p in tmp_path.iterdir()) == [f".b.{dead}-ab.tmp.png"]


def test_a_folder_swapped_through_a_link_is_restored_beside_its_target(tmp_path: Path) -> None:
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
