"""Tests of torch_modulo/pipeline.py: the jobs of the folder commands as Python functions (simulate, unwrap,
tonemap), the per-scene seed, and how simulate scales a scene and plans its exposures."""

from __future__ import annotations

import math
import pickle
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from torch_modulo import pipeline
from torch_modulo._task import Task
from torch_modulo.io import read_image, write_image
from torch_modulo.multishot import plan_exposures
from torch_modulo.noise import NoiseModel
from torch_modulo.pipeline import (
    fit_scale,
    plan_scene,
    scene_seed,
    simulate_job,
    tonemap_job,
    tonemap_options,
    unwrap_job,
)
from torch_modulo.sensors import FileSensor

NAN, INF = float("nan"), float("inf")


def _write(path: Path, image: torch.Tensor) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, image)
    return path


class TestJobs:
    def test_jobs_are_picklable_module_functions(self) -> None:
        for job in (simulate_job, unwrap_job, tonemap_job):
            assert pickle.loads(pickle.dumps(job)) is job
        assert pipeline.JOBS == {"simulate": simulate_job, "unwrap": unwrap_job, "tonemap": tonemap_job}

    def test_scene_seed_is_stable(self) -> None:
        assert scene_seed(3, "a.exr") == scene_seed(3, "a.exr")
        assert len({scene_seed(s, n) for s in (0, 1) for n in ("a.exr", "b.exr")}) == 4

    def test_simulate_then_unwrap_then_tonemap(self, tmp_path: Path) -> None:
        radiance = torch.exp2(torch.linspace(0, 12, 48)).view(1, 6, 8).expand(3, -1, -1).contiguous()
        radiance[0, 0, 0] = NAN
        source = _write(tmp_path / "scene.exr", radiance)
        options = {
            "bits": 8,
            "exposures": [1.0, 64.0, 4096.0],
            "noise": None,
            "seed": 0,
            "scale": "auto",
            "format": "exr",
            "truth": True,
        }
        info = simulate_job(Task("scene.exr", str(source), (str(tmp_path / "stack"),)), options)
        assert info["nonfinite_replaced"] == {"nan": 1, "posinf": 0, "neginf": 0} and info["warnings"]
        stack = FileSensor(tmp_path / "stack").read()
        assert stack.bits == 8 and stack.exposures.tolist() == [1.0, 64.0, 4096.0]
        unwrap_options = {"single": False, "bits": None, "exposure": None, "method": "robust", "solver": None}
        unwrap_job(Task("stack", str(tmp_path / "stack"), (str(tmp_path / "r.exr"),)), unwrap_options)
        assert read_image(tmp_path / "r.exr").shape == (3, 6, 8)
        info = tonemap_job(
            Task("r.exr", str(tmp_path / "r.exr"), (str(tmp_path / "r.png"),)), tonemap_options("log", {})
        )
        assert "warnings" not in info and read_image(tmp_path / "r.png").shape == (3, 6, 8)

    def test_simulate_keeps_what_else_the_output_folder_holds(self, tmp_path: Path) -> None:
        radiance = torch.exp2(torch.linspace(0, 12, 48)).view(1, 6, 8)
        source = _write(tmp_path / "in" / "scene.exr", radiance)
        out = tmp_path / "out" / "scene"
        (out / "notes").mkdir(parents=True)
        (out / "notes" / "thesis.txt").write_text("mine")
        (out / "mine.exr").write_bytes(b"not a frame")
        options = {"bits": 8, "noise": None, "seed": 0, "scale": "auto", "format": "exr", "truth": True}
        task = Task("scene.exr", str(source), (str(out),))
        simulate_job(task, {**options, "exposures": [1.0, 64.0, 4096.0]})
        first = {p.name for p in out.iterdir()}
        assert {"notes", "mine.exr", "frames.json", "radiance.exr"} <= first and len(first) == 7
        simulate_job(task, {**options, "exposures": [1.0, 64.0], "truth": False})  # a smaller stack replaces it
        assert (out / "notes" / "thesis.txt").read_text() == "mine"
        assert (out / "mine.exr").read_bytes() == b"not a frame"
        assert {p.name for p in out.iterdir()} == {"notes", "mine.exr", "frames.json"} | {
            p.name for p in out.glob("frame_*")
        }
        assert len(list(out.glob("frame_*"))) == 2 and FileSensor(out).read().exposures.tolist() == [1.0, 64.0]

    def test_colour_sensor_jobs(self, tmp_path: Path) -> None:
        from torch_modulo.cfa import demosaic, mosaic

        ramp = torch.exp2(torch.linspace(0, 12, 48)).view(1, 6, 8)
        source = _write(tmp_path / "scene.exr", torch.cat([ramp, 0.5 * ramp, 0.25 * ramp]))
        options = {
            "bits": 8,
            "exposures": [1.0, 64.0, 4096.0],
            "noise": None,
            "seed": 0,
            "scale": "auto",
            "format": "exr",
            "truth": True,
            "cfa": "GBRG",
        }
        info = simulate_job(Task("scene.exr", str(source), (str(tmp_path / "stack"),)), options)
        assert info["cfa"] == "GBRG" and info["shape"] == [3, 6, 8]
        stack = FileSensor(tmp_path / "stack").read()
        assert stack.cfa == "GBRG" and stack.moduli.shape == (1, 3, 1, 6, 8)
        truth = read_image(tmp_path / "stack" / "radiance.exr", dtype=torch.float64)
        assert truth.shape == (3, 6, 8)
        unwrap_options = {"single": False, "bits": None, "exposure": None, "method": "robust", "solver": None}
        task = Task("stack", str(tmp_path / "stack"), (str(tmp_path / "r.exr"),))
        info = unwrap_job(task, unwrap_options)  # the pattern from the stack; demosaiced by default
        assert info["cfa"] == "GBRG" and info["shape"] == [3, 6, 8] and "accuracy" in info
        counts = torch.floor(4096 * mosaic(truth, "GBRG")) / 4096  # noise-free: floor(tau_max E) / tau_max
        torch.testing.assert_close(read_image(tmp_path / "r.exr", dtype=torch.float64), demosaic(counts, "GBRG"))
        info = unwrap_job(task, {**unwrap_options, "demosaic": False})
        assert info["shape"] == [1, 6, 8] and info["accuracy"]["median_relative_error"] < 1e-3
        torch.testing.assert_close(read_image(tmp_path / "r.exr", dtype=torch.float64), counts)
        with pytest.raises(ValueError, match="records the colour filter array 'GBRG' but --cfa RGGB was given"):
            unwrap_job(task, {**unwrap_options, "cfa": "RGGB"})
        grey = _write(tmp_path / "grey.exr", ramp)
        with pytest.raises(ValueError, match=r"grey\.exr is not an RGB scene \(1 channel\)"):
            simulate_job(Task("grey.exr", str(grey), (str(tmp_path / "g"),)), options)
        assert not (tmp_path / "g").exists()

    def test_tonemap_options(self) -> None:
        assert tonemap_options("clahe", {"grid_size": [2, 2]}, srgb=True, depth=16) == {
            "op": "clahe",
            "params": {"grid_size": [2, 2]},
            "srgb": True,
            "depth": 16,
        }
        with pytest.raises(ValueError, match="tonemap_reinhard has no parameter 'gamma'; its parameters are key"):
            tonemap_options("reinhard", {"gamma": 2.0})
        with pytest.raises(ValueError, match="key"):
            tonemap_options("reinhard", {"key": -1.0})
        with pytest.raises(ValueError, match="op must be one of"):
            tonemap_options("drago", {})
        with pytest.raises(TypeError, match="srgb must be .*; got 'no'"):
            tonemap_options("log", {}, srgb="no")  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="depth must be one of 16, 8; got 12"):
            tonemap_options("log", {}, depth=12)


