"""Tests for torch_modulo/multishot/spatial.py: spatial evidence in noise-aware decoding and its plans."""

from __future__ import annotations

import math
import warnings

import pytest
import torch

import torch_modulo as tm
from torch_modulo.multishot import noisy
from torch_modulo.multishot.noisy import decode_noisy
from torch_modulo.multishot.planning import _noisy_plan, _spatial_min_ratio
from torch_modulo.multishot.spatial import neighbour_prediction, settle_counts
from torch_modulo.sensors import NoiseModel, SimulatedIntensitySensor, SimulatedModuloSensor

PHOTON = NoiseModel()
Q16 = NoiseModel.preset("q16")


def _plan_default(stops: float, noise: NoiseModel) -> list[float]:
    plan = tm.plan_exposures(stops, 8, noise=noise)
    return [t / plan[-1] for t in plan]


def _plan(stops: float, noise: NoiseModel, spatial: bool) -> list[float]:
    plan = tm.plan_exposures(stops, 8, noise=noise, spatial=spatial)
    return [t / plan[-1] for t in plan]


def _smooth_scene(stops: float, size: int = 48, seed: int = 0) -> torch.Tensor:
    """(1, 3, size, size) radiance: smooth blobs over a log ramp, from 16 counts at exposure 1 up over ``stops - 4``
    stops, with a sharp step down the middle (an edge)."""
    gen = torch.Generator().manual_seed(seed)
    y, x = torch.meshgrid(
        torch.linspace(0, 1, size, dtype=torch.float64), torch.linspace(0, 1, size, dtype=torch.float64), indexing="ij"
    )
    level = (x + y) / 2
    for _ in range(4):
        cy, cx, width = torch.rand(3, generator=gen, dtype=torch.float64)
        level = level + 0.3 * torch.exp(-((y - cy) ** 2 + (x - cx) ** 2) / (0.02 + 0.05 * width))
    level = (level - level.min()) / (level.max() - level.min())
    level = torch.where(x > 0.5, level, 0.7 * level)  # an edge
    channels = torch.stack([level, level * 0.9, level * 0.8])
    return torch.exp2(4 + channels * (stops - 4)).unsqueeze(0)


def _rel(estimate: torch.Tensor, radiance: torch.Tensor) -> torch.Tensor:
    return (estimate - radiance).abs() / radiance


def _decode(moduli: torch.Tensor, taus: list[float], noise: NoiseModel, spatial: bool) -> torch.Tensor:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return tm.unwrap_multi(moduli, taus, 8, noise=noise, spatial=spatial)


class TestNeighbourPrediction:
    def test_flat_field_averages_the_window(self) -> None:
        estimate = torch.full((1, 25), 10.0)
        estimate[0, 12] = 11.0  # within noise of its neighbours
        mean, variance = neighbour_prediction(estimate, torch.ones(1, 25), (5, 5))
        assert float(mean[0, 12]) == pytest.approx(10 + 1 / 9)  # the whole 3 x 3 window
        assert float(variance[0, 12]) == pytest.approx(1 / 9)
        assert float(variance[0, 0]) == 1.0  # a corner has no pair of opposite neighbours
        assert float(variance[0, 2]) == pytest.approx(1 / 3)  # a border pixel has the pair along the border

    def test_slopes_are_predicted_exactly(self) -> None:
        # A linear slope within the noise: each pair's mean is the pixel's value.
        y, x = torch.meshgrid(torch.arange(6.0), torch.arange(7.0), indexing="ij")
        estimate = (100 + 0.3 * x - 0.2 * y).reshape(1, -1)
        mean, variance = neighbour_prediction(estimate, torch.ones(1, 42), (6, 7))
        torch.testing.assert_close(mean, estimate)
        assert float(variance.reshape(6, 7)[2, 3]) == pytest.approx(1 / 9)

    def test_disagreeing_neighbours_are_left_out(self) -> None:
        # Across an edge (or a wrong rollover count) the estimates differ by more than their noise: the pixel keeps
        # its own prediction.
        estimate = torch.tensor([[0.0, 0.0, 100.0, 100.0]])
        mean, variance = neighbour_prediction(estimate, torch.ones(1, 4), (1, 4))
        assert torch.equal(mean, torch.tensor([[0.0, 0.0, 100.0, 100.0]]))
        assert torch.equal(variance, torch.ones(1, 4))

    def test_planes_are_separate(self) -> None:
        estimate = torch.tensor([[1.0, 1.0, 5.0, 5.0]])  # two 1 x 2 planes
        mean, _ = neighbour_prediction(estimate, torch.full((1, 4), 100.0), (1, 2))
        assert torch.equal(mean, estimate)

    @pytest.mark.parametrize("bad", [math.inf, math.nan])
    def test_a_non_finite_estimate_is_no_neighbour(self, bad: float) -> None:
        # An estimate beyond the work dtype's range fails every agreement test: its neighbours are predicted from
        # their other pairs (exact on this slope), finite, as if it were beyond the border.
        y, x = torch.meshgrid(torch.arange(6.0), torch.arange(7.0), indexing="ij")
        estimate = (100 + 0.3 * x - 0.2 * y).reshape(1, -1)
        broken = estimate.clone()
        broken[0, 2 * 7 + 3] = bad
        mean, variance = neighbour_prediction(broken, torch.ones(1, 42), (6, 7))
        others = torch.ones(1, 42, dtype=torch.bool)
        others[0, 2 * 7 + 3] = False
        torch.testing.assert_close(mean[others], estimate[others])
        assert float(variance.reshape(6, 7)[2, 4]) == pytest.approx(1 / 7)  # three of its four pairs
        assert float(variance.reshape(6, 7)[3, 3]) == pytest.approx(1 / 7)


