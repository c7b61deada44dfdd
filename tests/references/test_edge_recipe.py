"""Tests of references/learned_single/train.py, the recipe of the learned method's edge network: its samples (crops,
exposures, mosaics, powers), its batches in worker processes, its scenes folder, and tiny training runs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from references.learned_single import train
from torch_modulo.cfa import interpolate_wrapped, mosaic
from torch_modulo.singleshot.learned import load_model

ROOT = Path(__file__).resolve().parents[2]


def scene(size: int = 48, seed: int = 0) -> np.ndarray:
    """(size, size) counts: a dark floor, a smooth bump and a bright lamp whose border steps by several periods."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    img = 20 + 8 * x + 600 * np.exp(-((y - size / 2) ** 2 + (x - size / 3) ** 2) / (size * size / 8))
    lamp = (np.abs(y - 0.7 * size) < size / 8) & (np.abs(x - 0.7 * size) < size / 8)
    img = img + 1500 * lamp + rng.uniform(0, 3, img.shape)
    return np.floor(img)


class TestTraining:
    def test_mosaic_pairs(self) -> None:
        """The training recipe's mosaic samples: the guide unwrap_single sees, a target congruent with it that keeps
        the true photosite counts, and is the true counts where the colours are linear ramps."""
        counts = torch.from_numpy(np.stack([scene(24, s) for s in range(3)])).double()
        guide, target = train.mosaic_pair(counts, "BGGR")
        assert torch.equal(guide, interpolate_wrapped(mosaic(counts, "BGGR") % 256, "BGGR"))
        assert torch.equal(torch.remainder(target, 256), guide)
        assert torch.equal(mosaic(target, "BGGR"), mosaic(counts, "BGGR"))
        y, x = torch.meshgrid(torch.arange(24.0), torch.arange(24.0), indexing="ij")
        smooth = torch.stack([300 + 40 * x, 100 + 30 * (x + y), 500 + 25 * y])
        inner = np.s_[:, 1:-1, 1:-1]  # the borders are mirrored, not extrapolated
        assert torch.equal(train.mosaic_pair(smooth, "RGGB")[1][inner], smooth[inner])

    def test_crop_scales(self) -> None:
        """Crops are area averages of the scene by the drawn factor, or by the largest factor the scene fits."""
        flat = torch.full((3, 40, 64), 7.0)
        flat[:, :, 1::2] = 9.0  # columns alternate: a 2x2 (or 4x4) average is 8 everywhere
        rng = np.random.default_rng(0)
        for _ in range(8):
            crop = train.random_crop([flat], 10, rng, scales=(4,))
            assert crop.shape == (3, 10, 10) and torch.equal(crop, torch.full_like(crop, 8.0))
        small = train.random_crop([flat], 16, rng, scales=(4,))  # 4 x 16 > 40 rows: falls back to 2
        assert torch.equal(small, torch.full_like(small, 8.0))
        native = train.random_crop([flat], 30, rng, scales=(2,))  # 2 x 30 > 40 rows: falls back to 1
        assert set(native.unique().tolist()) == {7.0, 9.0}
        scenes = [torch.full((3, 40, 64), 1.0), torch.full((3, 40, 64), 2.0)]
        for _ in range(6):
            crop, index = train.random_crop(scenes, 10, rng, with_index=True)
            assert crop.shape == (3, 10, 10) and torch.equal(crop, torch.full_like(crop, index + 1.0))

    def test_batches_in_workers(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        """``--workers``: batches made in worker processes, repeatable, and a whole (tiny) training run with them."""
        ramp = torch.linspace(0.0, 1.0, 48).repeat(3, 48, 1) ** 4  # a bright corner
        args = train.parse_args(["--batch", "2", "--crop", "16", "--seed", "3"])
        first = next(iter(train.Batches([ramp], args, [])))
        assert first[0].shape == first[1].shape == (2, 3, 16, 16)
        assert torch.equal(first[0], torch.remainder(first[1], 256))  # wrapped inputs of the true counts
        loader = torch.utils.data.DataLoader(train.Batches([ramp], args, []), batch_size=None, num_workers=2)
        a, b = [batch for batch, _ in zip(loader, range(2), strict=False)]
        again = next(iter(torch.utils.data.DataLoader(train.Batches([ramp], args, []), batch_size=None, num_workers=2)))
        assert torch.equal(a[1], again[1]) and not torch.equal(a[1], b[1])  # per-worker seeds: repeatable, distinct
        monkeypatch.setattr(train, "load_train_scenes", lambda side, folder: [ramp])
        out = tmp_path / "run"
        argv = ["--out", str(out), "--steps", "2", "--crop", "16", "--batch", "1", "--width", "4", "--threads", "1"]
        summary = train.train(train.parse_args([*argv, "--workers", "2", "--log-every", "1"]))
        assert summary["steps"] == 2 and load_model(out / "edge_jump.pt").config["width"] == 4

    def test_data_folder(self, tmp_path: Path) -> None:
        """``--data``: the training scenes of another folder (a copy of the CC0/BSD ones, say), never its
        validation scenes."""
        from torch_modulo.io import write_image

        ramp = torch.linspace(0.01, 1.0, 48).repeat(3, 40, 1) ** 4
        for rel, image in (("polyhaven-cc0/a.exr", ramp), ("hdr-samples/b.exr", ramp.flip(-1))):
            (tmp_path / "data" / rel).parent.mkdir(parents=True)
            write_image(tmp_path / "data" / rel, image)
        scenes = train.load_train_scenes(64, tmp_path / "data")
        assert len(scenes) == 1 and torch.allclose(scenes[0], ramp, rtol=1e-3)  # EXR half precision
        argv = ["--out", str(tmp_path / "run"), "--steps", "1", "--crop", "16", "--batch", "1", "--width", "4"]
        assert train.train(train.parse_args([*argv, "--data", str(tmp_path / "data")]))["steps"] == 1
        with pytest.raises(SystemExit, match="no training scenes under"):
            train.train(train.parse_args([*argv, "--data", str(tmp_path / "empty")]))

    def test_radiance_power(self) -> None:
        """``--gamma``: a crop's stops scale by the power, its shading stays multiplicative, and batches still wrap
        their true counts."""
        texture, shading = torch.rand(3, 8, 8) + 0.5, torch.linspace(1.0, 64.0, 8).view(1, 1, 8)
        powered = train.radiance_power(texture * shading, 1.5)
        torch.testing.assert_close(powered, texture**1.5 * shading**1.5)
        assert float(train.radiance_power(torch.tensor([-1.0, 4.0]), 0.5)[0]) == 0.0  # negatives clamped
        ramp = torch.linspace(0.0, 1.0, 48).repeat(3, 48, 1) ** 4
        args = train.parse_args(["--batch", "2", "--crop", "16", "--gamma", "1.5", "--procedural", "0"])
        wrapped, counts = train.make_batch([ramp], 2, 16, np.random.default_rng(0), args)
        assert torch.equal(wrapped, torch.remainder(counts, 256)) and float(counts.max()) >= 512
        with pytest.raises(SystemExit, match="--gamma must be >= 1"):
            train.train(train.parse_args(["--gamma", "0.67", "--steps", "1"]))

    def test_scene_exposure(self) -> None:
        """Exposed by the whole scene, a dark crop of a scene with a bright lamp does not roll over; exposed by
        itself, it always rolls over at least twice."""
        scene = torch.full((3, 32, 32), 0.1)
        scene[:, :4, :4] = 100.0  # the lamp: the scene's top percentiles
        references = train.exposure_references(scene)
        assert references[True][100.0] == pytest.approx(100.0) and references[False][99.0] == pytest.approx(100.0)
        dark = scene[:, 16:, 16:]
        rng = np.random.default_rng(0)
        for _ in range(6):
            assert float(train.capture_pair(dark, rng, 0.0, references).max()) < 256  # at most 20 periods x 0.1 / 100
            assert float(train.capture_pair(dark, rng, 0.0).max()) >= 512


def test_runs_as_modules_from_the_repository_root() -> None:
    """The recipes are a package: each runs as ``python -m references.learned_single.NAME`` from the repository root,
    with no path edit (one process runs the three as ``-m`` does, with ``--help``)."""
    script = (
        "import runpy, sys\n"
        "for name in ('train', 'levels', 'fetch_selection_scenes'):\n"
        "    sys.argv = [name, '--help']\n"
        "    try:\n"
        "        runpy.run_module(f'references.learned_single.{name}', run_name='__main__', alter_sys=True)\n"
        "    except SystemExit as done:\n"
        "        assert done.code == 0, (name, done.code)\n"
        "    else:\n"
        "        raise AssertionError(f'{name} --help did not exit')\n"
    )
    done = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("usage:") == 3
