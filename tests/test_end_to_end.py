"""End-to-end tests of the folder commands (``torch-modulo simulate``, ``unwrap``, ``tonemap``) on small generated
scenes: what the files hold, what the reports say, and the promises every folder command keeps (inputs never
written, atomic outputs, resume, one bad file reported and skipped, torchrun and Ray). The options, messages and
exit codes of the command line are tested in test_cli.py; the jobs as Python functions in test_pipeline.py."""

from __future__ import annotations

import hashlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from cli_scenes import ROOT, write_scenes
from cli_scenes import names as _names
from cli_scenes import read_report as _report
from cli_scenes import run_cli as _cli
from cli_scenes import scene as _scene

from torch_modulo import capture_modulo, merge_intensity, plan_exposures, unwrap_multi
from torch_modulo.batch import MARKER_FOLDER
from torch_modulo.cli import main
from torch_modulo.io import read_image, read_metadata, write_image
from torch_modulo.sensors import FileSensor, FrameStack, NoiseModel, SimulatedModuloSensor, write_frames
from torch_modulo.tonemap import tonemap_clahe, tonemap_gamma, tonemap_histogram, tonemap_reinhard

TAUS = [1.0, 256.0, 65536.0]


@pytest.fixture
def scenes(tmp_path: Path) -> Path:
    """IN/ with three scenes: a.exr, b.hdr (RGBE) and sub/c.exr (a small negative value, as lossy files have)."""
    return write_scenes(tmp_path / "in")