class TestSpatialDecoding:
    def test_noise_free_frames_decode_exactly(self) -> None:
        # Noise-free frames of a spatial plan (ratios far beyond what a pixel alone decodes under q16), decoded with a
        # quiet model: every rollover count right, the counts exact to a count, as the per-pixel decoder's on the
        # ratios it can follow.
        quiet = NoiseModel(read_noise=0.1, shot_noise=False)
        radiance = _smooth_scene(16)
        taus = _plan(16, Q16, spatial=True)
        moduli = SimulatedModuloSensor(8, None)(radiance, taus).moduli
        counts = tm.unwrap_multi(moduli, taus, 8, noise=quiet, return_counts=True)
        assert float((counts - torch.floor(radiance * taus[-1]) - 0.5).abs().max()) <= 1.0
        alone = tm.unwrap_multi(moduli, taus, 8, noise=quiet, return_counts=True, spatial=False)
        assert torch.equal(counts, alone)

    def test_noise_free_frames_with_a_noise_model_are_decoded_right(self) -> None:
        # With the q16 model the bright pixels stop at their physical limit, and pixels on steep, curved slopes
        # (no agreeing pair of neighbours) where a pixel alone cannot follow the ratio; but no decoded frame has a
        # wrong count, which would leave a pixel far more off than the one-count step of its shortest frame.
        radiance = _smooth_scene(16)
        taus = _plan(16, Q16, spatial=True)
        moduli = SimulatedModuloSensor(8, None)(radiance, taus).moduli
        error = _rel(_decode(moduli, taus, Q16, spatial=True), radiance)
        assert bool(((error <= 1 / (radiance * taus[0])) | (error < 0.04)).all())  # 0.04: the darkest read 16 counts

    def test_without_noise_spatial_changes_nothing(self) -> None:
        radiance = _smooth_scene(16) / 2**8
        taus = [1.0, 100.0, 10000.0]
        moduli = SimulatedModuloSensor(8, None)(radiance, taus).moduli
        plain = tm.unwrap_multi(moduli, taus, 8)
        assert torch.equal(tm.unwrap_multi(moduli, taus, 8, spatial=True), plain)
        assert torch.equal(tm.unwrap_multi(moduli, taus, 8, spatial=False), plain)

    @pytest.mark.parametrize("noise", [PHOTON, Q16], ids=["q1", "q16"])
    def test_texture_never_decodes_worse_than_per_pixel(self, noise: NoiseModel) -> None:
        # Every pixel drawn independently over 12 stops (texture everywhere): on the per-pixel plan, the neighbours
        # rarely agree, and the spatial decode is no worse than the per-pixel one.
        gen = torch.Generator().manual_seed(1)
        radiance = torch.exp2(4 + 12 * torch.rand((1, 3, 40, 40), generator=gen, dtype=torch.float64))
        taus = _plan(16, noise, spatial=False)
        moduli = SimulatedModuloSensor(8, noise, seed=2)(radiance, taus).moduli
        spatial = _rel(_decode(moduli, taus, noise, spatial=True), radiance)
        alone = _rel(_decode(moduli, taus, noise, spatial=False), radiance)
        assert float((spatial > 0.5).double().mean()) <= float((alone > 0.5).double().mean())
        assert float(spatial.median()) <= float(alone.median()) * 1.01
        assert float(torch.quantile(spatial.float(), 0.99)) <= float(torch.quantile(alone.float(), 0.99)) * 1.05

    @pytest.mark.parametrize("noise", [PHOTON, Q16], ids=["q1", "q16"])
    def test_spatial_plan_meets_the_oracle_with_fewer_frames(self, noise: NoiseModel) -> None:
        # A protocol-N-like check on a smooth scene with an edge: the spatial plan has far fewer frames, and its
        # decode stays within the targets against the oracle (the longest frame with its true rollover count).
        stops = 18
        radiance = _smooth_scene(stops, size=64, seed=3)
        taus = _plan(stops, noise, spatial=True)
        assert len(taus) * 1.5 < len(_plan(stops, noise, spatial=False))
        moduli = SimulatedModuloSensor(8, noise, seed=4)(radiance, taus).moduli
        oracle = _rel(SimulatedIntensitySensor(53, noise, seed=4)(radiance, taus).frames[:, -1] / taus[-1], radiance)
        decoded = _rel(_decode(moduli, taus, noise, spatial=True), radiance)
        assert float((decoded > 0.5).double().mean()) <= float((oracle > 0.5).double().mean()) + 1e-3
        assert float(decoded.median()) <= 1.5 * float(oracle.median())
        # The per-pixel decoder cannot follow the spatial plan's ratios.
        alone = _rel(_decode(moduli, taus, noise, spatial=False), radiance)
        assert float(alone.median()) > float(decoded.median())

    def test_bands_decode_as_the_whole_plane(self, monkeypatch: pytest.MonkeyPatch) -> None:
        # On the CPU planes are decoded band by band of rows with context; the result is the whole plane's (the
        # whole-tensor path, taken on other devices and under torch.compile).
        radiance = _smooth_scene(16, size=40)[:, :2].repeat_interleave(18, dim=2)  # 720 x 40
        radiance = torch.cat([radiance] * 10, dim=-1)  # 720 x 400: bands of 655 rows
        taus = _plan(16, Q16, spatial=True)
        moduli = SimulatedModuloSensor(8, Q16, seed=8)(radiance, taus).moduli
        b, m = moduli.shape[:2]
        flat = moduli.reshape(b, m, -1).float()
        tau = torch.tensor([taus], dtype=torch.float64)
        banded = decode_noisy(flat, tau, 8, Q16, shape=(720, 400))
        monkeypatch.setattr(noisy, "chunk_on_cpu", lambda *tensors: False)
        whole = decode_noisy(flat, tau, 8, Q16, shape=(720, 400))
        for a, w in zip(banded, whole, strict=True):
            torch.testing.assert_close(a, w, rtol=1e-6, atol=0.0)

    def test_no_gradient_reaches_the_frames(self) -> None:
        # The decoder works in place; it detaches the frames rather than fail in backward.
        taus = _plan(12, Q16, spatial=True)
        moduli = SimulatedModuloSensor(8, Q16, seed=2)(_smooth_scene(12, size=16), taus).moduli
        flat = moduli.reshape(1, len(taus), -1).float().requires_grad_()
        for shape in (None, (16, 16)):
            out = decode_noisy(flat, torch.tensor([taus], dtype=torch.float64), 8, Q16, shape=shape)
            assert not any(t.requires_grad for t in out)

    def test_module_and_function_agree(self) -> None:
        radiance = _smooth_scene(14, size=24)
        taus = _plan(14, Q16, spatial=True)
        moduli = SimulatedModuloSensor(8, Q16, seed=5)(radiance, taus).moduli
        layer = tm.MultiExposureUnwrap(bits=8, noise=Q16, spatial=False)
        assert torch.equal(layer(moduli, taus), _decode(moduli, taus, Q16, spatial=False))
        assert torch.equal(tm.MultiExposureUnwrap(bits=8, noise=Q16)(moduli, taus), _decode(moduli, taus, Q16, True))
        assert "spatial=False" in repr(layer)

    def test_defaults_decode_and_plan_with_spatial_evidence(self) -> None:
        radiance = _smooth_scene(14, size=24)
        taus = _plan(14, Q16, spatial=True)
        assert taus == _plan_default(14, Q16)
        assert len(taus) < len(_plan(14, Q16, spatial=False))  # larger ratios: fewer frames
        moduli = SimulatedModuloSensor(8, Q16, seed=5)(radiance, taus).moduli
        assert torch.equal(tm.unwrap_multi(moduli, taus, 8, noise=Q16), _decode(moduli, taus, Q16, spatial=True))
        assert not torch.equal(_decode(moduli, taus, Q16, spatial=True), _decode(moduli, taus, Q16, spatial=False))

    def test_spatial_plans_warn_only_without_neighbours(self) -> None:
        taus = _plan(18, PHOTON, spatial=True)
        radiance = _smooth_scene(18, size=8)
        moduli = SimulatedModuloSensor(8, PHOTON, seed=6)(radiance, taus).moduli
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            tm.unwrap_multi(moduli, taus, 8, noise=PHOTON)  # the default decodes with spatial evidence
        with pytest.warns(UserWarning, match=r"is unsafe .* \(or decode with spatial=True, for which these ratios"):
            tm.unwrap_multi(moduli, taus, 8, noise=PHOTON, spatial=False)
        with pytest.warns(UserWarning, match=r"is unsafe .* \(an image narrower than 3 pixels has no 2-D neighbour"):
            tm.unwrap_multi(moduli[..., :1, :], taus, 8, noise=PHOTON)  # a single row

    def test_bad_input(self) -> None:
        moduli = torch.zeros(2, 1, 4, 4)
        with pytest.raises(TypeError, match="spatial must be a bool"):
            tm.unwrap_multi(moduli, [1.0, 2.0], 8, noise=Q16, spatial="no")  # type: ignore[call-overload]
        with pytest.raises(TypeError, match="spatial must be a bool"):
            tm.MultiExposureUnwrap(noise=Q16, spatial=1)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="whole image planes"):
            decode_noisy(torch.zeros(1, 2, 10), torch.tensor([[1.0, 2.0]]), 8, Q16, shape=(3, 3))