class TestScaling:
    def test_plan_scene_is_protocol_n(self) -> None:
        g = torch.Generator().manual_seed(0)
        image = torch.exp2(torch.rand(3, 32, 32, generator=g, dtype=torch.float64) * 14 - 3)
        low = float(torch.quantile(image.flatten(), 0.001))
        stops = math.ceil(math.log2(float(image.max()) / low) + 4)
        for noise in (None, NoiseModel(), "q16"):
            taus, scale, got_stops = plan_scene(image, 8, noise)
            plan = plan_exposures(stops, 8, noise=noise)
            assert got_stops == stops and scale == pytest.approx(16 / low)
            assert taus == pytest.approx([t / plan[-1] for t in plan], rel=1e-12) and taus[-1] == 1.0
            # a given scale moves the exposures instead: the same counts
            moved, same, _ = plan_scene(image, 8, noise, scale=2.0)
            assert same == 2.0 and moved == pytest.approx([t * scale / 2.0 for t in taus], rel=1e-12)

    def test_plan_scene_keeps_the_brightest_value_off_the_rollover(self) -> None:
        image = torch.ones(1, 40, 50, dtype=torch.float64)
        image[0, 0, 0] = 4096.0  # max / p = 2^12 exactly: the noise-free plan for 16 stops reads 256 at the shortest
        taus, scale, stops = plan_scene(image, 8)
        assert stops == 17 and float(image.max()) * scale * taus[0] < 256

    def test_plan_scene_under_dark_current_is_planned_at_its_own_exposures(self) -> None:
        # Regression: plan_scene planned at base 1 and rescaled to longest 1, so under dark current (electrons per
        # unit exposure) the plan reasoned about ~1e5 times the dark counts captured: 312% median error on a CLI run.
        g = torch.Generator().manual_seed(0)
        image = torch.exp2(16 * torch.rand(1, 64, 64, generator=g, dtype=torch.float64))  # 16 stops
        from torch_modulo.multishot import unwrap_multi
        from torch_modulo.sensors import SimulatedModuloSensor

        medians, gross = {}, {}
        for dark in (0.0, 5.0, 20.0):
            noise = NoiseModel(dark_current=dark)
            # each pixel alone: the scene is independent draws per pixel, where no neighbour agrees
            taus, scale, stops = plan_scene(image, 8, noise, spatial=False)
            # a fixed point: the plan made at its own shortest exposure, ending at the longest (1)
            fixed = plan_exposures(stops, 8, noise=noise, base=taus[0], spatial=False)
            assert taus[-1] == 1.0 and taus == pytest.approx(fixed)
            radiance = (image * scale)[None]
            stack = SimulatedModuloSensor(bits=8, noise=noise, seed=0)(radiance, taus)
            decoded = unwrap_multi(stack.moduli, stack.exposures, 8, noise=noise, spatial=False)
            relative = (decoded - radiance).abs() / radiance
            medians[dark], gross[dark] = float(relative.median()), float((relative > 0.5).double().mean())
        # measured: medians 1.94%, 1.95%, 1.92%, gross 0.07%, 0.10%, 0.29% (before the fix: 2.8% / 1.0%, 5.6% / 21%)
        assert medians[0.0] < 0.03
        for dark in (5.0, 20.0):
            assert medians[dark] < 1.25 * medians[0.0] and gross[dark] < 0.01

    def test_plan_scene_without_dark_current_scales_the_base_one_plan(self) -> None:
        # Without dark current a plan is scale-free: exactly the base-1 plan rescaled, as before the dark-current fix.
        from torch_modulo.protocols import protocol_n

        g = torch.Generator().manual_seed(2)
        image = torch.exp2(torch.rand(1, 16, 16, generator=g, dtype=torch.float64) * 10)
        auto_scale, _ = protocol_n(image)
        for noise in (None, "photon-counting", "dfpa", NoiseModel(read_noise=3.0, prnu=0.02)):
            for scale in ("auto", 0.5):
                taus, factor, stops = plan_scene(image, 8, noise, scale=scale)
                plan = plan_exposures(stops, 8, noise=noise)
                assert taus == [t * (auto_scale / factor) / plan[-1] for t in plan]

    def test_fit_scale(self) -> None:
        image = torch.rand(3, 20, 30, dtype=torch.float64) + 0.5
        assert fit_scale(image, 8, [2.0, 32.0]) * float(image.max()) * 2.0 == pytest.approx(255)
        noisy = fit_scale(image, 8, [2.0, 32.0], "photon-counting") * float(image.max()) * 2.0
        assert noisy + 3 * math.sqrt(NoiseModel().count_variance(noisy)) == pytest.approx(255)
        # one exposure: protocol A's percentile at 16 periods, of luminance (RGB) or of all values (grey)
        y = 0.2126 * image[0] + 0.7152 * image[1] + 0.0722 * image[2]
        assert fit_scale(image, 8, [4.0]) == pytest.approx(4095 / (float(torch.quantile(y.flatten(), 0.999)) * 4))
        grey = image[:1]
        assert fit_scale(grey, 10, [1.0]) == pytest.approx(16383 / float(torch.quantile(grey.flatten(), 0.999)))
        with pytest.raises(ValueError, match="black"):
            fit_scale(torch.zeros(1, 2, 2), 8, [1.0])
        with pytest.raises(ValueError, match="black"):
            plan_scene(torch.zeros(1, 2, 2), 8)

    def test_fit_scale_leaves_room_for_dark_counts(self) -> None:
        image = torch.rand(1, 20, 30, dtype=torch.float64) + 0.5
        noise = NoiseModel(dark_current=40.0)  # 40 dark counts per unit exposure: 80 at the shortest exposure
        signal = fit_scale(image, 8, [2.0, 32.0], noise) * float(image.max()) * 2.0
        total = signal + 80.0
        assert total + 3 * math.sqrt(noise.count_variance(total)) == pytest.approx(255)
        with pytest.raises(ValueError, match="dark counts of the shortest exposure 8 \\(320 counts\\) leave no count"):
            fit_scale(image, 8, [8.0, 32.0], noise)

    def test_jobs_plan_and_decode_with_noise(self, tmp_path: Path) -> None:
        g = torch.Generator().manual_seed(1)
        source = _write(tmp_path / "s.exr", torch.exp2(torch.rand(3, 16, 16, generator=g) * 12))
        options = {"bits": 8, "exposures": "auto", "noise": "q16", "seed": 0, "scale": "auto"}
        info = simulate_job(
            Task("s.exr", str(source), (str(tmp_path / "stack"),)), {**options, "format": "exr", "truth": True}
        )
        assert info["noise"] == "q16" and info["stops"] >= 12 and "warnings" not in info
        stack = FileSensor(tmp_path / "stack").read()
        assert stack.metadata["noise"] == NoiseModel.preset("q16").to_dict()
        unwrap_options = {"single": False, "bits": None, "exposure": None, "method": "robust", "solver": None}
        info = unwrap_job(Task("stack", str(tmp_path / "stack"), (str(tmp_path / "r.exr"),)), unwrap_options)
        # The stack's model, by default. Every pixel is drawn alone (a texture throughout), which the spatial plan's
        # first ratio asks the neighbours for: 2 of the 768 values stop early (docs/multishot.md, "When to turn it
        # off").
        assert info["noise"] == "q16" and info["accuracy"]["gross_share"] < 0.005
        assert info["accuracy"]["median_relative_error"] < 0.05


