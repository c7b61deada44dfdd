"""The figure scripts in examples/ run at reduced size (--quick), write their PNG and report sane numbers.

Each test imports a script and calls its ``main`` with ``--quick --out tmp_path``; ``main`` returns the numbers it
printed. The checks are the paper's claims at small size: if the library regresses (a wrong rollover count, a
broken merge) the claim fails here.
"""

from __future__ import annotations

import importlib
import math
import os
import stat
import sys
from pathlib import Path
from types import ModuleType

import pytest

from torch_modulo.assets import default_scene_path

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _load(name: str) -> ModuleType:
    if str(EXAMPLES) not in sys.path:
        sys.path.insert(0, str(EXAMPLES))
    return importlib.import_module(name)


def _whole(value: float) -> int:
    """``value`` as an int, asserting that it is one (a count recovered from a reported share or score)."""
    count = round(value)
    assert abs(value - count) < 1e-6 * max(1.0, abs(value)), value
    return count


def _run(name: str, tmp_path: Path, *extra: str) -> dict:
    result = _load(name).main(["--quick", "--out", str(tmp_path), *extra])
    png = Path(result["png"])
    assert png.parent == tmp_path
    assert png.is_file() and png.stat().st_size > 1000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert list(tmp_path.glob(".*.tmp")) == []  # atomic write left nothing behind
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(png.stat().st_mode) == 0o666 & ~umask  # regression: mkstemp's 0600 leaked into the PNG
    assert result["verdict"].startswith("VERDICT: ")
    return result


class TestFig08Band:
    def test_modulo_beats_intensity(self, tmp_path: Path) -> None:
        result = _run("fig08_band", tmp_path)
        errors = result["errors"]
        modulo = errors["modulo, 2 captures (1:16)"]
        two = errors["intensity, 2 captures (1:16)"]
        five = errors["intensity, 5 captures (1:2:4:8:16)"]
        # The modulo reconstruction is floor(E): below one 8-bit step everywhere and 256 distinct levels.
        assert modulo["max"] < 1.0
        assert modulo["levels"] == 256
        # A 4-bit intensity camera quantises the upper half with the short exposure: steps of 16.
        assert two["max"] > 8.0 and five["max"] > 8.0
        assert five["mean"] < two["mean"]  # more captures help the dark end
        assert modulo["mean"] < five["mean"] / 5
        assert result["holds"]


class TestFig10MultiShot:
    def test_modulo_exact_intensity_quantised(self, tmp_path: Path) -> None:
        result = _run("fig10_multi_shot", tmp_path)
        for scores in result["scores"].values():
            assert scores["modulo, 2 captures"]["exact"]
            assert math.isinf(scores["modulo, 2 captures"]["psnr"])
            two = scores["intensity, 2 captures"]["psnr"]
            five = scores["intensity, 5 captures"]["psnr"]
            assert 20.0 < two < five < 45.0
        assert result["holds"]


class TestClaim24Stops:
    def test_three_captures_cover_24_stops(self, tmp_path: Path) -> None:
        result = _run("claim_24_stops", tmp_path)
        assert result["exposures"] == [1.0, 256.0, 65536.0]
        ramp = result["results"]["24-stop ramp"]
        assert ramp["exact_share"] == 1.0
        assert ramp["exact_share_paper"] == 1.0  # ratios of exactly 2^N: Eq. 6 as printed is exact too
        assert ramp["covered_stops"] > 23.9
        assert ramp["rel_median_modulo"] < ramp["rel_median_intensity"] / 10
        # Ratios of 255 leave a noise margin: the robust rule stays exact, Eq. 6 as printed does not.
        safe = result["results"]["24-stop ramp, ratios 255"]
        assert safe["exact_share"] == 1.0
        assert safe["exact_share_paper"] < 0.9
        assert result["holds"]