class TestSettling:
    @staticmethod
    def _frame() -> tuple[torch.Tensor, ...]:
        # A smooth ramp of counts (40 to 74 periods) and its moduli; predictions that err smoothly (as neighbours'
        # shared estimates do), by a bump of 0.6 of a period at (3, 3) and 0.36 at its 4-neighbours. Where the error
        # passes 0.3 of a period the pixels are candidates (at the bump's top the nearest count is a period high);
        # the others are decided, right.
        period = 256.0
        y, x = torch.meshgrid(torch.arange(8.0), torch.arange(8.0), indexing="ij")
        counts = 10240.0 + 900.0 * x + 350.0 * y + 0.3  # steps of 3.5 and 1.4 periods between neighbours
        half = torch.remainder(counts, period) + 0.5
        error = 0.6 * period * torch.exp(-((y - 3.0) ** 2 + (x - 3.0) ** 2) / 2.0)
        expected = counts + 0.5 + error
        nearest = ((expected - half) / period).round().clamp_min(0.0)
        spread = torch.full((8, 8), (period / 2) ** 2)  # a prediction as loose as half a period
        own = torch.full((8, 8), 40.0**2)
        block = error > 0.3 * period
        flat = [v.reshape(1, 64) for v in (half, nearest, expected, spread, own)]
        decided, candidates = (~block).double().reshape(1, 64), block.double().reshape(1, 64)
        return (*flat, decided, candidates, counts.reshape(1, 64))

    def test_candidates_take_the_count_their_neighbours_pin(self) -> None:
        half, nearest, expected, spread, own, decided, candidates, counts = self._frame()
        truth = ((counts + 0.5 - half) / 256.0).round()
        assert int((nearest != truth).sum()) == 1  # alone, the bump's top would be a period high
        settled = settle_counts(half, nearest, expected, spread, own, decided, candidates, (8, 8), 256.0)
        assert torch.equal(settled, truth)

    def test_a_candidate_without_neighbours_keeps_its_nearest_count(self) -> None:
        half, nearest, expected, spread, own, _, _, _ = self._frame()
        alone = torch.zeros_like(half)
        alone[0, 3 * 8 + 3] = 1.0
        settled = settle_counts(half, nearest, expected, spread, own, torch.zeros_like(half), alone, (8, 8), 256.0)
        assert torch.equal(settled, nearest)
        # and nothing to settle returns the counts as they were
        none = torch.zeros_like(half)
        assert settle_counts(half, nearest, expected, spread, own, none, none, (8, 8), 256.0) is nearest

    def test_the_candidates_alone_settle_as_the_whole_planes(self, monkeypatch: pytest.MonkeyPatch) -> None:
        # Eager, the step works on the gathered candidates; under torch.compile on whole planes: the same counts.
        gen = torch.Generator().manual_seed(3)
        shape = (2, 9, 11)
        counts = 5000.0 + 400.0 * torch.rand(shape, generator=gen).cumsum(-1)
        half = torch.remainder(counts, 256.0) + 0.5
        expected = counts + 0.5 + 200.0 * torch.randn(shape, generator=gen)
        nearest = ((expected - half) / 256.0).round().clamp_min(0.0)
        spread = torch.full(shape, 150.0**2)
        own = counts / 16.0
        draw = torch.rand(shape, generator=gen)
        decided, candidates = (draw < 0.5).float(), ((draw >= 0.5) & (draw < 0.9)).float()
        args = [v.reshape(1, -1) for v in (half, nearest, expected, spread, own, decided, candidates)]
        sparse = settle_counts(*args, (9, 11), 256.0, row0=1)
        assert not torch.equal(sparse, args[1])  # some counts move
        monkeypatch.setattr(torch.compiler, "is_compiling", lambda: True)
        assert torch.equal(settle_counts(*args, (9, 11), 256.0, row0=1), sparse)

    @pytest.mark.parametrize("noise", [PHOTON, Q16], ids=["q1", "q16"])
    def test_settling_follows_bright_pixels_up_large_ratios(
        self, monkeypatch: pytest.MonkeyPatch, noise: NoiseModel
    ) -> None:
        # The default spatial plan of a smooth scene: its bright pixels fail the prediction's gate at the larger
        # ratios; settled against the frames' own differences they decode more frames, and end more precise,
        # without a gross error more.
        stops = 20
        radiance = _smooth_scene(stops, size=64, seed=6)
        taus = _plan(stops, noise, spatial=True)
        moduli = SimulatedModuloSensor(8, noise, seed=7)(radiance, taus).moduli
        flat = moduli.reshape(1, len(taus), -1).double()
        tau = torch.tensor([taus], dtype=torch.float64)
        estimate, _, used = decode_noisy(flat, tau, 8, noise, shape=(3 * 64, 64))
        monkeypatch.setattr(noisy, "SETTLE_GATE", 0.0)
        unsettled, _, used_before = decode_noisy(flat, tau, 8, noise, shape=(3 * 64, 64))
        truth = radiance.reshape(1, -1)
        bright = truth > torch.quantile(truth, 2 / 3)
        assert float(used[bright].mean()) > float(used_before[bright].mean())
        error, before = _rel(estimate, truth), _rel(unsettled, truth)
        assert float(error[bright].median()) < 0.9 * float(before[bright].median())
        assert float((error > 0.5).double().mean()) <= float((before > 0.5).double().mean())