class TestSpatial:
    """``spatial``: simulate plans for the decoder with spatial evidence and records it; unwrap follows the record."""

    OPTIONS = {"bits": 8, "exposures": "auto", "noise": "q16", "seed": 0, "scale": "auto", "format": "exr"}
    UNWRAP = {"single": False, "bits": None, "exposure": None, "method": "robust", "solver": None}

    def _scene(self, tmp_path: Path) -> Path:
        y, x = torch.meshgrid(torch.linspace(0, 1, 32), torch.linspace(0, 1, 40), indexing="ij")
        ramp = torch.exp2(14 * (0.6 * x + 0.4 * y))  # a smooth 14-stop scene
        return _write(tmp_path / "s.exr", torch.stack([ramp, 0.7 * ramp, 0.4 * ramp]))

    def test_a_spatial_plan_is_recorded_and_decoded_so(self, tmp_path: Path) -> None:
        from torch_modulo.multishot import unwrap_multi

        source = self._scene(tmp_path)
        infos = {
            spatial: simulate_job(
                Task("s.exr", str(source), (str(tmp_path / f"stack{spatial}"),)),
                {**self.OPTIONS, "truth": True, "spatial": spatial},
            )
            for spatial in (False, True)
        }
        assert infos[True]["spatial"] is True and infos[False]["spatial"] is False
        assert len(infos[True]["exposures"]) < len(infos[False]["exposures"])
        stack = FileSensor(tmp_path / "stackTrue").read()
        assert stack.metadata["spatial"] is True
        assert FileSensor(tmp_path / "stackFalse").read().metadata["spatial"] is False
        default = simulate_job(Task("s.exr", str(source), (str(tmp_path / "d"),)), {**self.OPTIONS, "truth": True})
        assert default["exposures"] == infos[True]["exposures"] and default["spatial"] is True  # the default
        quiet = {**self.OPTIONS, "noise": None, "truth": False}
        quiet = simulate_job(Task("s.exr", str(source), (str(tmp_path / "q"),)), quiet)
        assert "spatial" not in quiet and "warnings" not in quiet  # noise-free: nothing to say
        task = Task("stack", str(tmp_path / "stackTrue"), (str(tmp_path / "r.exr"),))
        info = unwrap_job(task, self.UNWRAP)  # spatial, as the stack records
        assert info["spatial"] is True and info["accuracy"]["gross_share"] == 0.0 and "warnings" not in info
        expected = unwrap_multi(stack.moduli, stack.exposures, 8, noise="q16", spatial=True)[0]
        torch.testing.assert_close(read_image(tmp_path / "r.exr"), expected.float())
        assert read_image(tmp_path / "r.exr", with_metadata=True)[1]["spatial"] is True
        info = unwrap_job(task, {**self.UNWRAP, "spatial": False})  # per pixel, on request
        assert info["spatial"] is False
        expected = unwrap_multi(stack.moduli, stack.exposures, 8, noise="q16", spatial=False)[0]
        torch.testing.assert_close(read_image(tmp_path / "r.exr"), expected.float())
        info = unwrap_job(task, {**self.UNWRAP, "spatial": True, "noise": None})  # no model: noise-free, said
        assert "spatial" not in info and "decoded noise-free" in info["warnings"][0]

    def test_a_mosaic_is_decoded_plane_by_plane(self, tmp_path: Path) -> None:
        from torch_modulo.multishot import unwrap_multi

        source = self._scene(tmp_path)
        options = {**self.OPTIONS, "truth": True, "spatial": True, "cfa": "RGGB"}
        simulate_job(Task("s.exr", str(source), (str(tmp_path / "stack"),)), options)
        stack = FileSensor(tmp_path / "stack").read()
        task = Task("stack", str(tmp_path / "stack"), (str(tmp_path / "r.exr"),))
        info = unwrap_job(task, {**self.UNWRAP, "demosaic": False})
        assert info["spatial"] is True and info["shape"] == [1, 32, 40] and info["accuracy"]["gross_share"] == 0.0
        # Each colour plane is its own image: a photosite's neighbours are the nearest of its colour.
        expected = torch.empty(1, 32, 40)
        for dy in (0, 1):
            for dx in (0, 1):
                plane = stack.moduli[:, :, :, dy::2, dx::2]  # (1, M, 1, 16, 20)
                decoded = unwrap_multi(plane, stack.exposures, 8, noise="q16", spatial=True)
                expected[:, dy::2, dx::2] = decoded[0].float()
        torch.testing.assert_close(read_image(tmp_path / "r.exr"), expected)