class TestFig14Noise:
    def test_multi_shot_degrades_with_noise(self, tmp_path: Path) -> None:
        result = _run("fig14_noise", tmp_path, "--no-single")
        r = result["results"]
        assert r["0.0"]["2 captures 1:16, room"] == 1.0
        assert r["0.0"]["2 captures 1:256, room"] == 1.0
        # A larger ratio multiplies the short exposure's noise: it breaks first.
        assert r["4.0"]["2 captures 1:256, room"] < r["4.0"]["2 captures 1:16, room"] < 1.0
        assert result["holds"]

    @pytest.mark.slow
    def test_with_single_shot(self, tmp_path: Path) -> None:
        result = _run("fig14_noise", tmp_path)
        r = result["results"]
        smooth = "single shot, smooth surface"
        assert r["0.0"][smooth] == 1.0  # noise-free, the smooth surface unwraps exactly
        assert r["4.0"][smooth] == 1.0  # moderate read noise does not hurt single shot
        assert r["32.0"][smooth] < 0.95 and r["shot"][smooth] < 0.95
        assert result["holds"]


class TestFig02WrapUnwrap:
    def test_surface_recovered_exactly(self, tmp_path: Path) -> None:
        result = _run("fig02_wrap_unwrap", tmp_path)
        assert result["equal"] and result["exact_k"] == 1.0
        assert result["holds"]


class TestFig05Energy:
    def test_energy_falls_and_truth_is_not_the_minimum(self, tmp_path: Path) -> None:
        result = _run("fig05_06_energy", tmp_path)
        assert result["monotone"]
        smooth = result["runs"]["smooth synthetic surface"]
        assert smooth["exact_k"] == 1.0
        assert smooth["energies"][-1] < smooth["energies"][0]
        room = result["runs"]["apartment (embedded)"]
        assert 0.5 < room["exact_k"] < 1.0
        assert result["prefers_wrong"] == ["apartment (embedded)"]  # the paper's energy prefers a wrong answer
        # The intermediate states end at the final result.
        assert result["states"]["smooth surface"][-1][2] == 1.0
        assert result["holds"] == "PARTLY"


class TestFig09SingleShot:
    def test_scores_are_sane(self, tmp_path: Path) -> None:
        result = _run("fig09_single_shot", tmp_path)
        (scene,) = result["scenes"]
        h, w = scene["shape"]
        n = h * w  # one grey plane
        wrong, rolled = _whole((1 - scene["exact_k"]) * n), _whole(scene["wrapped_share"] * n)
        wrong_rolled = _whole((1 - scene["exact_k_wrapped"]) * rolled)
        assert 0 < wrong < n / 2 and 0 < rolled < n and wrong_rolled <= wrong
        # Restored and true counts share the modulus, so each aligned error is a whole number m of periods (256):
        # the PSNR (peak 4095) implies sum(m^2) = n 4095^2 / (256^2 10^(PSNR/10)), a whole number >= the wrong
        # values (m^2 >= 1 on each).
        squares = _whole(n * 4095**2 / (256**2 * 10 ** (scene["psnr"] / 10)))
        assert squares >= wrong
        assert scene["energy_found"] > 0 and scene["energy_truth"] > 0
        assert not result["holds"]


class TestFig13Failure:
    def test_two_captures_exact(self, tmp_path: Path) -> None:
        result = _run("fig13_failure", tmp_path)
        assert result["scores"]["two captures (1:256)"]["identical"]
        assert result["scores"]["two captures (1:256)"]["exact_k"] == 1.0

    def test_sun(self, tmp_path: Path, shared_hdr: Path) -> None:
        result = _run("fig13_failure", tmp_path, "--scene", "qt-preview/landscape.hdr")
        assert result["scene"] == "landscape"
        single = result["scores"]["single shot"]
        assert single["exact_k_bright"] < 0.5 < single["exact_k"]
        assert result["holds"]