class TestSpatialPlans:
    def test_min_ratio_keeps_the_limit_precision(self) -> None:
        # Settled against the frame's own differences, a pixel decodes up to the whole gate whatever the ratio, so
        # the ratio that keeps a pixel at its limit within 1.18 times the per-pixel plan's precision is about 5.1.
        assert 4.5 < _spatial_min_ratio(1.5, 255.0) < 6.0
        assert _spatial_min_ratio(2.0, 255.0) > _spatial_min_ratio(1.5, 255.0)

    @pytest.mark.parametrize("noise", [PHOTON, Q16, NoiseModel.preset("dfpa")], ids=["q1", "q16", "dfpa"])
    @pytest.mark.parametrize("stops", [10, 16, 24])
    def test_fewer_frames_larger_ratios(self, noise: NoiseModel, stops: float) -> None:
        spatial = _plan(stops, noise, spatial=True)
        alone = _plan(stops, noise, spatial=False)
        assert len(spatial) <= len(alone)
        ratios = [b / a for a, b in zip(spatial, spatial[1:], strict=False)]
        assert all(r >= _spatial_min_ratio(1.5, 255.0) * (1 - 1e-9) for r in ratios)
        # The same scene: the same shortest exposure (from 1) and at least the same longest.
        absolute = _noisy_plan(stops, 8, 1.0, 255.0, noise, 3.0, 1.2, 1.5, noise, spatial=True)
        reference = _noisy_plan(stops, 8, 1.0, 255.0, noise, 3.0, 1.2, 1.5, noise)
        assert absolute is not None and reference is not None
        assert absolute[0] == reference[0] == 1.0 and absolute[-1] >= reference[-1] * (1 - 1e-9)


