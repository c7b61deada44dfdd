"""The demo (torch_modulo/demo.py, ``torch-modulo demo``) end to end on a small generated scene."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from torch_modulo import io
from torch_modulo.cli import main
from torch_modulo.demo import LOW_CONFIDENCE, SCENE_PEAK, run_demo
from torch_modulo.metrics import exact_k_map, exact_k_share
from torch_modulo.singleshot import unwrap_confidence
from torch_modulo.tonemap import REC709_LUMA


def _scene(path: Path) -> Path:
    """A smooth 40x96 RGB scene (a ramp and a bump, steps under half a period): single shot can unwrap it."""
    y, x = torch.meshgrid(torch.linspace(-1, 1, 40), torch.linspace(-1, 1, 96), indexing="ij")
    base = 0.01 + (x + 1) / 2 + 0.2 * torch.exp(-(x**2 + y**2) * 4)
    image = torch.stack([base, 0.8 * base, 0.6 * base])
    io.write_image(path, image)
    return path


def test_run_demo_writes_every_file_and_true_numbers(tmp_path: Path) -> None:
    lines: list[str] = []
    summary = run_demo(tmp_path / "out", _scene(tmp_path / "scene.exr"), workers=1, log=lines.append)
    assert summary["multi_shot"]["exact_k"] == 1.0  # noise-free, ratio 64 < 2^8: the robust rule is exact
    assert (
        summary["multi_shot"]["median_relative_error_modulo"] < summary["multi_shot"]["median_relative_error_intensity"]
    )
    assert summary["single_shot"]["exact_k"] == 1.0
    assert summary["single_shot"]["method"] == "learned"
    assert summary["single_shot"]["low_confidence_share"] == 0.0  # smooth: every level is determined
    # nothing is wrong, so every wrong value is (vacuously) flagged: the share is 1, not 0/0
    assert summary["single_shot"]["wrong_k_flagged_low_confidence"] == 1.0
    for name in summary["files"]:
        assert Path(name).is_file(), name
    written = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert written["single_shot"] == summary["single_shot"]
    assert any("single shot" in line for line in lines)
    comparison = io.read_image(tmp_path / "out" / "comparison.png")
    assert comparison.shape[0] == 3 and comparison.shape[2] == 2 * 96


def test_the_confidence_flags_are_scored_against_the_wrong_counts(tmp_path: Path) -> None:
    """A rough bright window (steps of several periods) defeats single shot on part of it; the summary's shares are
    those of the written result against the scene's true counts."""
    y, x = torch.meshgrid(torch.linspace(-1, 1, 40), torch.linspace(-1, 1, 96), indexing="ij")
    base = 0.01 + (x + 1) / 2 + 0.2 * torch.exp(-(x**2 + y**2) * 4)
    base[12:28, 30:60] += 0.5 + 0.5 * torch.rand(16, 30, generator=torch.Generator().manual_seed(0))
    hdr = torch.stack([base, 0.8 * base, 0.6 * base])
    io.write_image(tmp_path / "window.exr", hdr)
    single = run_demo(tmp_path / "out", tmp_path / "window.exr", workers=1, log=lambda _: None)["single_shot"]
    # The demo's truth: luminance's 99.9th percentile at SCENE_PEAK counts, floored (exposure 1).
    luma = torch.einsum("chw,c->hw", hdr, torch.tensor(REC709_LUMA, dtype=hdr.dtype))
    truth = torch.floor(hdr * (SCENE_PEAK / float(torch.quantile(luma.flatten(), 0.999))))[None]
    restored = io.read_image(tmp_path / "out" / "single_shot.exr")[None]
    wrong = ~exact_k_map(restored, truth, 8)
    low = unwrap_confidence(restored, 8) < LOW_CONFIDENCE
    assert single["exact_k"] == pytest.approx(float(exact_k_share(restored, truth, 8)[0]), abs=1e-12)
    assert 0 < int(wrong.sum()) < wrong.numel() // 4  # part of the window is wrong, the rest of the scene right
    assert single["low_confidence_share"] == pytest.approx(float(low.double().mean()), abs=1e-12)
    flagged = int((wrong & low).sum()) / int(wrong.sum())
    assert single["wrong_k_flagged_low_confidence"] == pytest.approx(flagged, abs=1e-6)
    assert 0.0 < flagged < 1.0  # the map flags some of the wrong values, not all


def test_cli_demo_with_the_papers_graph_cut(tmp_path: Path) -> None:
    out = tmp_path / "out"
    args = ["demo", "--out", str(out), "--scene", str(_scene(tmp_path / "scene.exr")), "--workers", "1"]
    assert main([*args, "--solver", "fast"]) == 0
    single = json.loads((out / "summary.json").read_text())["single_shot"]
    assert single["method"] == "fast" and single["exact_k"] == 1.0


def test_cli_demo_reports_a_missing_scene(tmp_path: Path, capsys) -> None:
    assert main(["demo", "--out", str(tmp_path / "out"), "--scene", str(tmp_path / "missing.exr")]) == 1
    assert "missing.exr" in capsys.readouterr().err