class TestMissingScenes:
    """Without the scenes folder (a fresh clone) the figures run on what exists, under its own name, and say what is
    missing; a scene the user names must exist."""

    @pytest.fixture
    def common(self, monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> ModuleType:
        module = _load("_common")
        monkeypatch.setattr(module, "SCENES_DIR", tmp_path / "absent")
        return module

    def test_embedded_stands_in_under_its_own_name(self, common: ModuleType, capsys: pytest.CaptureFixture) -> None:
        found = common.find_scenes(["openexr-images/a.exr", "hdr-samples/b.hdr"])
        assert found == [("apartment (embedded)", default_scene_path())]
        out = capsys.readouterr().out
        assert "missing 2 of 2 scene(s)" in out and "openexr-images/a.exr, hdr-samples/b.hdr" in out
        assert "does not exist" in out and "using the embedded scene instead" in out
        assert common.find_scenes(["openexr-images/a.exr"], fallback=False) == []
        with pytest.raises(FileNotFoundError, match="openexr-images/a.exr"):
            common.find_scenes(["openexr-images/a.exr"], required=True)

    def test_present_scenes_only(
        self, common: ModuleType, monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture
    ) -> None:
        (tmp_path / "src").mkdir()
        (tmp_path / "src" / "a.exr").write_bytes(b"")
        monkeypatch.setattr(common, "SCENES_DIR", tmp_path)
        assert common.find_scenes(["src/a.exr", "src/b.exr"]) == [("a", tmp_path / "src" / "a.exr")]
        assert "missing 1 of 2 scene(s) under" in capsys.readouterr().out

    def test_fig10_default_scenes(self, common: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
        result = _load("fig10_multi_shot").main(["--out", str(tmp_path)])  # the real scenes, not --quick
        assert list(result["scores"]) == ["apartment (embedded)"]
        assert "missing 3 of 3 scene(s)" in capsys.readouterr().out
        assert result["holds"]

    def test_fig09_default_scenes(self, common: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
        result = _load("fig09_single_shot").main(["--out", str(tmp_path), "--method", "fast"])  # not --quick
        assert [scene["name"] for scene in result["scenes"]] == ["apartment (embedded)"]  # once, under its own name
        assert "missing 7 of 7 scene(s)" in capsys.readouterr().out

    @pytest.mark.parametrize(("script", "option"), [("fig09_single_shot", "--scenes"), ("fig13_failure", "--scene")])
    def test_named_scene_must_exist(self, common: ModuleType, tmp_path: Path, script: str, option: str) -> None:
        with pytest.raises(FileNotFoundError, match="qt-preview/landscape.hdr"):
            _load(script).main(["--quick", "--out", str(tmp_path), option, "qt-preview/landscape.hdr"])


def test_sensor_pipeline_reads_every_scene_of_a_colour_camera_folder(tmp_path: Path) -> None:
    """``--frames``: a stack of two mosaicked scenes gives two RGB radiance maps (it wrote the first scene's
    mosaic alone)."""
    import torch

    from torch_modulo.cfa import demosaic, mosaic
    from torch_modulo.io import read_image
    from torch_modulo.sensors import SimulatedModuloSensor, write_frames

    y, x = torch.meshgrid(torch.linspace(0, 1, 6), torch.linspace(0, 1, 8), indexing="ij")
    rgb = torch.stack([torch.stack([10 + 200 * x, 20 + 150 * y, 30 + 100 * x * y]) * s for s in (1.0, 0.5)])
    stack = SimulatedModuloSensor(bits=8, noise=None, cfa="GBRG")(rgb, [1.0, 16.0])  # no rollover at 1: exact
    write_frames(stack, tmp_path / "cam")
    _load("sensor_pipeline").main(["--frames", str(tmp_path / "cam"), "--out", str(tmp_path / "out")])
    for b in range(2):
        radiance = read_image(tmp_path / "out" / f"cam_b{b:03d}_radiance.exr", dtype=torch.float64)
        expected = demosaic(torch.floor(mosaic(rgb[b : b + 1] * 16, "GBRG")) / 16, "GBRG")[0]
        torch.testing.assert_close(radiance, expected.double(), rtol=1e-5, atol=1e-4)
