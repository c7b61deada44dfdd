"""Tests of the batch engine's atomic writes (torch_modulo/batch/atomic.py re-exports torch_modulo/_atomic.py,
tested in tests/test_atomic.py): a run cleans up what a killed run left behind, restores a folder a kill left moved
aside, and reports final paths, never temporary ones."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from fakes import make_inputs as _make_inputs
from fakes import names as _names
from fakes import run as _run

from torch_modulo import _atomic
from torch_modulo._atomic import replace_folder, temporary_file
from torch_modulo.batch import MARKER_FOLDER, Task, atomic
from torch_modulo.batch.engines import _error_text


def _dead_pid() -> int:
    """The id of a process that has exited."""
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def _stack(folder: Path, **files: str) -> None:
    folder.mkdir(parents=True)
    for name, text in files.items():
        (folder / name.replace("_", ".", 1)).write_text(text)


def test_the_atomic_writes_stay_importable_from_the_batch_package() -> None:
    import torch_modulo.batch as batch

    for name in atomic.__all__:
        assert getattr(atomic, name) is getattr(_atomic, name)
    for name in ("atomic_output_dir", "remove_stale_temporaries", "write_json"):
        assert getattr(batch, name) is getattr(_atomic, name)


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

    def test_a_batch_on_an_input_of_240_bytes(self, tmp_path: Path) -> None:
        name = "x" * 236 + ".txt"  # its done marker <name>.json is 245 bytes: its temporary name would be 270
        tasks = _make_inputs(tmp_path, {name: "alpha"})
        report = _run(tasks, tmp_path)
        assert _names(report.done) == [name], report.failed
        assert (tmp_path / "out" / name).read_text() == "ALPHA"
        assert _names(_run(tasks, tmp_path).skipped) == [name]


def _folder_job(task: Task, options: dict[str, Any]) -> None:
    """Writes a folder output (through replace_folder, as simulate does) holding the upper-cased input."""
    text = Path(task.source).read_text()
    replace_folder(Path(task.outputs[0]), lambda tmp: (tmp / "result.txt").write_text(text.upper()), {"result.txt"})


def _image_job(task: Task, options: dict[str, Any]) -> None:
    """Writes an image whose write fails with the temporary's name in the message."""
    path = Path(task.outputs[0]).with_suffix(".png")
    tmp = temporary_file(path, keep_suffix=True)
    raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(tmp))


class TestReportedErrors:
    @pytest.fixture
    def full(self, monkeypatch: pytest.MonkeyPatch) -> None:
        """The output folder's file system has 4096 bytes free."""

        class Stat:
            f_bavail, f_frsize, f_blocks, f_bfree = 1, 4096, 100, 1

        monkeypatch.setattr(_atomic.os, "statvfs", lambda folder: Stat())

    def test_a_corrupt_input_is_not_blamed_on_a_full_disk(self, full: None) -> None:
        task = Task("corrupt.exr", "/in/corrupt.exr", ("/out/corrupt",))
        error = OSError("cannot read image /in/corrupt.exr: EXR Error (/in/corrupt.exr): Unable to read magic")
        assert _error_text(error, task) == f"OSError: {error}"
        write_error = OSError("cannot write /out/corrupt/frame.exr: Could not open")
        assert _error_text(write_error, task).endswith("; No space left on device (4096 bytes free in /out)")

    def test_a_batch_names_final_paths_with_spaces(self, tmp_path: Path) -> None:
        tasks = _make_inputs(tmp_path, {"my scene.exr": "x"})
        report = _run(tasks, tmp_path, job=_image_job)
        assert _names(report.failed) == ["my scene.exr"]
        error = report.failed[0]["error"]
        assert error == f"OSError: [Errno 30] Read-only file system: '{tmp_path / 'out' / 'my scene.png'}'", error