def test_importing_the_jobs_imports_neither_the_batch_engine_nor_the_command_line() -> None:
    code = (
        "import sys, torch_modulo.pipeline\n"
        "print(sorted(m for m in sys.modules if m.startswith(('torch_modulo.batch', 'torch_modulo.cli', "
        "'torch_modulo.folders'))))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"


def test_moved_names_still_work_with_a_deprecation_warning() -> None:
    from torch_modulo import folders, radiance

    assert pipeline.load_radiance is radiance.load_radiance and pipeline.NONFINITE is radiance.NONFINITE
    assert pipeline.RADIANCE_EXTENSIONS is radiance.RADIANCE_EXTENSIONS
    for name in ("folder_tasks", "count_values", "MODULUS_EXTENSIONS"):
        with pytest.warns(
            DeprecationWarning, match=f"torch_modulo.pipeline.{name} is deprecated; use torch_modulo.folders"
        ):
            assert getattr(pipeline, name) is getattr(folders, name)
    with pytest.raises(AttributeError, match="has no attribute 'nothing'"):
        pipeline.nothing  # noqa: B018


class TestSimulateRefusesUndecodableExposures:
    def test_ratios_above_two_to_the_bits_are_refused_before_writing(self, tmp_path: Path) -> None:
        # Regression: exposures 1, 1000, 1e6 at 8 bits warned, wrote every stack, and unwrap then failed them all.
        source = write_image(tmp_path / "a.exr", torch.rand(3, 4, 4) * 100 + 1)
        options = {"bits": 8, "exposures": [1.0, 1000.0, 1e6], "noise": None, "seed": 0, "scale": "auto"}
        options |= {"format": "exr", "truth": True}
        task = Task("a.exr", str(source), (str(tmp_path / "out"),))
        with pytest.raises(ValueError, match=r"exposures 1 and 1000 are 1000 times apart, more than 2\^8 = 256"):
            pipeline.simulate_job(task, options)
        assert not (tmp_path / "out").exists()
        info = pipeline.simulate_job(task, {**options, "force_exposures": True})
        assert info["exposures"] == [1.0, 1000.0, 1e6] and any("1000 times apart" in w for w in info["warnings"])


def test_tonemap_job_refuses_frames(tmp_path: Path) -> None:
    # Regression: the tonemap job tone-mapped a wrapped frame as radiance.
    frame = write_image(tmp_path / "f.exr", torch.ones(1, 2, 2) * 3, {"bits": 8, "exposure": 16.0})
    task = Task("f.exr", str(frame), (str(tmp_path / "f.png"),))
    with pytest.raises(ValueError, match=r"f\.exr is not radiance: a frame of a modulo camera"):
        pipeline.tonemap_job(task, tonemap_options("log", {}))
    assert not (tmp_path / "f.png").exists()