def _digest(folder: Path) -> dict[str, tuple[str, int]]:
    """Content hash and modification time of every file under folder (to prove inputs are never touched)."""
    return {
        p.relative_to(folder).as_posix(): (hashlib.sha256(p.read_bytes()).hexdigest(), p.stat().st_mtime_ns)
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _truth(path: Path) -> torch.Tensor:
    """What simulate captures from a file: its values clamped at 0, scaled so the maximum reads 255 at tau = 1."""
    x = read_image(path, dtype=torch.float64).clamp_min(0)
    return x * (255.0 / float(x.max()))


# --------------------------------------------------------------------------------------------------- simulate


class TestSimulate:
    def test_end_to_end(self, scenes: Path, tmp_path: Path) -> None:
        before = _digest(scenes)
        out = tmp_path / "stacks"
        args = ("--bits", 8, "--exposures", "1,256,65536", "--noise", "none", "--workers", 1)
        assert _cli("simulate", scenes, out, *args) == 0
        assert _digest(scenes) == before
        report = _report(out, "simulate")
        assert _names(report["done"]) == ["a.exr", "b.hdr", "sub/c.exr"]
        assert report["counts"]["failed"] == 0 and report["options"]["exposures"] == TAUS
        for name, folder in (("a.exr", out / "a"), ("b.hdr", out / "b"), ("sub/c.exr", out / "sub" / "c")):
            stack = FileSensor(folder, dtype=torch.float64).read()
            assert stack.bits == 8 and stack.exposures.tolist() == TAUS and stack.kind == "modulo"
            truth = read_image(folder / "radiance.exr", dtype=torch.float64)
            expected = _truth(scenes / name)
            torch.testing.assert_close(truth, expected, rtol=1e-6, atol=0)  # float32 file
            # noise-free: the frames are Eq. 1 of the stored truth
            for m, tau in enumerate(TAUS):
                assert torch.equal(stack.moduli[0, m], capture_modulo(truth, tau, bits=8))
            assert stack.metadata["source"] == name
            assert stack.metadata["radiance_scale"] == pytest.approx(
                255.0 / float(read_image(scenes / name, dtype=torch.float64).clamp_min(0).max())
            )
            meta = read_metadata(folder / "frame_b000_m02.exr")
            assert meta["bits"] == 8 and meta["exposure"] == 65536.0
        assert _names(report["done"])[2] == "sub/c.exr" and report["done"][2]["negatives_clamped"] == 1

    def test_noise_is_reproducible_whatever_the_workers(self, scenes: Path, tmp_path: Path) -> None:
        runs = {}
        for label, workers, seed in (("w1", 1, 3), ("w2", 2, 3), ("seed4", 1, 4)):
            out = tmp_path / label
            assert (
                _cli("simulate", scenes, out, "--noise", "read=2,prnu=0.01", "--seed", seed, "--workers", workers) == 0
            )
            runs[label] = {s: FileSensor(out / s).read() for s in ("a", "b", "sub/c")}
        assert all(runs["w1"][s] == runs["w2"][s] for s in runs["w1"])
        assert all(not torch.equal(runs["w1"][s].moduli, runs["seed4"][s].moduli) for s in runs["w1"])
        assert runs["w1"]["a"].metadata["noise"]["read_noise"] == 2.0
        # different scenes draw different noise (per-scene seeds)
        assert runs["w1"]["a"].metadata["seed"] != runs["w1"]["b"].metadata["seed"]

    def test_png_frames_without_truth(self, scenes: Path, tmp_path: Path) -> None:
        out = tmp_path / "png"
        assert (
            _cli(
                "simulate",
                scenes / "a.exr",
                out,
                "--bits",
                10,
                "--exposures",
                "1,32",
                "--format",
                "png",
                "--no-truth",
                "--scale",
                2.5,
                "--noise",
                "none",
            )
            == 0
        )
        assert sorted(p.name for p in (out / "a").iterdir()) == [
            "frame_b000_m00.png",
            "frame_b000_m01.png",
            "frames.json",
        ]
        stack = FileSensor(out / "a", dtype=torch.float64).read()
        x = read_image(scenes / "a.exr", dtype=torch.float64).clamp_min(0) * 2.5
        assert stack.bits == 10
        assert torch.equal(stack.moduli[0, 1], capture_modulo(x, 32.0, bits=10))

    def test_extra_channels_are_dropped(self, tmp_path: Path) -> None:
        (tmp_path / "in").mkdir()
        rgb = _scene(5)
        write_image(tmp_path / "in" / "rgba.exr", torch.cat([rgb, torch.ones(1, 12, 16)]))
        write_image(tmp_path / "in" / "views.exr", torch.cat([rgb, _scene(6), _scene(7)]))  # like a multi-view EXR
        write_image(tmp_path / "in" / "ya.exr", torch.cat([rgb[:1], torch.ones(1, 12, 16)]))
        assert _cli("simulate", tmp_path / "in", tmp_path / "out", "--exposures", "1,16", "--noise", "none") == 0
        for name, channels in (("rgba", 3), ("views", 3), ("ya", 1)):
            stack = FileSensor(tmp_path / "out" / name, dtype=torch.float64).read()
            assert stack.moduli.shape == (1, 2, channels, 12, 16)
            truth = read_image(tmp_path / "out" / name / "radiance.exr", dtype=torch.float64)
            expected = rgb[:channels].double() * (255.0 / float(rgb[:channels].max()))
            torch.testing.assert_close(truth, expected.float().double(), rtol=0, atol=0)


# ----------------------------------------------------------------------------------------------------- unwrap


class TestUnwrap:
    def test_multi_shot_end_to_end(self, scenes: Path, tmp_path: Path) -> None:
        stacks, radiance = tmp_path / "stacks", tmp_path / "radiance"
        assert _cli("simulate", scenes, stacks, "--noise", "none", "--exposures", "1,256,65536") == 0
        before = _digest(stacks)
        assert _cli("unwrap", stacks, radiance, "--workers", 2) == 0
        assert _digest(stacks) == before
        assert _names(_report(radiance, "unwrap")["done"]) == ["a", "b", "sub/c"]
        for name in ("a", "b", "sub/c"):
            restored, meta = read_image(radiance / f"{name}.exr", with_metadata=True, dtype=torch.float64)
            truth = read_image(stacks / name / "radiance.exr", dtype=torch.float64)
            # exact rollover counts: the radiance is floor(tau_max E) / tau_max
            expected = torch.floor(truth * TAUS[-1]) / TAUS[-1]
            torch.testing.assert_close(restored, expected, rtol=2**-23, atol=0)
            assert meta["bits"] == 8 and meta["exposures"] == TAUS and meta["method"] == "robust"

    def test_intensity_stack_is_merged(self, tmp_path: Path) -> None:
        frames = torch.stack([torch.floor(_scene(6) * t).clamp(max=255) for t in (0.05, 1.0, 20.0)])
        stack = FrameStack(frames, [0.05, 1.0, 20.0], bits=8, kind="intensity")
        write_frames(stack, tmp_path / "in" / "clipped")
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out") == 0
        restored, meta = read_image(tmp_path / "out" / "clipped.exr", with_metadata=True, dtype=torch.float64)
        expected = merge_intensity(frames.double(), [0.05, 1.0, 20.0], bits=8)
        torch.testing.assert_close(restored, expected, rtol=1e-6, atol=0)
        assert meta["method"] == "merge_intensity"

    def test_paper_method_and_bits_override(self, tmp_path: Path) -> None:
        radiance = _scene(7) / 16  # max 256 * 1.6 / 16 < 255 at tau = 1
        taus = [1.0, 100.0, 10000.0]
        stack = FrameStack(torch.stack([capture_modulo(radiance, t, bits=8) for t in taus]), taus, bits=8)
        write_frames(stack, tmp_path / "in" / "s")
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out", "--method", "paper") == 0
        restored = read_image(tmp_path / "out" / "s.exr", dtype=torch.float64)
        expected = unwrap_multi(stack.moduli.double(), taus, bits=8, method="paper")[0]
        torch.testing.assert_close(restored, expected.float().double(), rtol=0, atol=0)

    def test_single_shot(self, tmp_path: Path) -> None:
        singleshot = pytest.importorskip("torch_modulo.singleshot")
        if not hasattr(singleshot, "unwrap_single"):
            pytest.skip("torch_modulo.singleshot.unwrap_single is not there yet")
        (tmp_path / "in").mkdir()
        counts = torch.floor(torch.linspace(0, 900, 24).view(1, 1, 24).expand(1, 10, 24)).contiguous()
        modulus = torch.remainder(counts, 256)
        write_image(tmp_path / "in" / "ramp.png", modulus, {"bits": 8, "exposure": 2.0})
        write_image(tmp_path / "in" / "nobits.png", modulus)  # no bit depth anywhere: reported, not guessed
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out", "--single") == 1
        report = _report(tmp_path / "out", "unwrap")
        assert _names(report["done"]) == ["ramp.png"]
        assert "no bit depth" in report["failed"][0]["error"] and "nobits.png" in report["failed"][0]["error"]
        restored, meta = read_image(tmp_path / "out" / "ramp.exr", with_metadata=True, dtype=torch.float64)
        expected = singleshot.unwrap_single(modulus.unsqueeze(0), 8)[0].double() / 2.0
        torch.testing.assert_close(restored, expected)
        torch.testing.assert_close(restored, counts.double() / 2.0)  # a smooth ramp unwraps exactly
        assert meta["exposure"] == 2.0 and meta["method"] == "single" and meta["solver"] == "default"
        # another solver is another option: the rerun redoes the image
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out", "--single", "--solver", "fast", "--bits", 8) == 0
        assert _names(_report(tmp_path / "out", "unwrap")["done"]) == ["nobits.png", "ramp.png"]
        # the number of workers is not: the next rerun skips both
        assert (
            _cli(
                "unwrap", tmp_path / "in", tmp_path / "out", "--single", "--solver", "fast", "--bits", 8, "--workers", 1
            )
            == 0
        )
        assert _names(_report(tmp_path / "out", "unwrap")["skipped"]) == ["nobits.png", "ramp.png"]

    def test_single_shot_checks_the_metadata(self, tmp_path: Path) -> None:
        (tmp_path / "in").mkdir()
        modulus = torch.remainder(torch.floor(torch.linspace(0, 900, 24)).view(1, 1, 24).expand(1, 4, 24), 256)
        bad = {"neg": {"bits": 8, "exposure": -2}, "nan": {"bits": 8, "exposure": float("nan")}, "zero": {"bits": 8}}
        bad |= {"inf": {"bits": 8, "exposure": float("inf")}, "frac": {"bits": 8.7}, "bool": {"bits": True}}
        bad["zero"]["exposure"] = 0
        for name, meta in bad.items():
            write_image(tmp_path / "in" / f"{name}.exr", modulus, meta)
        write_image(tmp_path / "in" / "good.exr", modulus, {"bits": 8.0, "exposure_time": 4})
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out", "--single") == 1
        report = _report(tmp_path / "out", "unwrap")
        assert _names(report["done"]) == ["good.exr"]
        errors = {e["input"]: e["error"] for e in report["failed"]}
        assert sorted(errors) == sorted(f"{name}.exr" for name in bad)
        for name in ("neg", "nan", "inf", "zero"):
            assert "exposure from the metadata of" in errors[f"{name}.exr"], errors[f"{name}.exr"]
        for name in ("frac", "bool"):
            assert "bits from the metadata of" in errors[f"{name}.exr"], errors[f"{name}.exr"]
        restored = read_image(tmp_path / "out" / "good.exr", dtype=torch.float64)
        expected = torch.floor(torch.linspace(0, 900, 24, dtype=torch.float64)).view(1, 1, 24).expand(1, 4, 24)
        torch.testing.assert_close(restored * 4, expected)

    def test_single_shot_confidence(self, tmp_path: Path) -> None:
        from torch_modulo.singleshot import unwrap_confidence

        (tmp_path / "in").mkdir()
        counts = torch.floor(torch.linspace(0, 900, 24).view(1, 1, 24).expand(1, 10, 24)).contiguous()
        counts[:, 3:6, 8:12] += 1664  # a block 6.5 periods up: steep steps all round, its level is a guess
        write_image(tmp_path / "in" / "img.png", torch.remainder(counts, 256), {"bits": 8})
        guided = ("--single", "--method", "guided")
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out", *guided) == 0
        assert not (tmp_path / "out" / "img.confidence.exr").exists()
        # asking for the map is another option: the image is redone and both files are written
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out", *guided, "--confidence") == 0
        assert _names(_report(tmp_path / "out", "unwrap")["done"]) == ["img.png"]
        restored = read_image(tmp_path / "out" / "img.exr", dtype=torch.float64)
        confidence, meta = read_image(tmp_path / "out" / "img.confidence.exr", with_metadata=True)
        torch.testing.assert_close(confidence.double(), unwrap_confidence(restored, 8).float().double())
        assert float(confidence[:, 3:6, 8:12].max()) < 0.35 < 0.5 < float(confidence[:, 8:, :].min())
        assert meta["unit"] == "confidence in [0, 1]"
        (tmp_path / "out" / "img.confidence.exr").unlink()  # a missing output makes the task incomplete
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out", *guided, "--confidence") == 0
        assert (tmp_path / "out" / "img.confidence.exr").exists()

    def test_single_shot_method_options(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        from torch_modulo.singleshot.learned import solver  # where the learned method calls its level moves

        calls = []
        real = solver.region_moves
        monkeypatch.setattr(solver, "region_moves", lambda *a, **kw: calls.append(1) or real(*a, **kw))
        (tmp_path / "in").mkdir()
        counts = torch.floor(torch.linspace(0, 900, 24).view(1, 1, 24).expand(1, 10, 24)).contiguous()
        write_image(tmp_path / "in" / "img.png", torch.remainder(counts, 256), {"bits": 8})
        tree = ("--single", "--method", "learned: levels=false")  # spaces and any case
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out", *tree) == 0
        assert not calls  # the option reached unwrap_single
        meta = read_metadata(tmp_path / "out" / "img.exr")
        assert meta["solver"] == "learned" and meta["solver_options"] == {"levels": False}
        assert meta["learned_version"] == 3
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out", *tree) == 0  # the same options: skipped
        assert _names(_report(tmp_path / "out", "unwrap")["skipped"]) == ["img.png"]
        assert (
            _cli("unwrap", tmp_path / "in", tmp_path / "out", "--single", "--method", "learned") == 0
        )  # others: redone
        assert _names(_report(tmp_path / "out", "unwrap")["done"]) == ["img.png"] and calls
        assert "solver_options" not in read_metadata(tmp_path / "out" / "img.exr")

    def test_single_shot_learned_confidence(self, tmp_path: Path) -> None:
        from torch_modulo.singleshot import learned_confidence

        (tmp_path / "in").mkdir()
        counts = torch.floor(torch.linspace(0, 900, 24).view(1, 1, 24).expand(1, 10, 24)).contiguous()
        modulus = torch.remainder(counts, 256)
        write_image(tmp_path / "in" / "img.png", modulus, {"bits": 8})
        expected = learned_confidence(modulus.double(), 8).float().double()
        for method in (("--method", "learned"), ()):  # named, and as the default method
            out = tmp_path / f"out{len(method)}"
            assert _cli("unwrap", tmp_path / "in", out, "--single", *method, "--confidence") == 0
            restored = read_image(out / "img.exr", dtype=torch.float64)
            assert torch.equal(torch.remainder(restored, 256), modulus)
            torch.testing.assert_close(read_image(out / "img.confidence.exr", dtype=torch.float64), expected)


# ---------------------------------------------------------------------------------------------------- tonemap


class TestTonemap:
    def test_end_to_end(self, scenes: Path, tmp_path: Path) -> None:
        before = _digest(scenes)
        out = tmp_path / "png"
        assert _cli("tonemap", scenes, out, "--workers", 2, "--no-srgb") == 0
        assert _digest(scenes) == before
        for name in ("a.exr", "b.hdr", "sub/c.exr"):
            png = read_image(out / Path(name).with_suffix(".png"))
            expected = torch.round(tonemap_histogram(read_image(scenes / name).clamp_min(0)) * 255)
            assert torch.equal(png, expected)

    def test_operator_and_parameters(self, scenes: Path, tmp_path: Path) -> None:
        out = tmp_path / "png"
        assert (
            _cli("tonemap", scenes / "a.exr", out, "--op", "reinhard", "--param", "key=0.36", "--srgb", "--depth", 16)
            == 0
        )
        png, meta = read_image(out / "a.png", with_metadata=True)
        expected = torch.round(tonemap_reinhard(read_image(scenes / "a.exr"), key=0.36, srgb=True) * 65535)
        assert torch.equal(png, expected)
        assert meta["op"] == "reinhard" and meta["params"] == {"key": 0.36} and meta["srgb"] is True

    def test_tuple_parameter(self, scenes: Path, tmp_path: Path) -> None:
        out = tmp_path / "png"
        assert _cli("tonemap", scenes / "a.exr", out, "--op", "clahe", "--param", "grid_size=2,2", "--no-srgb") == 0
        expected = torch.round(tonemap_clahe(read_image(scenes / "a.exr"), grid_size=(2, 2)) * 255)
        assert torch.equal(read_image(out / "a.png"), expected)

    def test_pngs_are_srgb_encoded_by_default(self, scenes: Path, tmp_path: Path) -> None:
        hdr = read_image(scenes / "a.exr")
        assert _cli("tonemap", scenes / "a.exr", tmp_path / "default") == 0
        png, meta = read_image(tmp_path / "default" / "a.png", with_metadata=True)
        assert torch.equal(png, torch.round(tonemap_histogram(hdr, srgb=True) * 255)) and meta["srgb"] is True
        # gamma's own gamma (2.2 by default) encodes for display: no sRGB on top unless asked
        assert _cli("tonemap", scenes / "a.exr", tmp_path / "gamma", "--op", "gamma") == 0
        assert torch.equal(read_image(tmp_path / "gamma" / "a.png"), torch.round(tonemap_gamma(hdr) * 255))


# ------------------------------------------------------------------------------------------ folder promises


class TestFolderPromises:
    def test_corrupted_inputs_among_good_ones(self, scenes: Path, tmp_path: Path) -> None:
        (scenes / "garbage.exr").write_bytes(b"this is not an EXR file" * 10)
        good = (scenes / "a.exr").read_bytes()
        (scenes / "truncated.exr").write_bytes(good[: len(good) // 2])
        write_image(scenes / "nan.exr", torch.full((3, 4, 4), float("nan")))
        out = tmp_path / "png"
        assert _cli("tonemap", scenes, out) == 1
        report = _report(out, "tonemap")
        assert _names(report["done"]) == ["a.exr", "b.hdr", "sub/c.exr"]
        assert _names(report["failed"]) == ["garbage.exr", "nan.exr", "truncated.exr"]
        errors = {e["input"]: e["error"] for e in report["failed"]}
        assert errors["garbage.exr"].startswith("OSError: ") and "garbage.exr" in errors["garbage.exr"]
        assert "truncated.exr" in errors["truncated.exr"]
        assert errors["nan.exr"].startswith("ValueError: ") and "NaN" in errors["nan.exr"]
        assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*.png")) == ["a.png", "b.png", "sub/c.png"]

    def test_rerun_after_a_partial_run(self, scenes: Path, tmp_path: Path) -> None:
        out = tmp_path / "stacks"
        assert _cli("simulate", scenes, out, "--exposures", "1,256,65536") == 0
        kept = (out / "b" / "frame_b000_m00.exr").stat().st_mtime_ns
        # a crash: one scene's output never renamed into place (a hidden temporary is all that is left), another
        # finished without its done marker
        import shutil

        shutil.move(out / "a", out / ".a.tmp-999-dead")
        (out / MARKER_FOLDER / "simulate" / "sub" / "c.exr.json").unlink()
        assert _cli("simulate", scenes, out, "--exposures", "1,256,65536") == 0
        report = _report(out, "simulate")
        assert _names(report["done"]) == ["a.exr", "sub/c.exr"]
        assert _names(report["skipped"]) == ["b.hdr"]
        assert (out / "b" / "frame_b000_m00.exr").stat().st_mtime_ns == kept
        assert FileSensor(out / "a").read().num_exposures == 3
        # the same command with another option redoes everything
        assert _cli("simulate", scenes, out, "--exposures", "1,256,65536", "--seed", 9, "--noise", "default") == 0
        assert len(_report(out, "simulate")["done"]) == 3

    def test_ranks_from_the_environment(self, scenes: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        assert _cli("tonemap", scenes, tmp_path / "one") == 0
        for rank in (0, 1):
            monkeypatch.setenv("RANK", str(rank))
            monkeypatch.setenv("WORLD_SIZE", "2")
            assert _cli("tonemap", scenes, tmp_path / "two") == 0
            part = json.loads((tmp_path / "two" / f"tonemap-report.rank{rank}.json").read_text())
            assert _names(part["done"]) == [["a.exr", "sub/c.exr"], ["b.hdr"]][rank]
        for name in ("a.png", "b.png", "sub/c.png"):
            assert torch.equal(read_image(tmp_path / "one" / name), read_image(tmp_path / "two" / name))
        merged = _report(tmp_path / "two", "tonemap")
        assert merged["parts"] == [0, 1] and _names(merged["done"]) == ["a.exr", "b.hdr", "sub/c.exr"]

    def test_ray_engine(self, scenes: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        from batch.fakes import fake_ray as _fake_ray

        calls: list[str] = []
        monkeypatch.setitem(sys.modules, "ray", _fake_ray(calls))
        assert _cli("tonemap", scenes, tmp_path / "ray", "--engine", "ray", "--ray-address", "auto") == 0
        assert calls.count("submit") == 3 and calls[0] == "init:auto"
        assert _report(tmp_path / "ray", "tonemap")["engine"] == "ray"
        assert _cli("tonemap", scenes, tmp_path / "local") == 0
        for name in ("a.png", "b.png", "sub/c.png"):
            assert torch.equal(read_image(tmp_path / "ray" / name), read_image(tmp_path / "local" / name))

    @pytest.mark.slow
    def test_ctrl_c_stops_cleanly_and_the_rerun_resumes(self, tmp_path: Path) -> None:
        source = tmp_path / "in"
        source.mkdir()
        for i in range(150):
            write_image(source / f"s{i:03d}.exr", _scene(i, 64, 64))
        out = tmp_path / "out"
        command = [
            sys.executable,
            "-m",
            "torch_modulo.cli",
            "tonemap",
            str(source),
            str(out),
            "--op",
            "clahe",
            "--workers",
            "2",
        ]
        process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, cwd=ROOT)
        deadline = time.monotonic() + 120
        while not list(out.glob("*.png")) and time.monotonic() < deadline and process.poll() is None:
            time.sleep(0.01)
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=120)
        assert process.returncode == 130, stderr
        assert "Traceback" not in stderr
        report = _report(out, "tonemap")
        assert report["interrupted"] and report["not_finished"]
        assert sorted(_names(report["done"]) + report["not_finished"]) == [f"s{i:03d}.exr" for i in range(150)]
        assert sorted(p.stem for p in out.glob("*.png")) == sorted(Path(n).stem for n in _names(report["done"]))
        assert _cli("tonemap", source, out, "--op", "clahe") == 0
        again = _report(out, "tonemap")
        assert _names(again["skipped"]) == _names(report["done"])
        assert _names(again["done"]) == report["not_finished"]

    def test_torchrun_two_processes_equal_one(self, scenes: Path, tmp_path: Path) -> None:
        args = ["simulate", str(scenes), "--noise", "default", "--seed", "5", "--workers", "1", "--no-progress"]
        assert main([args[0], args[1], str(tmp_path / "one"), *args[2:]]) == 0
        env = {k: v for k, v in os.environ.items() if k not in ("RANK", "WORLD_SIZE", "LOCAL_RANK")}
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "torch.distributed.run",
                "--standalone",
                "--nproc_per_node",
                "2",
                "-m",
                "torch_modulo.cli",
                args[0],
                args[1],
                str(tmp_path / "two"),
                *args[2:],
            ],
            capture_output=True,
            text=True,
            cwd=ROOT,
            env=env,
            timeout=300,
        )
        assert result.returncode == 0, result.stderr[-3000:]
        for name in ("a", "b", "sub/c"):
            assert FileSensor(tmp_path / "one" / name).read() == FileSensor(tmp_path / "two" / name).read()
            assert torch.equal(
                read_image(tmp_path / "one" / name / "radiance.exr"),
                read_image(tmp_path / "two" / name / "radiance.exr"),
            )
        merged = _report(tmp_path / "two", "simulate")
        assert merged["world_size"] == 2 and merged["parts"] == [0, 1]
        assert _names(merged["done"]) == ["a.exr", "b.hdr", "sub/c.exr"]
        parts = [json.loads((tmp_path / "two" / f"simulate-report.rank{r}.json").read_text()) for r in (0, 1)]
        assert [_names(p["done"]) for p in parts] == [["a.exr", "sub/c.exr"], ["b.hdr"]]

    @pytest.mark.slow
    def test_torchrun_two_nodes(self, scenes: Path, tmp_path: Path) -> None:
        """--nnodes 2: two torchrun agents (here on one machine, static rendezvous) share the files."""
        import socket

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        assert _cli("tonemap", scenes, tmp_path / "one") == 0
        env = {k: v for k, v in os.environ.items() if k not in ("RANK", "WORLD_SIZE", "LOCAL_RANK")}
        agents = [
            subprocess.Popen(
                [
                    sys.executable,
                    "-m",
                    "torch.distributed.run",
                    "--nnodes",
                    "2",
                    "--nproc_per_node",
                    "1",
                    "--node_rank",
                    str(node),
                    "--master_addr",
                    "127.0.0.1",
                    "--master_port",
                    str(port),
                    "-m",
                    "torch_modulo.cli",
                    "tonemap",
                    str(scenes),
                    str(tmp_path / "two"),
                    "--workers",
                    "1",
                ],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
                cwd=ROOT,
                env=env,
            )
            for node in (0, 1)
        ]
        outputs = [agent.communicate(timeout=300) for agent in agents]
        assert [agent.returncode for agent in agents] == [0, 0], outputs[0][1][-2000:] + outputs[1][1][-2000:]
        for name in ("a.png", "b.png", "sub/c.png"):
            assert torch.equal(read_image(tmp_path / "one" / name), read_image(tmp_path / "two" / name))
        merged = _report(tmp_path / "two", "tonemap")
        assert merged["parts"] == [0, 1] and _names(merged["done"]) == ["a.exr", "b.hdr", "sub/c.exr"]


# ------------------------------------------------------------------------------------ defaults under noise


def _rough_scenes(folder: Path, count: int = 3) -> Path:
    """``count`` 64x64 RGB scenes of about 16 stops (the README's folder example, small)."""
    folder.mkdir(parents=True)
    for i in range(count):
        write_image(folder / f"s{i}.exr", _scene(10 + i, 64, 64))
    return folder


def _relative_errors(estimate: torch.Tensor, truth: torch.Tensor) -> torch.Tensor:
    mask = truth > 0
    return (estimate[mask] - truth[mask]).abs() / truth[mask]


class TestNoiseDefaults:
    def test_readme_folder_example_is_right_with_noise(
        self, tmp_path: Path, capsys: pytest.CaptureFixture[str]
    ) -> None:
        """`torch-modulo simulate hdr_scenes/ stacks/` then `torch-modulo unwrap stacks/ radiance/`, defaults."""
        scenes = _rough_scenes(tmp_path / "hdr_scenes")
        stacks, radiance = tmp_path / "stacks", tmp_path / "radiance"
        assert _cli("simulate", scenes, stacks, "--workers", 1) == 0
        assert _cli("unwrap", stacks, radiance, "--workers", 1) == 0
        err = capsys.readouterr().err
        assert "warning" not in err and "unsafe" not in err  # the planned exposures are safe
        assert "against the stored truth, mean over 3 results: median relative error" in err
        report = _report(radiance, "unwrap")
        for i in range(3):
            stack = FileSensor(stacks / f"s{i}").read()
            assert stack.num_exposures > 3  # noise needs more, closer exposures than the noise-free three
            truth = read_image(stacks / f"s{i}" / "radiance.exr", dtype=torch.float64)
            restored, meta = read_image(radiance / f"s{i}.exr", with_metadata=True, dtype=torch.float64)
            rel = _relative_errors(restored, truth)
            assert float(rel.median()) < 0.05
            assert float((rel > 0.5).double().mean()) < 0.005
            assert meta["noise"] == NoiseModel.preset("photon-counting").to_dict()
            entry = report["done"][i]
            assert entry["noise"] == "photon-counting" and "warnings" not in entry
            assert entry["accuracy"]["median_relative_error"] == pytest.approx(float(rel.median()), rel=1e-3)

    def test_simulate_agrees_with_the_python_sensor(self, tmp_path: Path) -> None:
        scenes = _rough_scenes(tmp_path / "in", count=1)
        assert _cli("simulate", scenes, tmp_path / "out", "--workers", 1) == 0
        stack = FileSensor(tmp_path / "out" / "s0").read()
        assert stack.metadata["noise"] == SimulatedModuloSensor().noise.to_dict()  # noise on, the same preset
        # --exposures auto: protocol N's scaling and plan for the scene's own stops, the longest exposure 1
        image = read_image(scenes / "s0.exr", dtype=torch.float64)
        low = float(torch.quantile(image[image > 0], 0.001))
        stops = math.ceil(math.log2(float(image.max()) / low) + 4)
        plan = plan_exposures(stops, 8, noise=SimulatedModuloSensor().noise)
        assert stack.exposures.tolist() == pytest.approx([t / plan[-1] for t in plan], rel=1e-12)
        assert stack.metadata["stops"] == stops and stack.metadata["radiance_scale"] == pytest.approx(16 / low)
        # the same frames as the Python sensor with the scene's seed
        truth = read_image(tmp_path / "out" / "s0" / "radiance.exr", dtype=torch.float64)
        python = SimulatedModuloSensor(seed=stack.metadata["seed"])(truth[None], stack.exposures.tolist())
        assert torch.equal(stack.moduli, python.moduli.float())

    def test_noise_none_plans_the_noise_free_exposures(self, tmp_path: Path) -> None:
        scenes = _rough_scenes(tmp_path / "in", count=1)
        assert _cli("simulate", scenes, tmp_path / "stacks", "--noise", "none") == 0
        assert _cli("unwrap", tmp_path / "stacks", tmp_path / "out") == 0
        stack = FileSensor(tmp_path / "stacks" / "s0").read()
        plan = plan_exposures(stack.metadata["stops"], 8)
        assert stack.metadata["noise"] is None and stack.num_exposures == len(plan) == 3
        truth = read_image(tmp_path / "stacks" / "s0" / "radiance.exr", dtype=torch.float64)
        assert float(truth.max()) * float(stack.exposures[0]) < 256  # the shortest frame does not roll over
        restored = read_image(tmp_path / "out" / "s0.exr", dtype=torch.float64)
        torch.testing.assert_close(restored, torch.floor(truth), rtol=2**-23, atol=0)  # exact: tau_max = 1

    def test_presets_reach_the_stack_and_the_decoder(self, tmp_path: Path) -> None:
        scenes = _rough_scenes(tmp_path / "in", count=1)
        assert _cli("simulate", scenes, tmp_path / "stacks", "--noise", "dfpa") == 0
        stack = FileSensor(tmp_path / "stacks" / "s0").read()
        dfpa = NoiseModel.preset("dfpa")
        assert stack.metadata["noise"] == dfpa.to_dict()
        plan = plan_exposures(stack.metadata["stops"], 8, noise=dfpa)
        assert stack.exposures.tolist() == pytest.approx([t / plan[-1] for t in plan], rel=1e-12)
        out = tmp_path / "out"
        for name, option in (("dfpa", ()), ("none", ("--noise", "none")), ("q16", ("--noise", "q16"))):
            assert _cli("unwrap", tmp_path / "stacks", out / name, *option) == 0
        moduli, taus = stack.moduli, stack.exposures
        expected = {
            "dfpa": unwrap_multi(moduli, taus, 8, noise=dfpa),  # by default, the model the stack records
            "none": unwrap_multi(moduli, taus, 8),  # forced noise-free
        }
        with pytest.warns(UserWarning, match="is unsafe under"):  # q16 needs closer exposures than the dfpa plan
            expected["q16"] = unwrap_multi(moduli, taus, 8, noise="q16")  # overridden
        for name, radiance in expected.items():
            restored, meta = read_image(out / name / "s0.exr", with_metadata=True)
            assert torch.equal(restored, radiance[0]), name
            model = None if name == "none" else NoiseModel.preset(name)
            assert meta["noise"] == (model.to_dict() if model else None)
            assert _report(out / name, "unwrap")["done"][0]["noise"] == (name if model else None)

    def test_unsafe_exposures_warn_and_name_a_plan(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        scenes = _rough_scenes(tmp_path / "in", count=1)
        assert _cli("simulate", scenes, tmp_path / "stacks", "--exposures", "1,256,65536") == 0  # accepted
        err = capsys.readouterr().err
        assert "simulate: s0.exr: exposure ratio 256 is unsafe under NoiseModel(" in err
        assert "keep ratios <= " in err and "e.g. --exposures auto (for this scene plan_exposures(" in err
        assert "is unsafe" in _report(tmp_path / "stacks", "simulate")["done"][0]["warnings"][0]
        truth = read_image(tmp_path / "stacks" / "s0" / "radiance.exr", dtype=torch.float64)
        noise = NoiseModel()
        bright = float(truth.max())  # the brightest value stays three deviations below the rollover at tau = 1
        assert 200 < bright and bright + 3 * math.sqrt(noise.count_variance(bright)) == pytest.approx(255, abs=1e-3)
        assert _cli("unwrap", tmp_path / "stacks", tmp_path / "out") == 0
        err = capsys.readouterr().err
        assert "unwrap: s0: exposure ratio 256 is unsafe under NoiseModel(" in err and "plan_exposures(" in err
        assert "is unsafe" in _report(tmp_path / "out", "unwrap")["done"][0]["warnings"][0]
        # Eqs. 6-7 as printed take no noise model: the recorded one is not used, and the report says so
        assert _cli("unwrap", tmp_path / "stacks", tmp_path / "paper", "--method", "paper") == 0
        entry = _report(tmp_path / "paper", "unwrap")["done"][0]
        assert entry["noise"] is None and "--method paper" in entry["warnings"][0]
        stack = FileSensor(tmp_path / "stacks" / "s0").read()
        expected = unwrap_multi(stack.moduli, stack.exposures, 8, method="paper")[0]
        assert torch.equal(read_image(tmp_path / "paper" / "s0.exr"), expected)


# -------------------------------------------------------------------------------------- single shot stacks


def _smooth_scene(path: Path) -> Path:
    """A smooth 40x96 RGB scene (a ramp and a bump): at 16 periods its steps stay under half a period."""
    y, x = torch.meshgrid(torch.linspace(-1, 1, 40), torch.linspace(-1, 1, 96), indexing="ij")
    base = 0.01 + (x + 1) / 2 + 0.2 * torch.exp(-(x**2 + y**2) * 4)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, torch.stack([base, 0.8 * base, 0.6 * base]))
    return path


class TestSingleShotStacks:
    def test_simulate_then_unwrap_single(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        source = _smooth_scene(tmp_path / "in" / "smooth.exr")
        stacks, out = tmp_path / "single", tmp_path / "out"
        assert _cli("simulate", source.parent, stacks, "--exposures", 2, "--noise", "none") == 0
        stack = FileSensor(stacks / "smooth").read()
        assert stack.num_exposures == 1 and stack.metadata["scaling"] == "single shot (protocol A)"
        truth = read_image(stacks / "smooth" / "radiance.exr", dtype=torch.float64)
        luminance = 0.2126 * truth[0] + 0.7152 * truth[1] + 0.0722 * truth[2]
        p999 = float(np.percentile(luminance.numpy(), 99.9))
        assert p999 * 2 == pytest.approx(4095, rel=1e-6)  # 16 periods at the exposure: the frame wraps
        assert float((truth * 2).max()) > 4 * 256
        capsys.readouterr()
        assert _cli("unwrap", stacks, out, "--single", "--confidence") == 0  # radiance.exr is not taken as a frame
        report = _report(out, "unwrap")
        assert _names(report["done"]) == ["smooth"] and not report["failed"]
        assert report["done"][0]["accuracy"] == {"exact_k": 1.0, "psnr_db": math.inf}
        assert "exact rollover counts 100.00%, PSNR inf dB" in capsys.readouterr().err
        restored, meta = read_image(out / "smooth.exr", with_metadata=True, dtype=torch.float64)
        torch.testing.assert_close(restored, torch.floor(truth * 2) / 2)
        assert meta["exposure"] == 2.0 and meta["bits"] == 8
        assert (out / "smooth.confidence.exr").is_file()

    def test_single_shot_scores_noisy_frames_by_their_nearest_counts(self, tmp_path: Path) -> None:
        source = _smooth_scene(tmp_path / "in" / "smooth.exr")
        assert _cli("simulate", source.parent, tmp_path / "single", "--exposures", 1, "--noise", "q16") == 0
        assert _cli("unwrap", tmp_path / "single", tmp_path / "out", "--single") == 0
        accuracy = _report(tmp_path / "out", "unwrap")["done"][0]["accuracy"]
        assert accuracy["exact_k"] > 0.99 and accuracy["psnr_db"] > 40

    def test_single_refuses_a_stack_of_several_exposures(self, tmp_path: Path) -> None:
        source = _smooth_scene(tmp_path / "in" / "smooth.exr")
        assert _cli("simulate", source.parent, tmp_path / "stacks", "--exposures", "1,16", "--noise", "none") == 0
        assert _cli("unwrap", tmp_path / "stacks", tmp_path / "out", "--single") == 1
        error = _report(tmp_path / "out", "unwrap")["failed"][0]["error"]
        assert "holds 2 modulo frames; --single unwraps one modulo frame" in error and "--exposures 1" in error

    def test_multi_shot_refuses_a_stack_of_one_exposure(self, tmp_path: Path) -> None:
        source = _smooth_scene(tmp_path / "in" / "smooth.exr")
        assert _cli("simulate", source.parent, tmp_path / "stacks", "--exposures", "1", "--noise", "none") == 0
        assert _cli("unwrap", tmp_path / "stacks", tmp_path / "out") == 1  # it gave I_m / tau as radiance, rc 0
        error = _report(tmp_path / "out", "unwrap")["failed"][0]["error"]
        assert "holds one modulo frame; rollover counting needs several: unwrap it with --single" in error


class TestOutputsThatWouldLoseData:
    def test_a_scene_beside_a_folder_of_its_name_is_refused(self, tmp_path: Path) -> None:
        (tmp_path / "in" / "a").mkdir(parents=True)
        write_image(tmp_path / "in" / "a.exr", _scene(1))
        write_image(tmp_path / "in" / "a" / "x.exr", _scene(2))
        write_image(tmp_path / "in" / "b.exr", _scene(3))
        assert _cli("simulate", tmp_path / "in", tmp_path / "stacks", "--workers", 2) == 1
        report = _report(tmp_path / "stacks", "simulate")
        assert _names(report["done"]) == ["b.exr"] and _names(report["failed"]) == ["a.exr", "a/x.exr"]
        assert "output a and the output of a/x.exr would lie one inside the other" in report["failed"][0]["error"]
        assert not (tmp_path / "stacks" / "a").exists()

    def test_a_file_beside_a_single_input_is_never_replaced(
        self, tmp_path: Path, capsys: pytest.CaptureFixture[str]
    ) -> None:
        folder = tmp_path / "shots"
        folder.mkdir()
        write_image(folder / "x.exr", _scene(1))
        write_image(folder / "x.png", torch.zeros(3, 12, 16))  # the user's own x.png beside the input
        before = _digest(folder)
        assert _cli("tonemap", folder / "x.exr", folder) == 1
        after = _digest(folder)
        assert after["x.exr"] == before["x.exr"] and after["x.png"] == before["x.png"]
        assert "x.png exists and no run of torch-modulo tonemap wrote it" in capsys.readouterr().err
        assert _cli("tonemap", folder / "x.exr", folder, "--force") == 0  # told to
        assert _digest(folder)["x.png"] != before["x.png"]
        assert _cli("tonemap", folder / "x.exr", folder) == 0  # its own output now: a rerun resumes

    def test_a_kill_before_the_marker_does_not_make_the_output_foreign(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        from torch_modulo.batch import run as batch_run

        folder = tmp_path / "shots"
        folder.mkdir()
        write_image(folder / "x.exr", _scene(1))

        def no_marker(*args: Any, **kwargs: Any) -> None:
            raise OSError(28, "No space left on device")

        with monkeypatch.context() as patch:  # the output is written, its done marker is not
            patch.setattr(batch_run, "write_marker", no_marker)
            assert _cli("tonemap", folder / "x.exr", folder) == 1
        assert (folder / "x.png").is_file()
        assert _cli("tonemap", folder / "x.exr", folder) == 0  # "the next run redoes this input", as promised
        assert _names(_report(folder, "tonemap")["done"]) == ["x.exr"]

    def test_a_link_to_itself_fails_alone(self, scenes: Path, tmp_path: Path) -> None:
        (scenes / "loop.exr").symlink_to(scenes / "loop.exr")
        assert _cli("tonemap", scenes, tmp_path / "png") == 1
        report = _report(tmp_path / "png", "tonemap")
        assert len(report["done"]) == 3 and _names(report["failed"]) == ["loop.exr"]

    def test_a_broken_link_is_an_input_that_fails(self, scenes: Path, tmp_path: Path) -> None:
        (scenes / "gone.exr").symlink_to(tmp_path / "nowhere.exr")
        assert _cli("tonemap", scenes, tmp_path / "png") == 1
        report = _report(tmp_path / "png", "tonemap")
        assert len(report["done"]) == 3 and _names(report["failed"]) == ["gone.exr"]
        assert "gone.exr" in report["failed"][0]["error"]


# ------------------------------------------------------------------------------------------ colour sensors


def _colour_scene(path: Path, h: int = 32, w: int = 48) -> Path:
    """A small smooth RGB scene (three gradients with different directions), dark near 0 in one corner."""
    y, x = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    rgb = torch.stack([0.01 + x + 0.5 * y, 0.01 + 0.8 * x + 0.3 * y, 0.01 + 0.5 * x + 0.8 * y])
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, rgb)
    return path


class TestColourSensor:
    def test_simulate_unwrap_multi_demosaic_tonemap(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        from torch_modulo import demosaic, mosaic

        source = _colour_scene(tmp_path / "in" / "s.exr")
        stacks, out = tmp_path / "stacks", tmp_path / "out"
        assert _cli("simulate", source.parent, stacks, "--cfa", "RGGB") == 0  # noise on, exposures planned
        assert _report(stacks, "simulate")["done"][0]["cfa"] == "RGGB"
        stack = FileSensor(stacks / "s").read()
        assert stack.cfa == "RGGB" and stack.moduli.shape[2:] == (1, 32, 48) and stack.num_exposures > 1
        truth = read_image(stacks / "s" / "radiance.exr", dtype=torch.float64)
        assert truth.shape == (3, 32, 48)  # the truth stays RGB
        capsys.readouterr()
        assert _cli("unwrap", stacks, out) == 0  # the pattern comes from the stack
        restored, meta = read_image(out / "s.exr", with_metadata=True, dtype=torch.float64)
        assert restored.shape == (3, 32, 48) and meta["cfa"] == "RGGB" and meta["demosaic"] == "malvar"
        noise = NoiseModel(**stack.metadata["noise"])
        expected = demosaic(unwrap_multi(stack.moduli, stack.exposures, 8, noise=noise, cfa="RGGB"), "RGGB")[0]
        torch.testing.assert_close(restored.float(), expected)  # unwrapped first, then demosaiced
        accuracy = _report(out, "unwrap")["done"][0]["accuracy"]  # RGB scored against the RGB truth
        assert accuracy["median_relative_error"] < 0.08 and accuracy["gross_share"] < 0.005
        assert "median relative error" in capsys.readouterr().err
        assert _cli("tonemap", out, tmp_path / "png") == 0
        assert read_image(tmp_path / "png" / "s.png").shape == (3, 32, 48)
        # --no-demosaic: the restored mosaic, scored against the mosaicked truth
        assert _cli("unwrap", stacks, tmp_path / "mosaic", "--no-demosaic") == 0
        restored, meta = read_image(tmp_path / "mosaic" / "s.exr", with_metadata=True, dtype=torch.float64)
        assert restored.shape == (1, 32, 48) and meta["cfa"] == "RGGB" and meta["demosaic"] == "none"
        torch.testing.assert_close(demosaic(restored.float()[None], "RGGB")[0], expected)
        accuracy = _report(tmp_path / "mosaic", "unwrap")["done"][0]["accuracy"]
        rel = (restored - mosaic(truth, "RGGB")).abs() / mosaic(truth, "RGGB")
        assert accuracy["median_relative_error"] == pytest.approx(float(rel.median()), rel=1e-3)

    def test_single_shot_mosaic_is_exact_on_a_smooth_scene(self, tmp_path: Path) -> None:
        from torch_modulo import mosaic

        source = _colour_scene(tmp_path / "in" / "s.exr")
        stacks, out = tmp_path / "single", tmp_path / "out"
        args = ("--exposures", 1, "--noise", "none", "--cfa", "RGGB", "--scale", 1000)  # about 4 periods
        assert _cli("simulate", source.parent, stacks, *args) == 0
        assert FileSensor(stacks / "s").read().moduli.shape == (1, 1, 1, 32, 48)
        truth = read_image(stacks / "s" / "radiance.exr", dtype=torch.float64)
        assert float(truth.max()) > 4 * 256  # the frame wraps
        assert _cli("unwrap", stacks, out, "--single", "--confidence") == 0
        accuracy = _report(out, "unwrap")["done"][0]["accuracy"]
        assert accuracy["exact_k"] == 1.0 and accuracy["psnr_db"] == math.inf  # exact on the mosaic
        assert accuracy["colour_psnr_db"] > 40  # the demosaiced RGB against the RGB truth
        restored, meta = read_image(out / "s.exr", with_metadata=True)
        assert restored.shape == (3, 32, 48) and meta["cfa"] == "RGGB" and meta["solver"] == "default"
        assert read_image(out / "s.confidence.exr").shape == (1, 32, 48)
        assert _cli("unwrap", stacks, tmp_path / "mosaic", "--single", "--no-demosaic") == 0
        restored = read_image(tmp_path / "mosaic" / "s.exr", dtype=torch.float64)
        torch.testing.assert_close(restored, torch.floor(mosaic(truth, "RGGB")))

    def test_cfa_for_modulus_images_outside_stacks(self, tmp_path: Path) -> None:
        from torch_modulo import mosaic

        rgb = read_image(_colour_scene(tmp_path / "scene.exr"), dtype=torch.float64) * 1000
        counts = torch.floor(mosaic(rgb, "GRBG"))
        (tmp_path / "camera").mkdir()
        write_image(tmp_path / "camera" / "shot.png", torch.remainder(counts, 256), {"bits": 8}, dtype="uint8")
        write_image(tmp_path / "camera" / "rgb.png", torch.remainder(torch.floor(rgb), 256), {"bits": 8}, dtype="uint8")
        out = tmp_path / "out"
        assert _cli("unwrap", tmp_path / "camera", out, "--single", "--cfa", "GRBG", "--no-demosaic") == 1
        report = _report(out, "unwrap")
        assert _names(report["done"]) == ["shot.png"]
        assert (
            "rgb.png is not a mosaic (cfa GRBG)" in report["failed"][0]["error"]
            and "got 3 x 32 x 48" in (report["failed"][0]["error"])
        )
        torch.testing.assert_close(read_image(out / "shot.exr", dtype=torch.float64), counts)
        (tmp_path / "camera" / "rgb.png").unlink()
        assert _cli("unwrap", tmp_path / "camera", tmp_path / "rgb", "--single", "--cfa", "GRBG") == 0
        restored, meta = read_image(tmp_path / "rgb" / "shot.exr", with_metadata=True)
        assert restored.shape == (3, 32, 48) and meta["cfa"] == "GRBG"

    def test_a_pattern_that_disagrees_with_the_stack_is_refused(self, tmp_path: Path) -> None:
        source = _colour_scene(tmp_path / "in" / "s.exr")
        for exposures, extra in (("auto", []), ("1", ["--single"])):
            stacks, out = tmp_path / f"stacks{exposures}", tmp_path / f"out{exposures}"
            assert (
                _cli("simulate", source.parent, stacks, "--cfa", "RGGB", "--noise", "none", "--exposures", exposures)
                == 0
            )
            assert _cli("unwrap", stacks, out, "--cfa", "BGGR", *extra) == 1
            error = _report(out, "unwrap")["failed"][0]["error"]
            assert "records the colour filter array 'RGGB' but --cfa BGGR was given" in error

    def test_scenes_that_are_not_rgb_are_refused_per_file(self, tmp_path: Path) -> None:
        (tmp_path / "in").mkdir()
        write_image(tmp_path / "in" / "grey.exr", _scene(1, channels=1))
        _colour_scene(tmp_path / "in" / "odd.exr", h=33)
        out = tmp_path / "out"
        assert _cli("simulate", tmp_path / "in", out, "--cfa", "BGGR", "--noise", "none") == 1
        report = _report(out, "simulate")
        assert _names(report["failed"]) == ["grey.exr"] and _names(report["done"]) == ["odd.exr"]
        error = report["failed"][0]["error"]
        assert "grey.exr is not an RGB scene (1 channel): --cfa BGGR simulates a colour sensor" in error
        assert "cropped 33 x 48 to 32 x 48" in report["done"][0]["warnings"][0]
        assert read_image(out / "odd" / "radiance.exr").shape == (3, 32, 48)
        assert FileSensor(out / "odd").read().cfa == "BGGR"
        assert _cli("simulate", tmp_path / "in" / "grey.exr", tmp_path / "grey") == 0  # without --cfa: as before


# ----------------------------------------------------------------------------------------------- reliability


def _bad_values_scene(path: Path) -> Path:
    """A scene with one NaN, one +Inf and one negative value (as damaged and lossy files have)."""
    image = _scene(8)
    image[0, 1, 2] = float("nan")
    image[1, 3, 4] = float("inf")
    image[2, 5, 6] = -0.5
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, image)
    return path


class TestReliability:
    def test_symlink_loop_in_the_input_tonemaps_each_scene_once(self, scenes: Path, tmp_path: Path) -> None:
        os.symlink(scenes, scenes / "sub" / "loop")  # the input folder inside itself
        os.symlink(scenes / "a.exr", scenes / "also_a.exr")  # a second name for one file
        out = tmp_path / "png"
        assert _cli("tonemap", scenes, out, "--workers", 1) == 0
        assert _names(_report(out, "tonemap")["done"]) == ["a.exr", "b.hdr", "sub/c.exr"]
        assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*.png")) == ["a.png", "b.png", "sub/c.png"]

    def test_nonfinite_radiance_is_read_the_same_by_every_command(self, tmp_path: Path) -> None:
        from torch_modulo.data import HDRFolder
        from torch_modulo.radiance import load_radiance

        source = _bad_values_scene(tmp_path / "in" / "bad.exr")
        expected = load_radiance(source)
        assert bool(torch.isfinite(expected).all()) and float(expected.min()) >= 0
        assert torch.equal(HDRFolder(tmp_path / "in", channels=None)[0], expected)  # the Dataset reads the same
        assert _cli("tonemap", tmp_path / "in", tmp_path / "png", "--no-srgb") == 0
        assert torch.equal(read_image(tmp_path / "png" / "bad.png"), torch.round(tonemap_histogram(expected) * 255))
        done = _report(tmp_path / "png", "tonemap")["done"][0]
        assert done["nonfinite_replaced"] == {"nan": 1, "posinf": 1, "neginf": 0}
        assert done["warnings"][0].startswith("replaced 2 NaN or infinite values (1 NaN, 1 +Inf, 0 -Inf)")
        assert (
            _cli("simulate", tmp_path / "in", tmp_path / "stacks", "--noise", "none", "--exposures", "1,256,65536") == 0
        )
        truth = read_image(tmp_path / "stacks" / "bad" / "radiance.exr", dtype=torch.float64)
        torch.testing.assert_close(truth, (expected.double() * (255 / float(expected.max()))).float().double())
        assert _report(tmp_path / "stacks", "simulate")["done"][0]["negatives_clamped"] == 1

    def test_nonfinite_raise_refuses_the_file_with_its_counts(self, tmp_path: Path) -> None:
        source = _bad_values_scene(tmp_path / "in" / "bad.exr")
        for command in ("tonemap", "simulate"):
            out = tmp_path / command
            assert _cli(command, tmp_path / "in", out, "--nonfinite", "raise") == 1
            error = _report(out, command)["failed"][0]["error"]
            assert error.startswith(f"ValueError: {source} holds 2 NaN or infinite values (1 NaN, 1 +Inf, 0 -Inf)")


class TestSimulateInputs:
    def test_display_referred_files_are_refused_unless_linear(self, tmp_path: Path) -> None:
        # Regression: `simulate photo.png out/` took the sRGB 0-255 values as linear radiance and reported it done.
        photo = tmp_path / "photo.png"
        write_image(photo, torch.arange(48.0).view(3, 4, 4) * 5, dtype="uint8")
        out = tmp_path / "out"
        assert _cli("simulate", photo, out, "--exposures", "1,16", "--noise", "none") == 1
        (failed,) = _report(out, "simulate")["failed"]
        assert "photo.png holds 8-bit integers" in failed["error"] and "--linear" in failed["error"]
        assert not (out / "photo").exists()
        assert _cli("simulate", photo, out, "--exposures", "1,16", "--noise", "none", "--linear") == 0
        assert FileSensor(out / "photo").read().num_exposures == 2

    def test_the_library_job_refuses_them_too(self, tmp_path: Path) -> None:
        from torch_modulo._task import Task
        from torch_modulo.pipeline import simulate_job

        photo = tmp_path / "photo.tif"
        write_image(photo, torch.arange(48.0).view(3, 4, 4) * 5, dtype="uint16")
        options = {"bits": 8, "exposures": [1.0, 16.0], "noise": None, "seed": 0, "scale": "auto"}
        options |= {"format": "exr", "truth": True}
        task = Task("photo.tif", str(photo), (str(tmp_path / "out"),))
        with pytest.raises(ValueError, match="photo.tif holds 16-bit integers"):
            simulate_job(task, options)
        assert simulate_job(task, {**options, "linear": True})["exposures"] == [1.0, 16.0]

    def test_max_side_averages_areas_and_crop_cuts_the_centre(self, scenes: Path, tmp_path: Path) -> None:
        # Regression: simulate had no way to shrink big scenes (the benchmarks' area averaging) or to crop them.
        from torch_modulo.protocols import downsample_area
        from torch_modulo.radiance import load_radiance

        out = tmp_path / "out"
        base = ("--exposures", "1,16", "--noise", "none")
        assert _cli("simulate", scenes / "a.exr", out, *base, "--max-side", 8) == 0
        truth = read_image(out / "a" / "radiance.exr", dtype=torch.float64)
        expected = downsample_area(load_radiance(scenes / "a.exr", dtype=torch.float64), 8)  # 12 x 16 -> 6 x 8
        scale = FileSensor(out / "a").read().metadata["radiance_scale"]
        torch.testing.assert_close(truth, (expected * scale).float().double())
        assert _report(out, "simulate")["done"][0]["shape"] == [3, 6, 8]
        assert _cli("simulate", scenes / "a.exr", tmp_path / "crop", *base, "--max-side", 8, "--crop", "4,6") == 0
        cropped = read_image(tmp_path / "crop" / "a" / "radiance.exr", dtype=torch.float64)
        assert cropped.shape == (3, 4, 6)
        assert _cli("simulate", scenes / "a.exr", tmp_path / "big", *base, "--crop", "20") == 1
        (failed,) = _report(tmp_path / "big", "simulate")["failed"]
        assert "a.exr is 12 x 16, smaller than --crop 20 x 20" in failed["error"]


class TestTonemapInputs:
    def test_frames_and_confidence_maps_are_skipped_and_reported(self, scenes: Path, tmp_path: Path) -> None:
        # Regression: tonemap on a folder of frame stacks tone-mapped every wrapped frame as radiance, and on
        # `unwrap --confidence` output it tone-mapped the confidence maps.
        stacks = tmp_path / "stacks"
        assert _cli("simulate", scenes / "a.exr", stacks, "--exposures", "1,16", "--noise", "none") == 0
        write_image(stacks / "map.confidence.exr", torch.rand(1, 4, 4), {"unit": "confidence in [0, 1]"})
        out = tmp_path / "png"
        assert _cli("tonemap", stacks, out) == 0
        report = _report(out, "tonemap")
        assert _names(report["done"]) == ["a/radiance.exr"]  # the stored truth is radiance
        skipped = {e["input"]: e["reason"] for e in report["skipped"]}
        assert sorted(skipped) == ["a/frame_b000_m00.exr", "a/frame_b000_m01.exr", "map.confidence.exr"]
        assert "a frame of a modulo camera" in skipped["a/frame_b000_m00.exr"]
        assert "a confidence map" in skipped["map.confidence.exr"]
        assert report["counts"] == {"total": 4, "done": 1, "skipped": 3, "failed": 0, "not_finished": 0}
        assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*.png")) == ["a/radiance.png"]
