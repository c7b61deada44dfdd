"""The Ray engine of torch_modulo/batch/engines.py on a real local Ray instance, not the stand-in module of
test_engines.py: a folder run of the tone-mapping job with one bad file, its report, and a resume.

Skipped when Ray is not installed (``pip install 'torch_modulo[ray]'``). The Ray instance is started once for the
module, on this machine only (``address="local"``, so ``RAY_ADDRESS`` cannot send the test to a cluster), with 2 CPUs
and no dashboard; starting it is most of the test's time.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import torch

from torch_modulo.batch import run_batch
from torch_modulo.folders import folder_tasks
from torch_modulo.io import read_image, write_image
from torch_modulo.pipeline import tonemap_job, tonemap_options

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module")
def local_ray() -> Iterator[Any]:
    """A local Ray instance with 2 CPUs, shut down after the module's tests."""
    if ray.is_initialized():
        pytest.skip("a Ray instance is already running in this process")
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield ray
    finally:
        ray.shutdown()


def _radiance(seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return torch.exp2(torch.rand(3, 6, 8, generator=gen) * 12 - 6)


def _folder(src: Path) -> None:
    """Three radiance files (one in a subfolder) and one file that is not an image."""
    (src / "sub").mkdir(parents=True)
    write_image(src / "a.exr", _radiance(0))
    write_image(src / "c.hdr", _radiance(1))
    write_image(src / "sub" / "b.exr", _radiance(2))
    (src / "bad.exr").write_bytes(b"not an image")


def _names(entries: list[dict[str, Any]]) -> list[str]:
    return sorted(e["input"] for e in entries)


def test_folder_run_report_and_resume_on_a_real_ray(local_ray: Any, tmp_path: Path) -> None:
    src, out, reference = tmp_path / "in", tmp_path / "out", tmp_path / "reference"
    _folder(src)
    tasks, _ = folder_tasks("tonemap", src, out)
    options = tonemap_options("reinhard", {}, srgb=True)
    messages: list[str] = []

    def tonemap(**kwargs: Any) -> Any:
        return run_batch(
            "tonemap", tasks, tonemap_job, options, out, input_path=src, engine="ray", progress=False,
            log=messages.append, **kwargs,
        )  # fmt: skip

    # The first run: the Ray workers tone-map the three radiance files; the bad one fails alone, named.
    first = tonemap()
    assert first.engine == "ray" and first.workers == 2  # the local instance's 2 CPUs
    assert _names(first.done) == ["a.exr", "c.hdr", "sub/b.exr"]
    assert _names(first.failed) == ["bad.exr"] and first.exit_code == 1
    error = first.failed[0]["error"]
    assert error.startswith("OSError: cannot read image ") and "bad.exr" in error
    assert any("bad.exr" in m for m in messages)
    for task in tasks:  # what the Ray workers wrote is what the job writes in this process
        if task.name == "bad.exr":
            assert not Path(task.outputs[0]).exists()
            continue
        here = Path(reference, task.name).with_suffix(".png")
        here.parent.mkdir(parents=True, exist_ok=True)
        tonemap_job(type(task)(task.name, task.source, (str(here),)), options)
        assert torch.equal(read_image(task.outputs[0]), read_image(here))

    # The report on the disk says the same.
    saved = json.loads((out / "tonemap-report.json").read_text())
    assert saved["engine"] == "ray" and saved["workers"] == 2
    assert saved["counts"] == {"total": 4, "done": 3, "skipped": 0, "failed": 1, "not_finished": 0}
    assert saved["failed"][0]["input"] == "bad.exr" and saved["failed"][0]["error"] == error

    # A resume after the bad file is replaced: only that file runs; the finished outputs are not rewritten.
    stamps = {t.name: os.stat(t.outputs[0]).st_mtime_ns for t in tasks if t.name != "bad.exr"}
    write_image(src / "bad.exr", _radiance(3))
    resumed = tonemap()
    assert _names(resumed.skipped) == ["a.exr", "c.hdr", "sub/b.exr"]
    assert _names(resumed.done) == ["bad.exr"] and not resumed.failed and resumed.exit_code == 0
    assert {t.name: os.stat(t.outputs[0]).st_mtime_ns for t in tasks if t.name != "bad.exr"} == stamps
    assert (out / "bad.png").is_file()
    assert json.loads((out / "tonemap-report.json").read_text())["counts"]["skipped"] == 3