class TestMosaics:
    """``cfa=``: with spatial evidence a mosaic's four colour planes are decoded apart."""

    def _mosaic(self) -> tuple[torch.Tensor, torch.Tensor, list[float]]:
        radiance = _smooth_scene(14)  # (1, 3, 48, 48)
        taus = _plan(14, Q16, spatial=True)
        sensor = SimulatedModuloSensor(8, Q16, seed=3, cfa="GRBG")
        return sensor(radiance, taus).moduli, radiance, taus  # moduli (1, M, 1, 48, 48)

    def test_planes_are_decoded_apart(self) -> None:
        moduli, _, taus = self._mosaic()
        out, variance = tm.unwrap_multi(moduli, taus, 8, noise=Q16, spatial=True, cfa="GRBG", return_variance=True)
        assert out.shape == variance.shape == (1, 1, 48, 48)
        for dy in (0, 1):
            for dx in (0, 1):
                plane = moduli[..., dy::2, dx::2]
                alone, alone_variance = tm.unwrap_multi(plane, taus, 8, noise=Q16, spatial=True, return_variance=True)
                assert torch.equal(out[..., dy::2, dx::2], alone)
                assert torch.equal(variance[..., dy::2, dx::2], alone_variance)
        unbatched = tm.unwrap_multi(moduli[0], taus, 8, noise=Q16, spatial=True, cfa="GRBG")
        assert torch.equal(unbatched, out[0])

    def test_the_layer_reads_the_pattern_of_a_frame_stack(self) -> None:
        moduli, radiance, taus = self._mosaic()
        stack = SimulatedModuloSensor(8, Q16, seed=3, cfa="GRBG")(radiance, taus)
        layer = tm.MultiExposureUnwrap(8, noise=Q16, spatial=True)
        expected = tm.unwrap_multi(moduli, taus, 8, noise=Q16, spatial=True, cfa="GRBG")
        assert torch.equal(layer(stack), expected)

    def test_without_spatial_evidence_the_pattern_changes_nothing(self) -> None:
        moduli, _, taus = self._mosaic()
        for noise in (None, Q16):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                plain = tm.unwrap_multi(moduli, taus, 8, noise=noise, spatial=False)
                assert torch.equal(tm.unwrap_multi(moduli, taus, 8, noise=noise, spatial=False, cfa="GRBG"), plain)

    def test_bad_patterns_and_shapes_are_named(self) -> None:
        moduli, _, taus = self._mosaic()
        with pytest.raises(ValueError, match="cfa"):
            tm.unwrap_multi(moduli, taus, 8, noise=Q16, spatial=True, cfa="RGBW")
        with pytest.raises(ValueError, match=r"even height and width.*got shape \(1, \d+, 1, 47, 48\)"):
            tm.unwrap_multi(moduli[..., :47, :], taus, 8, noise=Q16, spatial=True, cfa="GRBG")
        with pytest.raises(ValueError, match="one channel"):
            tm.unwrap_multi(moduli.expand(-1, -1, 3, -1, -1), taus, 8, noise=Q16, cfa="GRBG")
