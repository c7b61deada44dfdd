"""Tests for colour filter arrays: torch_modulo/cfa.py, and the path of a colour modulo camera through the sensors
(simulated and file-backed), the FrameStack, single- and multi-shot unwrapping and demosaicing."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest
import torch
from kornia.color import CFA, raw_to_rgb

import torch_modulo as tm
from torch_modulo.cfa import (
    CFA_PATTERNS,
    DEMOSAIC_METHODS,
    Demosaic,
    Mosaic,
    cfa_colours,
    check_cfa,
    demosaic,
    interpolate_wrapped,
    merge_planes,
    mosaic,
    split_planes,
)
from torch_modulo.sensors import (
    MANIFEST,
    FileSensor,
    FrameStack,
    NoiseModel,
    SimulatedIntensitySensor,
    SimulatedModuloSensor,
    fixed_pattern_gain,
    simulate_capture,
    write_frames,
)

#: kornia names a pattern by pixel (1, 1) (OpenCV's names); ours by the top-left 2 x 2 cell.
KORNIA = {"RGGB": CFA.BG, "GRBG": CFA.GB, "BGGR": CFA.RG, "GBRG": CFA.GR}
BAD_PATTERNS = ["rggb", "RGB", "RGBG", "", None, 3, ("R", "G", "G", "B"), ["RGGB"]]


def _rgb(shape: tuple[int, ...], seed: int = 0, scale: float = 1000.0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(shape, generator=g, dtype=torch.float64) * scale


def _smooth_rgb(h: int = 32, w: int = 48, batch: int = 1, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """A smooth colour scene whose counts roll over many times: (B, 3, H, W), channels of different slopes."""
    y, x = torch.meshgrid(
        torch.linspace(0, 1, h, dtype=torch.float64), torch.linspace(0, 1, w, dtype=torch.float64), indexing="ij"
    )
    scenes = []
    for i in range(batch):
        s = 1.0 + 0.2 * i
        r = s * (1500 * x + 600 * y) + 40 * torch.sin(6 * y) + 60
        g = s * 900 * (x + y) + 30 * torch.cos(5 * x) + 40
        b = s * (700 * (1 - x) + 1000 * y) + 25
        scenes.append(torch.stack([r, g, b]))
    return torch.stack(scenes).to(dtype)


# ------------------------------------------------------------------------------------------------------ patterns


class TestPatterns:
    def test_colours(self) -> None:
        assert cfa_colours("RGGB") == (0, 1, 1, 2)
        assert cfa_colours("BGGR") == (2, 1, 1, 0)
        assert cfa_colours("GRBG") == (1, 0, 2, 1)
        assert cfa_colours("GBRG") == (1, 2, 0, 1)
        for pattern in CFA_PATTERNS:
            assert sorted(cfa_colours(pattern)) == [0, 1, 1, 2]

    @pytest.mark.parametrize("bad", BAD_PATTERNS, ids=repr)
    def test_bad_pattern_named(self, bad: object) -> None:
        with pytest.raises(ValueError, match=r"cfa must be one of .*'RGGB'.*; got " + re.escape(repr(bad))):
            check_cfa(bad)

    @pytest.mark.parametrize("bad", ["rggb", "XYZW", None])
    def test_every_entry_point_names_the_bad_pattern(self, bad: object) -> None:
        rgb, m = _rgb((1, 3, 4, 4)), _rgb((1, 1, 4, 4)).floor()
        calls = [
            lambda: mosaic(rgb, bad),
            lambda: demosaic(m, bad),
            lambda: Mosaic(bad),
            lambda: Demosaic(bad),
            lambda: cfa_colours(bad),
            lambda: SimulatedModuloSensor(cfa=bad) if bad is not None else check_cfa(bad),
            lambda: simulate_capture(rgb, [1.0], cfa=bad) if bad is not None else check_cfa(bad),
            lambda: FrameStack(m[None] % 256, [1.0], 8, cfa=bad) if bad is not None else check_cfa(bad),
            lambda: tm.unwrap_single(m % 256, 8, cfa=bad, workers=1) if bad is not None else check_cfa(bad),
            lambda: tm.SingleShotUnwrap(8, cfa=bad) if bad is not None else check_cfa(bad),
        ]
        for call in calls:
            with pytest.raises(ValueError, match=re.escape(repr(bad))):
                call()


# ----------------------------------------------------------------------------------------------- planes, mosaic


class TestPlanes:
    @pytest.mark.parametrize("shape", [(1, 2, 2), (1, 4, 6), (2, 1, 4, 6), (3, 2, 1, 8, 2), (0, 1, 4, 4)])
    def test_round_trip_shapes(self, shape: tuple[int, ...], device: torch.device, dtype: torch.dtype) -> None:
        m = _rgb(shape).to(device, dtype)
        planes = split_planes(m)
        assert planes.shape == (*shape[:-3], 4, shape[-2] // 2, shape[-1] // 2)
        assert planes.device == m.device and planes.dtype == dtype
        assert torch.equal(merge_planes(planes), m)

    def test_unit_plane_order(self) -> None:
        m = torch.arange(16.0).view(1, 4, 4)
        planes = split_planes(m)
        assert planes[0].tolist() == [[0.0, 2.0], [8.0, 10.0]]  # photosites (0, 0)
        assert planes[1].tolist() == [[1.0, 3.0], [9.0, 11.0]]  # (0, 1)
        assert planes[2].tolist() == [[4.0, 6.0], [12.0, 14.0]]  # (1, 0)
        assert planes[3].tolist() == [[5.0, 7.0], [13.0, 15.0]]  # (1, 1)

    @pytest.mark.parametrize("shape", [(1, 3, 4), (1, 4, 5), (2, 1, 7, 7)])
    def test_odd_refused(self, shape: tuple[int, ...]) -> None:
        h, w = shape[-2:]
        with pytest.raises(ValueError, match=rf"even height and width.*got {h} x {w}"):
            split_planes(torch.zeros(shape))

    def test_errors(self) -> None:
        with pytest.raises(ValueError, match=r"mosaic must have shape \(\*, 1, H, W\); got \(3, 4, 4\)"):
            split_planes(torch.zeros(3, 4, 4))
        with pytest.raises(ValueError, match=r"\(\*, 1, H, W\); got \(4, 4\)"):
            split_planes(torch.zeros(4, 4))
        with pytest.raises(ValueError, match=r"planes must have shape \(\*, 4, h, w\); got \(1, 3, 2, 2\)"):
            merge_planes(torch.zeros(1, 3, 2, 2))
        with pytest.raises(TypeError, match="mosaic must be a torch.Tensor; got list"):
            split_planes([[0.0]])  # type: ignore[arg-type]


class TestMosaic:
    def test_smoke(self, device: torch.device, dtype: torch.dtype) -> None:
        rgb = _rgb((2, 3, 4, 6)).to(device, dtype)
        out = mosaic(rgb, "RGGB")
        assert out.shape == (2, 1, 4, 6) and out.device == rgb.device and out.dtype == dtype

    @pytest.mark.parametrize("pattern", CFA_PATTERNS)
    def test_unit(self, pattern: str) -> None:
        rgb = torch.stack([torch.full((2, 2), v) for v in (1.0, 2.0, 3.0)])
        letters = {1.0: "R", 2.0: "G", 3.0: "B"}
        assert "".join(letters[v] for v in mosaic(rgb, pattern).flatten().tolist()) == pattern

    @pytest.mark.parametrize("pattern", CFA_PATTERNS)
    def test_planes_are_the_colours(self, pattern: str) -> None:
        rgb = _rgb((2, 3, 6, 8))
        planes = split_planes(mosaic(rgb, pattern))
        for i, (c, (dy, dx)) in enumerate(zip(cfa_colours(pattern), ((0, 0), (0, 1), (1, 0), (1, 1)), strict=True)):
            assert torch.equal(planes[:, i], rgb[:, c, dy::2, dx::2])

    @pytest.mark.parametrize("shape", [(3, 2, 2), (1, 3, 4, 6), (2, 5, 3, 8, 4)])
    def test_cardinality(self, shape: tuple[int, ...]) -> None:
        assert mosaic(_rgb(shape), "GBRG").shape == (*shape[:-3], 1, *shape[-2:])

    def test_errors(self) -> None:
        with pytest.raises(ValueError, match=r"rgb must have shape \(\*, 3, H, W\); got \(1, 4, 4, 4\)"):
            mosaic(torch.zeros(1, 4, 4, 4), "RGGB")
        with pytest.raises(ValueError, match=r"even height and width.*got 5 x 4"):
            mosaic(torch.zeros(1, 3, 5, 4), "RGGB")
        with pytest.raises(TypeError, match="rgb must be a torch.Tensor"):
            mosaic("rgb", "RGGB")  # type: ignore[arg-type]

    def test_batched_equals_per_image_and_input_unmodified(self) -> None:
        rgb = _rgb((3, 3, 4, 6))
        before = rgb.clone()
        out = mosaic(rgb, "BGGR")
        assert torch.equal(rgb, before)
        assert torch.equal(out, torch.cat([mosaic(rgb[i : i + 1], "BGGR") for i in range(3)]))
        assert mosaic(rgb[:0], "BGGR").shape == (0, 1, 4, 6)

    def test_module_equals_function(self) -> None:
        rgb = _rgb((2, 3, 4, 4))
        layer = Mosaic("GRBG")
        assert torch.equal(layer(rgb), mosaic(rgb, "GRBG")) and "GRBG" in repr(layer)

    def test_gradcheck(self) -> None:
        rgb = _rgb((1, 3, 4, 4)).requires_grad_()
        assert torch.autograd.gradcheck(lambda x: mosaic(x, "RGGB"), (rgb,))


# --------------------------------------------------------------------------------------------------- demosaicing


class TestDemosaic:
    @pytest.mark.parametrize("method", DEMOSAIC_METHODS)
    @pytest.mark.parametrize(
        "shape",
        # Empty images (H or W 0) give empty results, as mosaic does; they crashed in a reshape before.
        [(1, 2, 2), (1, 1, 4, 6), (2, 3, 1, 8, 10), (0, 1, 4, 4), (1, 1, 0, 0), (2, 1, 0, 4), (1, 6, 0), (0, 1, 0, 0)],
    )
    def test_round_trip_shapes(
        self, shape: tuple[int, ...], method: str, device: torch.device, dtype: torch.dtype
    ) -> None:
        m = _rgb(shape).to(device, dtype)
        rgb = demosaic(m, "RGGB", method)
        assert rgb.shape == (*shape[:-3], 3, *shape[-2:]) and rgb.device == m.device and rgb.dtype == dtype
        assert mosaic(rgb, "RGGB").shape == m.shape

    @pytest.mark.parametrize("method", DEMOSAIC_METHODS)
    @pytest.mark.parametrize("pattern", CFA_PATTERNS)
    def test_photosites_kept_and_flat_colour_exact(self, pattern: str, method: str) -> None:
        m = _rgb((2, 1, 6, 8)).floor()
        assert torch.equal(mosaic(demosaic(m, pattern, method), pattern), m)
        flat = torch.tensor([120.0, 3500.0, 9e6], dtype=torch.float64).view(1, 3, 1, 1).expand(1, 3, 6, 8)
        assert torch.equal(demosaic(mosaic(flat, pattern), pattern, method), flat)

    @pytest.mark.parametrize("method", DEMOSAIC_METHODS)
    @pytest.mark.parametrize("pattern", CFA_PATTERNS)
    def test_linear_ramps_exact_inside(self, pattern: str, method: str) -> None:
        y, x = torch.meshgrid(torch.arange(10.0), torch.arange(12.0), indexing="ij")
        ramp = torch.stack([3 * x + 2 * y + 5, x + 7 * y + 1, 2 * x + y + 9])[None].double() * 1e4  # HDR values
        out = demosaic(mosaic(ramp, pattern), pattern, method)
        torch.testing.assert_close(out[..., 2:-2, 2:-2], ramp[..., 2:-2, 2:-2], rtol=0, atol=1e-6)

    def test_hdr_values_not_clamped(self) -> None:
        m = torch.full((1, 1, 4, 4), 5e7)
        m[..., 1::2, 1::2] = 2.5  # a dark blue behind a bright red and green
        out = demosaic(m, "RGGB")
        assert float(out.max()) == 5e7 and float(out[0, 2].min()) == 2.5

    @pytest.mark.parametrize("pattern", CFA_PATTERNS)
    def test_bilinear_matches_kornia_inside(self, pattern: str) -> None:
        m = _rgb((2, 1, 8, 10), scale=5e5)
        ours = demosaic(m, pattern, "bilinear")
        torch.testing.assert_close(ours[..., 2:-2, 2:-2], raw_to_rgb(m, KORNIA[pattern])[..., 2:-2, 2:-2])

    def test_malvar_never_negative(self) -> None:
        m = torch.zeros(1, 1, 8, 8, dtype=torch.float64)
        m[..., :, 4:] = 1e6  # a very steep edge: the Laplacian term overshoots
        assert float(demosaic(m, "RGGB").min()) == 0.0
        assert float(demosaic(m, "RGGB", "bilinear").min()) == 0.0

    @pytest.mark.parametrize("method", DEMOSAIC_METHODS)
    @pytest.mark.parametrize("pattern", CFA_PATTERNS)
    def test_negative_photosites_kept_exactly(self, pattern: str, method: str) -> None:
        # Regression: "malvar" clamped negative photosite values (dark-subtracted counts, say) to 0, contrary to "the
        # photosites' own values are kept exactly". Both methods keep them, and a flat negative colour comes back.
        m = _rgb((2, 1, 6, 8)).floor() - 40.0
        assert float(m.min()) < 0
        out = demosaic(m, pattern, method)
        assert torch.equal(mosaic(out, pattern), m)
        assert float(out.min()) >= float(m.min())  # nothing below the image's own darkest value
        flat = torch.tensor([-7.0, 3500.0, -0.5], dtype=torch.float64).view(1, 3, 1, 1).expand(1, 3, 6, 8)
        assert torch.equal(demosaic(mosaic(flat, pattern), pattern, method), flat)

    def test_malvar_overshoot_floor_is_per_image(self) -> None:
        # The overshoot stops at 0, or at the image's own darkest value when that is negative: one image's negative
        # values do not lower the floor of another image of the batch.
        m = torch.zeros(2, 1, 8, 8, dtype=torch.float64)
        m[..., :, 4:] = 1e6
        m[1, ..., 0, 0] = -3.0
        out = demosaic(m, "RGGB")
        assert float(out[0].min()) == 0.0 and float(out[1].min()) == -3.0
        assert torch.equal(out[0:1], demosaic(m[0:1], "RGGB"))

    def test_errors(self) -> None:
        with pytest.raises(TypeError, match="counts must be a floating-point tensor"):
            demosaic(torch.zeros(1, 1, 4, 4, dtype=torch.int64), "RGGB")
        with pytest.raises(ValueError, match=r"counts must have shape \(\*, 1, H, W\); got \(1, 3, 4, 4\)"):
            demosaic(torch.zeros(1, 3, 4, 4), "RGGB")
        with pytest.raises(ValueError, match=r"even height and width.*got 4 x 3"):
            demosaic(torch.zeros(1, 1, 4, 3), "RGGB")
        with pytest.raises(ValueError, match="method must be one of 'bilinear', 'malvar'; got 'nearest'"):
            demosaic(torch.zeros(1, 1, 4, 4), "RGGB", "nearest")
        with pytest.raises(ValueError, match="method must be one of .*; got 'ahd'"):
            Demosaic("RGGB", "ahd")

    @pytest.mark.parametrize("method", DEMOSAIC_METHODS)
    def test_batched_equals_per_image_and_input_unmodified(self, method: str) -> None:
        m = _rgb((3, 1, 6, 8))
        before = m.clone()
        out = demosaic(m, "GBRG", method)
        assert torch.equal(m, before)
        assert torch.equal(out, torch.cat([demosaic(m[i : i + 1], "GBRG", method) for i in range(3)]))

    @pytest.mark.parametrize("method", DEMOSAIC_METHODS)
    def test_module_equals_function(self, method: str) -> None:
        m = _rgb((2, 1, 6, 6))
        layer = Demosaic("BGGR", method)
        assert torch.equal(layer(m), demosaic(m, "BGGR", method)) and method in repr(layer)

    @pytest.mark.parametrize("method", DEMOSAIC_METHODS)
    def test_gradcheck(self, method: str) -> None:
        m = (1000.0 + _rgb((1, 1, 6, 6), scale=10.0)).requires_grad_()  # far from 0: no clamping
        assert torch.autograd.gradcheck(lambda x: demosaic(x, "RGGB", method), (m,))


class TestInterpolateWrapped:
    @pytest.mark.parametrize("pattern", CFA_PATTERNS)
    def test_photosites_kept_and_smooth_colours_found(self, pattern: str, device: torch.device) -> None:
        rgb = torch.floor(_smooth_rgb(batch=2)).to(device)
        m = mosaic(rgb, pattern) % 256
        guide = interpolate_wrapped(m, pattern)
        assert guide.shape == rgb.shape and guide.device == m.device and guide.dtype == m.dtype
        assert torch.equal(mosaic(guide, pattern), m)
        assert bool(((guide >= 0) & (guide < 256) & (guide == guide.floor())).all())
        off = torch.remainder(guide - rgb + 128, 256) - 128  # the wrapped error of the interpolated colours
        assert float(off[..., 2:-2, 2:-2].abs().max()) <= 4

    def test_unit_across_a_rollover(self) -> None:
        m = torch.tensor([[[[250.0, 10.0], [12.0, 20.0]]]])  # the greens 266 and 268 wrapped to 10 and 12
        assert interpolate_wrapped(m, "RGGB")[0, :, 0, 0].tolist() == [250.0, 11.0, 20.0]
        m = torch.tensor([[[[100.0, 250.0], [6.0, 20.0]]]])  # greens 250 and 262: they meet at 0, not at 128
        assert interpolate_wrapped(m, "RGGB")[0, 1, 0, 0].tolist() == 0.0

    @pytest.mark.parametrize("shape", [(1, 1, 0, 0), (2, 1, 4, 0), (1, 0, 2), (0, 1, 4, 4)])
    def test_empty_images_and_batches_give_empty_results(self, shape: tuple[int, ...]) -> None:
        out = interpolate_wrapped(torch.zeros(shape), "BGGR", 8)
        assert out.shape == (*shape[:-3], 3, *shape[-2:]) and out.dtype == torch.float32

    def test_batched_equals_per_image(self) -> None:
        m = _rgb((3, 1, 6, 8)).floor() % 256
        out = interpolate_wrapped(m, "GRBG", 8)
        assert torch.equal(out, torch.cat([interpolate_wrapped(m[i : i + 1], "GRBG", 8) for i in range(3)]))

    def test_errors(self) -> None:
        with pytest.raises(ValueError, match=r"\[0, 256\)"):
            interpolate_wrapped(torch.full((1, 1, 2, 2), 256.0), "RGGB", 8)
        with pytest.raises(ValueError, match=r"even height and width.*got 2 x 3"):
            interpolate_wrapped(torch.zeros(1, 1, 2, 3), "RGGB")
        with pytest.raises(TypeError, match="modulus must be a floating-point tensor"):
            interpolate_wrapped(torch.zeros(1, 1, 2, 2, dtype=torch.int32), "RGGB")
        with pytest.raises(ValueError, match="cfa must be one of .*; got 'GGRB'"):
            interpolate_wrapped(torch.zeros(1, 1, 2, 2), "GGRB")


# ------------------------------------------------------------------------------------------------------ capture


class TestSimulated:
    @pytest.mark.parametrize("pattern", CFA_PATTERNS)
    def test_noise_free_is_the_mosaic_captured(self, pattern: str, device: torch.device) -> None:
        rgb = _rgb((2, 3, 6, 8), scale=3000.0).to(device, torch.float32)
        frames = simulate_capture(rgb, [1.0, 8.0], 8, None, cfa=pattern)
        assert frames.shape == (2, 2, 1, 6, 8) and frames.device == rgb.device
        for i, tau in enumerate((1.0, 8.0)):
            assert torch.equal(frames[:, i], tm.capture_modulo(mosaic(rgb, pattern), tau, 8))
        clipped = simulate_capture(rgb, [1.0, 8.0], 8, None, wrap=False, cfa=pattern)
        assert torch.equal(clipped[:, 1], tm.capture_intensity(mosaic(rgb, pattern), 8.0, 8))

    def test_noise_per_photosite(self) -> None:
        rgb = _rgb((1, 3, 16, 16), scale=2000.0)
        noise = NoiseModel(read_noise=2.0, prnu=0.01)
        draw = lambda: torch.Generator().manual_seed(7)  # noqa: E731
        gain = torch.ones(1, 16, 16, dtype=torch.float64) * 1.01
        ours = simulate_capture(rgb, [1.0, 4.0], 8, noise, generator=draw(), gain=gain, cfa="GRBG")
        same = simulate_capture(mosaic(rgb, "GRBG"), [1.0, 4.0], 8, noise, generator=draw(), gain=gain)
        assert torch.equal(ours, same)  # mosaic first, then the same draws per photosite
        # flat grey light: the photosites of one 2 x 2 cell see independent noise
        flat = simulate_capture(torch.full((3, 64, 64), 5000.0), [1.0], 16, NoiseModel(), cfa="RGGB")
        planes = split_planes(flat[0])
        assert not torch.equal(planes[0], planes[3]) and not torch.equal(planes[1], planes[2])
        assert abs(float(planes.var()) - 5000.0) < 500.0  # Poisson: variance = mean, per photosite

    @pytest.mark.parametrize("sensor_type", [SimulatedModuloSensor, SimulatedIntensitySensor])
    def test_sensor_records_the_pattern(self, sensor_type: type) -> None:
        rgb = _rgb((2, 3, 8, 8), scale=3000.0).float()
        sensor = sensor_type(bits=8, noise=NoiseModel(prnu=0.02), seed=3, cfa="BGGR")
        stack = sensor(rgb, [1.0, 16.0])
        assert stack.shape == (2, 2, 1, 8, 8) and stack.cfa == "BGGR" and stack.metadata["cfa"] == "BGGR"
        assert "cfa='BGGR'" in repr(sensor) and "cfa='BGGR'" in repr(stack)
        plain = sensor_type(bits=8, noise=NoiseModel(prnu=0.02), seed=3)(mosaic(rgb, "BGGR"), [1.0, 16.0])
        assert torch.equal(stack.moduli, plain.moduli)  # gain and noise per photosite, same draws
        assert plain.cfa is None and "cfa" not in plain.metadata
        # one gain per photosite of the mosaic, (1, H, W), drawn from the sensor's fpn_seed (seed + 1)
        gain = sensor.gain_map((1, 8, 8), "cpu", torch.float32)
        assert sensor.fpn_seed == 4
        assert torch.equal(gain, fixed_pattern_gain((1, 8, 8), 0.02, seed=4))
        assert float((gain - 1).abs().max()) > 0  # a pattern, not a flat gain
        wrap = sensor_type is SimulatedModuloSensor
        draws = sensor.manual_seed(3).generator("cpu")  # the capture again, by hand: that gain, the same draws
        again = simulate_capture(
            mosaic(rgb, "BGGR"), [1.0, 16.0], 8, sensor.noise, wrap=wrap, generator=draws, gain=gain
        )
        assert torch.equal(stack.frames, again)

    def test_unbatched(self) -> None:
        stack = SimulatedModuloSensor(noise=None, cfa="RGGB")(_rgb((3, 4, 6)).float(), [1.0, 4.0])
        assert stack.shape == (1, 2, 1, 4, 6)
        assert simulate_capture(_rgb((3, 4, 6)).float(), [1.0, 4.0], cfa="RGGB").shape == (2, 1, 4, 6)

    def test_errors(self) -> None:
        with pytest.raises(ValueError, match=r"radiance must be RGB.*cfa='RGGB'.*got shape \(1, 1, 4, 4\)"):
            simulate_capture(torch.ones(1, 1, 4, 4), [1.0], cfa="RGGB")
        with pytest.raises(ValueError, match=r"radiance must be RGB.*got shape \(1, 4, 4, 4\)"):
            SimulatedModuloSensor(cfa="RGGB")(torch.ones(1, 4, 4, 4), [1.0])
        with pytest.raises(ValueError, match=r"even height and width.*got 5 x 4"):
            simulate_capture(torch.ones(1, 3, 5, 4), [1.0], cfa="RGGB")
        with pytest.raises(ValueError, match="cfa must be one of .*; got 'RGBW'"):
            SimulatedIntensitySensor(cfa="RGBW")


# ---------------------------------------------------------------------------------------------- frames and files


class TestFrameStack:
    def test_field_and_metadata(self) -> None:
        moduli = torch.zeros(2, 3, 1, 4, 6)
        stack = FrameStack(moduli, [1.0, 2.0, 4.0], 8, {"scene": "x"}, cfa="GBRG")
        assert stack.cfa == "GBRG" and stack.metadata == {"scene": "x", "cfa": "GBRG"}
        assert FrameStack(moduli, [1.0, 2.0, 4.0], 8, {"cfa": "GBRG"}).cfa == "GBRG"  # from the metadata
        assert FrameStack(moduli, [1.0, 2.0, 4.0], 8).cfa is None
        assert stack[1].cfa == "GBRG" and stack.to(dtype=torch.float64).cfa == "GBRG"
        assert stack != FrameStack(moduli, [1.0, 2.0, 4.0], 8, {"scene": "x"}, cfa="RGGB")

    def test_errors(self) -> None:
        with pytest.raises(ValueError, match=r"one channel and an even height and width.*got shape \(1, 1, 3, 4, 4\)"):
            FrameStack(torch.zeros(1, 1, 3, 4, 4), [1.0], 8, cfa="RGGB")
        with pytest.raises(ValueError, match=r"got shape \(1, 1, 1, 4, 5\)"):
            FrameStack(torch.zeros(1, 1, 1, 4, 5), [1.0], 8, cfa="RGGB")
        with pytest.raises(ValueError, match="cfa='RGGB' disagrees with the metadata's cfa 'BGGR'"):
            FrameStack(torch.zeros(1, 1, 1, 4, 4), [1.0], 8, {"cfa": "BGGR"}, cfa="RGGB")
        with pytest.raises(ValueError, match=r"metadata\['cfa'\] must be one of .*; got 'rgb'"):
            FrameStack(torch.zeros(1, 1, 1, 4, 4), [1.0], 8, {"cfa": "rgb"})


class TestFiles:
    @pytest.mark.parametrize("fmt", ["exr", "png", "tiff"])
    def test_write_then_read_keeps_the_pattern(self, tmp_path: Path, fmt: str) -> None:
        stack = SimulatedModuloSensor(bits=8, seed=1, cfa="GRBG")(_rgb((2, 3, 6, 8), scale=3000.0).float(), [1.0, 16.0])
        write_frames(stack, tmp_path, format=fmt)
        manifest = json.loads((tmp_path / MANIFEST).read_text())
        assert manifest["cfa"] == "GRBG"
        back = FileSensor(tmp_path).read()
        assert back == stack and back.cfa == "GRBG"
        # without the manifest the frames' own metadata still names the pattern
        (tmp_path / MANIFEST).unlink()
        assert FileSensor(sorted(tmp_path.glob("frame_b000_*"))).read().cfa == "GRBG"

    def test_hand_written_manifest_and_argument(self, tmp_path: Path) -> None:
        stack = FrameStack(torch.zeros(1, 2, 1, 4, 4), [1.0, 8.0], 8)
        write_frames(stack, tmp_path, format="png")
        manifest = json.loads((tmp_path / MANIFEST).read_text())
        assert "cfa" not in manifest and FileSensor(tmp_path).read().cfa is None
        manifest["cfa"] = "BGGR"
        (tmp_path / MANIFEST).write_text(json.dumps(manifest))
        assert FileSensor(tmp_path).read().cfa == "BGGR"
        assert FileSensor(tmp_path, cfa="RGGB").read().cfa == "RGGB"  # the argument wins
        manifest["cfa"] = "RGBG"
        (tmp_path / MANIFEST).write_text(json.dumps(manifest))
        with pytest.raises(ValueError, match=r"frames.json: cfa must be one of .*; got 'RGBG'"):
            FileSensor(tmp_path)
        manifest["cfa"], manifest["metadata"] = "RGGB", {"cfa": "BGGR"}
        (tmp_path / MANIFEST).write_text(json.dumps(manifest))
        with pytest.raises(ValueError, match="cfa 'RGGB' disagrees with the metadata's cfa 'BGGR'"):
            FileSensor(tmp_path)

    def test_errors(self, tmp_path: Path) -> None:
        with pytest.raises(ValueError, match="cfa must be one of .*; got 'rggb'"):
            FileSensor(tmp_path, cfa="rggb")
        write_frames(FrameStack(torch.zeros(1, 1, 3, 4, 4), [1.0], 8), tmp_path / "rgb", format="png")
        with pytest.raises(ValueError, match=r"not mosaics.*cfa='RGGB'.*\(3, 4, 4\)"):
            FileSensor(tmp_path / "rgb", cfa="RGGB").read()
        for name, pattern in (("a", "RGGB"), ("b", "BGGR")):
            write_frames(FrameStack(torch.zeros(1, 1, 1, 4, 4), [1.0], 8, cfa=pattern), tmp_path / name, format="png")
        files = [tmp_path / "a" / "frame_b000_m00.png", tmp_path / "b" / "frame_b000_m00.png"]
        with pytest.raises(ValueError, match="has cfa='BGGR' but .* has cfa='RGGB'"):
            FileSensor(files).read()


# ---------------------------------------------------------------------------------------------------- unwrapping


class TestUnwrapSingle:
    @pytest.mark.parametrize("pattern", CFA_PATTERNS)
    def test_exact_on_smooth_mosaic(self, pattern: str) -> None:
        truth = torch.floor(mosaic(_smooth_rgb(), pattern))
        assert float(truth.max()) > 8 * 256  # many rollovers
        restored = tm.unwrap_single(truth % 256, 8, cfa=pattern, workers=1)
        assert torch.equal(restored, truth)
        # the naive way, the mosaic as one grey image, fails: neighbours see different colours
        naive = tm.unwrap_single(truth % 256, 8, workers=1)
        assert float((naive == truth).double().mean()) < 0.5

    def test_demosaiced_result_is_the_scene(self) -> None:
        rgb = torch.floor(_smooth_rgb())
        restored = tm.unwrap_single(mosaic(rgb, "RGGB") % 256, 8, cfa="RGGB", workers=1)
        out = demosaic(restored, "RGGB")
        err = (out - rgb)[..., 2:-2, 2:-2].abs() / rgb[..., 2:-2, 2:-2]
        assert float(err.max()) < 0.02

    def test_batched_equals_per_image(self) -> None:
        truth = torch.floor(mosaic(_smooth_rgb(batch=3), "BGGR"))
        modulus = truth % 256
        batched = tm.unwrap_single(modulus, 8, cfa="BGGR", workers=1)
        per_image = torch.cat([tm.unwrap_single(modulus[i : i + 1], 8, cfa="BGGR", workers=1) for i in range(3)])
        assert torch.equal(batched, per_image) and torch.equal(batched, truth)
        empty = tm.unwrap_single(modulus[:0], 8, cfa="BGGR", workers=1)
        assert empty.shape == (0, 1, 32, 48)

    def test_unbatched_shapes_and_info(self, device: torch.device, dtype: torch.dtype) -> None:
        truth = torch.floor(mosaic(_smooth_rgb(), "GBRG"))[0].to(device, dtype)
        out3 = tm.unwrap_single(truth % 256, 8, cfa="GBRG", workers=1)
        out2, info = tm.unwrap_single(truth[0] % 256, 8, cfa="GBRG", workers=1, return_info=True)
        assert out3.shape == (1, 32, 48) and out2.shape == (32, 48)
        assert out3.device == truth.device and out3.dtype == dtype
        assert torch.equal(out3, truth) and torch.equal(out2, truth[0])
        assert info.iterations.shape == (1, 3)  # one entry per colour

    def test_module_equals_function(self) -> None:
        modulus = torch.floor(mosaic(_smooth_rgb(batch=2), "GRBG")) % 256
        layer = tm.SingleShotUnwrap(8, cfa="GRBG", workers=1)
        assert layer.cfa == "GRBG"
        assert torch.equal(layer(modulus), tm.unwrap_single(modulus, 8, cfa="GRBG", workers=1))

    def test_errors(self) -> None:
        with pytest.raises(ValueError, match=r"modulus must be a mosaic with cfa='RGGB'.*got \(1, 3, 4, 4\)"):
            tm.unwrap_single(torch.zeros(1, 3, 4, 4), 8, cfa="RGGB", workers=1)
        with pytest.raises(ValueError, match=r"even height and width.*got 4 x 5"):
            tm.unwrap_single(torch.zeros(1, 1, 4, 5), 8, cfa="RGGB", workers=1)
        with pytest.raises(ValueError, match="cfa must be one of .*; got 'RGB'"):
            tm.unwrap_single(torch.zeros(1, 1, 4, 4), 8, cfa="RGB", workers=1)
        with pytest.raises(ValueError, match=r"\[0, 256\)"):
            tm.unwrap_single(torch.full((1, 1, 4, 4), 300.0), 8, cfa="RGGB", workers=1)


class TestWholePath:
    def test_simulate_write_read_unwrap_multi_demosaic(self, tmp_path: Path) -> None:
        rgb = _smooth_rgb(batch=2, dtype=torch.float32) * 40  # counts up to about 1e5 at tau = 1
        taus = [1 / 1024, 1 / 64, 1 / 4, 1.0]
        stack = SimulatedModuloSensor(bits=8, noise=None, cfa="RGGB")(rgb, taus)
        write_frames(stack, tmp_path, format="png")
        back = FileSensor(tmp_path).read()
        assert back == stack and back.cfa == "RGGB"
        radiance = tm.unwrap_multi(back.moduli, back.exposures, back.bits)  # per pixel: mosaics as they are
        assert radiance.shape == (2, 1, 32, 48)
        counts = torch.floor(mosaic(rgb, back.cfa))
        torch.testing.assert_close(torch.floor(radiance), counts, rtol=0, atol=0)
        colour = demosaic(radiance, back.cfa)
        err = (colour - rgb)[..., 2:-2, 2:-2].abs() / rgb[..., 2:-2, 2:-2]
        assert colour.shape == rgb.shape and float(err.max()) < 0.02
        shown = tm.tonemap_reinhard(colour)
        assert shown.shape == rgb.shape and bool(torch.isfinite(shown).all())

    def test_single_shot_path_through_files(self, tmp_path: Path) -> None:
        rgb = torch.floor(_smooth_rgb(dtype=torch.float32))
        stack = SimulatedModuloSensor(bits=8, noise=None, cfa="BGGR")(rgb, [1.0])
        write_frames(stack, tmp_path)
        back = FileSensor(tmp_path).read()
        restored = tm.unwrap_single(back.moduli[:, 0], back.bits, cfa=back.cfa, workers=1)
        assert torch.equal(restored, mosaic(rgb, "BGGR"))
        assert math.isfinite(float(demosaic(restored, back.cfa).sum()))