def test_demo_reads_grey_and_damaged_scenes_like_the_command_line(tmp_path: Path) -> None:
    y, x = torch.meshgrid(torch.linspace(-1, 1, 12), torch.linspace(-1, 1, 20), indexing="ij")
    grey = (0.01 + (x + 1) / 2 + 0.2 * torch.exp(-(x**2 + y**2) * 4))[None].clone()
    grey[0, 0, 0], grey[0, 1, 1] = float("nan"), float("inf")
    io.write_image(tmp_path / "grey.exr", grey)
    lines: list[str] = []
    summary = run_demo(tmp_path / "out", tmp_path / "grey.exr", workers=1, log=lines.append)
    assert any("replaced 2 NaN or infinite values" in line for line in lines)
    assert io.read_image(tmp_path / "out" / "multi_shot.exr").shape == (3, 12, 20)  # grey read as RGB
    assert summary["multi_shot"]["exact_k"] == 1.0


def test_every_png_shows_something_of_its_own(tmp_path: Path) -> None:
    """No two PNGs of the demo are the same picture (modulus_tonemapped.png was modulus.png again)."""
    from torch_modulo.singleshot import unwrap_single

    summary = run_demo(tmp_path / "out", _scene(tmp_path / "scene.exr"), workers=1, log=lambda _: None)
    pngs = sorted(Path(name) for name in summary["files"] if name.endswith(".png"))
    assert not (tmp_path / "out" / "modulus_tonemapped.png").exists()
    assert [p.name for p in pngs] == [
        "comparison.png",
        "intensity_merge_tonemapped.png",
        "intensity_tonemapped.png",
        "modulus.png",
        "multi_shot_tonemapped.png",
        "single_shot_tonemapped.png",
        "truth_tonemapped.png",
    ]
    images = {p.name: io.read_image(p) for p in pngs}
    for a in images:
        for b in images:
            if a < b and images[a].shape == images[b].shape:
                assert not torch.equal(images[a], images[b]), (a, b)
    # modulus.png is a camera frame: its values are the 8-bit modulus, its metadata says how to unwrap it
    modulus, meta = io.read_image(tmp_path / "out" / "modulus.png", with_metadata=True)
    assert meta["bits"] == 8 and meta["exposure"] == 1.0 and float(modulus.max()) <= 255
    restored = io.read_image(tmp_path / "out" / "single_shot.exr")
    assert torch.equal(unwrap_single(modulus[None], 8)[0], restored)


def test_demo_at_other_bit_depths_writes_a_frame_that_holds_them(tmp_path: Path) -> None:
    for bits, name in ((12, "modulus.png"), (20, "modulus.exr")):
        out = tmp_path / str(bits)
        scene = _scene(tmp_path / "scene.exr")
        summary = run_demo(out, scene, bits=bits, method="guided", workers=1, log=lambda _: None)
        frame, meta = io.read_image(out / name, with_metadata=True, dtype=torch.float64)
        assert str(out / name) in summary["files"] and meta["bits"] == bits
        assert float(frame.max()) < 2**bits and torch.equal(frame, torch.floor(frame))
        assert float(frame.max()) > 255  # the frame keeps the bits above 8


def test_demo_scales_a_mostly_black_scene_by_its_maximum_and_refuses_a_black_one(tmp_path: Path, capsys) -> None:
    image = torch.zeros(3, 40, 96)
    image[:, 10:14, 20:30] = 5.0  # 0.1% of the pixels or fewer are lit: the 99.9th percentile is 0
    image[:, 12, 25] = 7.0
    io.write_image(tmp_path / "dark.exr", image)
    summary = run_demo(tmp_path / "out", tmp_path / "dark.exr", method="guided", workers=1, log=lambda _: None)
    assert summary["multi_shot"]["exact_k"] == 1.0
    io.write_image(tmp_path / "black.exr", torch.zeros(3, 8, 8))
    assert main(["demo", "--out", str(tmp_path / "out2"), "--scene", str(tmp_path / "black.exr")]) == 1
    assert "is black" in capsys.readouterr().err


def test_options_that_cannot_work_are_refused_before_any_work(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit) as stop:  # argparse: a usage error, rc 2
        main(["demo", "--out", str(tmp_path / "out"), "--bits", "25"])
    assert stop.value.code == 2 and "expected a bit depth from 1 to 24; got 25" in capsys.readouterr().err
    lines: list[str] = []
    with pytest.raises(ValueError, match=r"ratio must be more than 1 and at most 2\*\*bits = 256 \(bits=8\)"):
        run_demo(tmp_path / "out", ratio=1000.0, log=lines.append)
    assert lines == [] and not (tmp_path / "out").exists()


def test_a_scene_among_the_demos_own_outputs_is_refused(tmp_path: Path) -> None:
    out = tmp_path / "out"
    run_demo(out, _scene(tmp_path / "scene.exr"), method="guided", workers=1, log=lambda _: None)
    before = (out / "multi_shot.exr").read_bytes()
    with pytest.raises(ValueError, match="is one of the files the demo writes in"):
        run_demo(out, out / "multi_shot.exr", method="guided", workers=1, log=lambda _: None)
    (tmp_path / "link.exr").symlink_to(out / "multi_shot.exr")  # through a link too
    with pytest.raises(ValueError, match="is one of the files the demo writes in"):
        run_demo(out, tmp_path / "link.exr", method="guided", workers=1, log=lambda _: None)
    assert (out / "multi_shot.exr").read_bytes() == before
