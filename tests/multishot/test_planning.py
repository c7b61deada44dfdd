"""Tests for torch_modulo/multishot/planning.py: exposure plans, noise-free and under noise."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import pytest
import torch
from multishot_helpers import scene, stack

import torch_modulo as tm
from torch_modulo.noise import NoiseModel, as_noise_model

# The planner's mechanics (gates, tolerance, min_ratio, budgets) are tested on the plans for each pixel decoded alone,
# whose rules the module docstring states; the spatial plans (the default) where a test says spatial=True.
plan_exposures = functools.partial(tm.plan_exposures, spatial=False)


class TestPlanExposures:
    def test_paper_claim_three_captures_cover_24_stops(self) -> None:
        taus = plan_exposures(24, bits=8, max_ratio=256)
        assert taus == [1.0, 256.0, 65536.0]

    @pytest.mark.parametrize(("stops", "bits", "count"), [(8, 8, 1), (5, 8, 1), (9, 8, 2), (16, 8, 3), (24, 8, 4)])
    def test_counts(self, stops: float, bits: int, count: int) -> None:
        taus = plan_exposures(stops, bits)
        assert len(taus) == count
        ratios = [b / a for a, b in zip(taus, taus[1:], strict=False)]
        assert all(r <= 2**bits - 1 + 1e-9 for r in ratios)
        if count > 1:
            assert math.log2(taus[-1] / taus[0]) == pytest.approx(stops - bits)

    def test_plan_then_unwrap_recovers_scene(self) -> None:
        taus = plan_exposures(20, bits=8, base=1.0)
        radiance = scene((1, 3, 16, 16), stops=20, seed=4) * 255.9
        counts = tm.unwrap_multi(stack(radiance, taus, 8), taus, 8, return_counts=True)
        assert torch.equal(counts, torch.floor(radiance * taus[-1]))
        assert float(counts.min()) >= 1.0  # the darkest pixel still gets a count

    @pytest.mark.parametrize(
        ("kwargs", "match"),
        [
            ({"stops": -1}, "stops"),
            ({"stops": float("nan")}, "stops"),
            ({"stops": 10, "base": 0.0}, "base"),
            ({"stops": 10, "max_ratio": 1.0}, "max_ratio"),
            ({"stops": 10, "max_ratio": 300}, "max_ratio"),
            ({"stops": 10, "bits": 0}, "bits"),
        ],
    )
    def test_bad_input(self, kwargs: dict, match: str) -> None:
        with pytest.raises(ValueError, match=match):
            plan_exposures(**kwargs)


class TestPlanExposuresUnderNoise:
    @pytest.mark.parametrize("preset", ["photon-counting", "q16", "dfpa"])
    def test_plan_keeps_every_pixel_decodable(self, preset: str) -> None:
        noise = tm.sensors.NoiseModel.preset(preset)
        plan = plan_exposures(18, 8, noise=noise)
        assert plan[0] == 1.0 and plan == sorted(plan)
        ratios = [b / a for a, b in zip(plan, plan[1:], strict=False)]
        assert all(1 < r <= 255 for r in ratios)
        safe, _ = tm.multishot.safe_ratio(8, noise)
        assert max(ratios[:-1], default=1.0) <= safe  # gross-error-prone pixels always reach the next frame

    def test_quieter_sensors_need_fewer_frames(self) -> None:
        lengths = [len(plan_exposures(20, 8, noise=p)) for p in ("photon-counting", "q16", "dfpa")]
        assert lengths[0] > lengths[1] > lengths[2] >= 3
        assert len(plan_exposures(20, 8, noise="q16", tolerance=2.0)) <= lengths[1]

    def test_shortest_exposure_keeps_the_brightest_below_rollover(self) -> None:
        noise = tm.sensors.NoiseModel()
        plan = plan_exposures(16, 8, noise=noise)
        brightest = 2.0**16 * plan[0] / plan[-1]  # E_max reads 2**16 counts at the longest exposure
        assert brightest + 3 * noise.count_variance(brightest) ** 0.5 <= 255

    @pytest.mark.parametrize(
        "noise", [None, "photon-counting", "q16", "dfpa", tm.sensors.NoiseModel(read_noise=3.0, prnu=0.02)]
    )
    def test_without_dark_current_a_plan_at_base_b_is_the_scaled_plan(self, noise: object) -> None:
        unit = plan_exposures(20, 8, noise=noise)
        for b in (1e-5, 0.37, 1e3):
            assert plan_exposures(20, 8, noise=noise, base=b) == pytest.approx([b * t for t in unit], rel=1e-9)

    @pytest.mark.parametrize("noise", [None, "photon-counting", tm.sensors.NoiseModel(read_noise=3.0, prnu=0.02)])
    def test_longest_without_dark_current_is_the_base_one_plan_rescaled(self, noise: object) -> None:
        unit = plan_exposures(20, 8, noise=noise)  # exactly what plan_scene did before planning with longest=
        for longest in (1e-5, 1.0, 1e3):
            assert plan_exposures(20, 8, noise=noise, longest=longest) == [t * longest / unit[-1] for t in unit]

    @pytest.mark.parametrize("dark", [5.0, 20.0, 100.0])
    def test_under_dark_current_longest_plans_at_the_exposures_captured(self, dark: float) -> None:
        noise = tm.sensors.NoiseModel(dark_current=dark)  # electrons per unit exposure: the plan depends on its unit
        for longest in (1.0, 1e-4, 50.0):
            taus = plan_exposures(20, 8, noise=noise, longest=longest)
            assert taus[-1] == pytest.approx(longest, rel=1e-15)
            assert taus == pytest.approx(plan_exposures(20, 8, noise=noise, base=taus[0]), rel=1e-9)
        unit = plan_exposures(20, 8, noise=noise)
        assert len(plan_exposures(20, 8, noise=noise, longest=1.0)) != len(unit)  # rescaling it would be wrong

    @pytest.mark.parametrize("dark", [0.0, 20.0, 100.0])
    def test_shortest_exposure_leaves_room_for_the_dark_counts(self, dark: float) -> None:
        # Regression: the brightest radiance read brightest_unwrapped counts at the shortest exposure, plus dark counts
        # that took it over the rollover (dark=100: 41% of the brightest tenth of pixels wrong).
        noise = tm.sensors.NoiseModel(dark_current=dark)
        for base in (1.0, 0.25):
            plan = plan_exposures(12, 8, noise=noise, base=base)
            total = 2.0**12 * plan[0] / plan[-1] + noise.dark_counts * plan[0]  # E_max's signal plus dark counts
            assert total + 3 * noise.count_variance(total) ** 0.5 == pytest.approx(255, abs=1e-6)
        whole = tm.multishot.brightest_unwrapped(8, noise)
        assert tm.multishot.brightest_unwrapped(8, noise, exposure=2.0) == pytest.approx(whole - 2 * dark, abs=1e-9)
        assert tm.multishot.brightest_unwrapped(8, noise, exposure=1e6) == (0.0 if dark else whole)

    def test_dark_current_plan_decodes_the_brightest(self) -> None:
        noise = tm.sensors.NoiseModel(dark_current=100.0)
        taus = plan_exposures(12, 8, noise=noise)
        top = tm.multishot.brightest_unwrapped(8, noise, exposure=taus[0]) / taus[0]  # the plan's E_max
        radiance = (torch.exp2(torch.linspace(-12, 0, 256, dtype=torch.float64)) * top).expand(1, 1, 16, 256)
        frames = tm.sensors.SimulatedModuloSensor(bits=8, noise=noise, seed=0)(radiance, taus)
        relative = (tm.unwrap_multi(frames.moduli, frames.exposures, 8, noise=noise) - radiance).abs() / radiance
        assert float((relative[..., 230:] > 0.5).double().mean()) == 0.0  # the brightest tenth

    def test_without_noise_unchanged(self) -> None:
        assert plan_exposures(24, 8, noise=None) == plan_exposures(24, 8)

    def test_regression_one_bit_counter_default_ratio(self) -> None:
        plan = plan_exposures(24, bits=1)
        assert plan[:3] == [1.0, 2.0, 4.0] and len(plan) == 24

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"stops": 200, "base": 1e300}, ValueError, "stops=200 from base=1e\\+300 needs exposures beyond float64"),
            ({"stops": 1100}, ValueError, "stops=1100 .* beyond float64"),
            ({"stops": 10, "max_ratio": "x"}, TypeError, "max_ratio must be a number; got 'x'"),
            ({"stops": 10, "noise": {"q": 1}}, TypeError, "noise must be a NoiseModel or None; got dict"),
            ({"stops": 10, "noise": "loud"}, ValueError, "noise preset must be one of"),
            ({"stops": 10, "noise": "q16", "tolerance": 0.5}, ValueError, "tolerance must be finite and >= 1"),
            ({"stops": 10, "noise": "q16", "min_ratio": 1.0}, ValueError, "min_ratio must be in \\(1, max_ratio"),
            ({"stops": 10, "noise": "q16", "sigmas": -1}, ValueError, "sigmas must be finite and > 0"),
            (
                {"stops": 10, "bits": 4, "noise": tm.sensors.NoiseModel(read_noise=8.0)},
                ValueError,
                "read noise alone exceeds the decoding gate",
            ),
            ({"stops": 10, "base": 2.0, "longest": 8.0}, ValueError, "give base or longest, not both"),
            ({"stops": 10, "longest": 0.0}, ValueError, "longest must be"),
            (
                {"stops": 10, "noise": tm.sensors.NoiseModel(dark_current=300.0)},
                ValueError,
                "dark counts of the shortest exposure base=1 \\(300 counts\\) leave no count below the rollover",
            ),
        ],
    )
    def test_regression_bad_input_named(self, kwargs: dict, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            plan_exposures(**kwargs)


class TestPlanExposuresExtremes:
    @pytest.mark.parametrize("max_ratio", [1 + 1e-5, 1 + 1e-7])
    def test_regression_noise_free_plans_cap_the_frame_count(self, max_ratio: float) -> None:
        # max_ratio=1 + 1e-7 built a list of 55 million exposures; the noise-aware planner stops at 256.
        with pytest.raises(ValueError, match=rf"max_ratio={max_ratio!r} needs \d+ exposures, more than 256"):
            plan_exposures(16, 8, max_ratio=max_ratio)
        assert len(plan_exposures(16, 8, max_ratio=1.03)) <= 256

    @pytest.mark.parametrize("base", [1e300, 1e-300])
    def test_regression_noise_aware_plans_at_extreme_bases(self, base: float) -> None:
        # base=1e300 raised OverflowError from the planner (tau**2); a plan at base b is the base-1 plan scaled.
        unit = plan_exposures(16, 8, noise="q16")
        assert plan_exposures(16, 8, base=base, noise="q16") == pytest.approx([base * t for t in unit], rel=1e-9)

    def test_regression_noise_aware_plans_beyond_float_range_are_refused(self) -> None:
        # stops - bits + log2(base) passes the range check, but the longest exposure, base 2^14 / 4.9, is beyond it.
        with pytest.raises(ValueError, match=r"stops=14 from base=8e\+304 .* beyond float64's range"):
            plan_exposures(14, 4, base=8e304, noise=tm.sensors.NoiseModel(read_noise=2.5))

    @pytest.mark.parametrize("preset", ["photon-counting", "q16", "dfpa", "dark"])
    @pytest.mark.parametrize("stops", [8, 8.5, 10, 12, 14, 16, 20, 24])
    @pytest.mark.parametrize("min_ratio", [1.5, 2.0])
    def test_regression_noise_aware_plans_keep_min_ratio(self, preset: str, stops: float, min_ratio: float) -> None:
        # plan_exposures(8, 8, noise="dfpa") gave [1, 1.01]; q16 and photon-counting at 8 stops ratios of 1.05 and
        # 1.21, below the smallest ratio worth a frame.
        noise = tm.sensors.NoiseModel(dark_current=20.0) if preset == "dark" else tm.sensors.NoiseModel.preset(preset)
        plan = plan_exposures(stops, 8, noise=noise, min_ratio=min_ratio)
        ratios = [b / a for a, b in zip(plan, plan[1:], strict=False)]
        assert all(r >= min_ratio * (1 - 1e-9) for r in ratios), ratios
        first = tm.multishot.brightest_unwrapped(8, noise, exposure=plan[0])
        assert plan[-1] >= plan[0] * 2.0**stops / first * (1 - 1e-9)  # E_min still reads a count at the longest

    @pytest.mark.parametrize("preset", ["photon-counting", "q16", "dfpa"])
    def test_plans_without_short_steps_decode_like_the_oracle(self, preset: str) -> None:
        # The plans whose short last step was lengthened decode a scene of their stops as well as the longest frame
        # read with its true rollover count (the same noise draws).
        noise = tm.sensors.NoiseModel.preset(preset)
        for stops in (8, 10, 12):
            plan = plan_exposures(stops, 8, noise=noise)
            taus = [t / plan[-1] for t in plan]
            top = tm.multishot.brightest_unwrapped(8, noise) / taus[0]
            radiance = (torch.exp2(torch.linspace(-stops, 0, 256, dtype=torch.float64)) * top).expand(1, 1, 32, 256)
            moduli = tm.sensors.SimulatedModuloSensor(8, noise, seed=4)(radiance, taus).moduli
            counts = tm.sensors.SimulatedIntensitySensor(53, noise, seed=4)(radiance, taus).frames[:, -1]
            decoded = (tm.unwrap_multi(moduli, taus, 8, noise=noise) - radiance).abs() / radiance
            oracle = (counts / taus[-1] - radiance).abs() / radiance
            # "More than half off", past a hair: at E_min (one count) a quantum-limited dfpa pixel's estimate
            # (c + 1/2) is half off whichever count it reads.
            gross = 0.5 + 1e-3
            assert float((decoded > gross).double().mean()) <= float((oracle > gross).double().mean()) + 1e-3
            assert float(decoded.median()) <= 1.5 * float(oracle.median())


class TestShortLastStep:
    """A plan whose ratios end a hair short of the longest exposure stretches them, rather than spend a frame on the
    last hair (a frame lengthened to ``min_ratio``, past the longest exposure)."""

    @staticmethod
    def greedy(monkeypatch: pytest.MonkeyPatch, stops: float, noise: str, spatial: bool) -> list[float]:
        with monkeypatch.context() as patch:
            patch.setattr(tm.multishot.planning, "_STRETCH", 1.0)
            return tm.plan_exposures(stops, 8, noise=noise, spatial=spatial)

    # (dfpa's spatial plans take ratios at max_ratio, which no stretch may pass: it stretches none of them.)
    @pytest.mark.parametrize(
        ("noise", "spatial"),
        [("q16", True), ("q16", False), ("photon-counting", True), ("photon-counting", False), ("dfpa", False)],
    )
    def test_stretched_by_at_most_one_percent_a_ratio(
        self, monkeypatch: pytest.MonkeyPatch, noise: str, spatial: bool
    ) -> None:
        stretched = 0
        for stops in [s / 2 for s in range(16, 97)]:  # 8 to 48 stops
            plan = tm.plan_exposures(stops, 8, noise=noise, spatial=spatial)
            greedy = self.greedy(monkeypatch, stops, noise, spatial)
            if plan == greedy:
                continue
            stretched += 1
            assert len(plan) == len(greedy) - 1
            longest = 2.0**stops / tm.multishot.brightest_unwrapped(8, as_noise_model(noise))
            assert plan[-1] == pytest.approx(longest, rel=1e-12) and greedy[-1] >= longest * (1 - 1e-12)
            # Each exposure before the longest moves up by at most 1% per ratio before it (the shortest stays).
            moved = [b / a for a, b in zip(greedy, plan[:-1], strict=False)]
            assert moved[0] == 1.0 and all(1.0 <= m <= 1.01**i * (1 + 1e-12) for i, m in enumerate(moved))
            # Each ratio is the greedy one at most 1% longer, the last too where the greedy plan lengthened its last
            # frame (the frame before it is then the walk's; where it moved that frame down instead, it is not).
            ratios = [b / a for a, b in zip(plan, plan[1:], strict=False)]
            walk = [b / a for a, b in zip(greedy, greedy[1:], strict=False)]
            compared = len(ratios) if greedy[-1] > longest * (1 + 1e-9) else len(ratios) - 1
            assert all(1 - 1e-12 <= r / g <= 1.01 * (1 + 1e-12) for r, g in zip(ratios[:compared], walk, strict=False))
        assert stretched >= 1  # each case here has such stops (6 in 81 for the spatial plans)

    @pytest.mark.parametrize("max_ratio", [None, 12.0])
    def test_a_stretch_keeps_max_ratio(self, max_ratio: float | None) -> None:
        # A 4-bit dfpa plan's ratios sit at max_ratio (15 by default); a stretch took them to 15.02 - 15.14.
        limit = 15.0 if max_ratio is None else max_ratio
        for stops in [s / 4 for s in range(200)]:
            plan = tm.plan_exposures(stops, 4, noise="dfpa", max_ratio=max_ratio)
            assert (
                max(b / a for a, b in zip(plan, plan[1:], strict=False)) <= limit * (1 + 1e-12)
                if len(plan) > 1
                else True
            )

    def test_regression_twenty_stops_at_q16_take_five_frames(self) -> None:
        # The ratios reach all but a hair of the longest exposure in four steps, and a fifth (the smallest ratio)
        # would go on past it: 6 frames without the stretch.
        plan = tm.plan_exposures(20, 8, noise="q16")
        assert len(plan) == 5
        assert plan[-1] == pytest.approx(2.0**20 / tm.multishot.brightest_unwrapped(8, as_noise_model("q16")))
        # A budget of as many frames as the plan holds is met by it (the budget search sees the stretch too).
        assert tm.plan_exposures(20, 8, noise="q16", frames=5) == pytest.approx(plan, rel=1e-12)


class TestFrameBudget:
    @pytest.mark.parametrize("preset", ["photon-counting", "q16", "dfpa"])
    @pytest.mark.parametrize("frames", [3, 5, 8])
    def test_plan_fits_the_budget_and_covers_the_scene(self, preset: str, frames: int) -> None:
        default = plan_exposures(16, 8, noise=preset, longest=1.0)
        plan = plan_exposures(16, 8, noise=preset, longest=1.0, frames=frames)
        assert len(plan) <= frames and plan[-1] == pytest.approx(1.0)
        # The same scene: the shortest exposure still holds the brightest value below the rollover.
        assert plan[0] == pytest.approx(default[0], rel=1e-9)
        if len(default) <= frames:  # a budget the default meets changes nothing but the tolerance
            assert len(plan) >= len(default)

    def test_larger_budgets_are_closer_to_the_oracle(self) -> None:
        # Each budget's plan is the one of smallest tolerance that fits, so more frames never predict worse.
        from torch_modulo.multishot.prediction import predict_modulo

        medians = [
            predict_modulo(
                plan_exposures(16, 8, noise="q16", longest=1.0, frames=k), 8, "q16", stops=16, spatial=False
            ).median_error
            for k in (3, 4, 6, 9)
        ]
        assert all(b <= a * 1.02 for a, b in zip(medians, medians[1:], strict=False)), medians

    @staticmethod
    def _smallest_fitting(plan_at: Callable[[float], list[float]], frames: int, low: float, high: float) -> list[float]:
        """The plan of the smallest value in [low, high] (bisection on its logarithm) with at most ``frames``."""
        best = plan_at(high)
        assert len(best) <= frames
        low, high = math.log(low), math.log(high)
        for _ in range(40):
            mid = 0.5 * (low + high)
            found = plan_at(math.exp(mid))
            low, high, best = (mid, high, best) if len(found) > frames else (low, mid, found)
        return best

    @pytest.mark.parametrize(("noise", "stops", "frames"), [("q16", 20, 9), ("photon-counting", 20, 9)])
    def test_a_budget_raises_the_smallest_ratio_before_the_tolerance(self, noise: str, stops: int, frames: int) -> None:
        # Below the default's frames the budget takes the smallest min_ratio that fits: the brightest pixels end
        # earlier, the rest keep their ratios. Raising the tolerance instead (the earlier rule) predicts worse.
        from torch_modulo.multishot.prediction import predict_modulo

        plan = plan_exposures(stops, 8, noise=noise, longest=1.0, frames=frames)
        tolerance = self._smallest_fitting(
            lambda tol: plan_exposures(stops, 8, noise=noise, longest=1.0, tolerance=tol), frames, 1.2, 2.0**40
        )
        default = plan_exposures(stops, 8, noise=noise, longest=1.0)
        assert len(default) > frames == len(plan) == len(tolerance)
        ratio = self._smallest_fitting(
            lambda r: plan_exposures(stops, 8, noise=noise, longest=1.0, min_ratio=r), frames, 1.5, 40.0
        )
        assert plan == pytest.approx(ratio, rel=1e-9)  # the smallest min_ratio that fits

        def median(taus: list[float]) -> float:
            return predict_modulo(taus, 8, noise, stops=stops, spatial=False).median_error

        assert median(plan) < 0.8 * median(tolerance)
        assert median(plan) < 2.0 * median(default)

    def test_a_budget_past_what_blank_pixels_decode_raises_the_tolerance(self) -> None:
        # q16, 24 stops in 4 frames: the smallest min_ratio that fits needs ratios after which a pixel that read
        # nothing cannot decode the next frame, so every dark pixel would keep only the shortest frames; the budget
        # raises the tolerance instead, whose ratios grow only as far as the dark pixels decode.
        from torch_modulo.multishot.prediction import predict_modulo

        plan = plan_exposures(24, 8, noise="q16", longest=1.0, frames=4)
        ratio = self._smallest_fitting(
            lambda r: plan_exposures(24, 8, noise="q16", longest=1.0, min_ratio=r), 4, 1.5, 255.0
        )
        assert len(plan) == len(ratio) == 4 and plan != ratio
        first, second = (predict_modulo(taus, 8, "q16", stops=24, spatial=False) for taus in (plan, ratio))
        assert first.gross_share < 0.75 * second.gross_share and first.median_error < 0.2 * second.median_error

    def test_spare_frames_lower_the_tolerance(self) -> None:
        default = plan_exposures(20, 8, noise="q16", longest=1.0)
        closest = plan_exposures(20, 8, noise="q16", longest=1.0, tolerance=1.0)
        assert len(closest) > len(default)
        assert plan_exposures(20, 8, noise="q16", longest=1.0, frames=len(closest)) == closest
        assert plan_exposures(20, 8, noise="q16", longest=1.0, frames=len(closest) + 5) == closest

    @pytest.mark.parametrize(("noise", "spatial"), [("q16", True), (NoiseModel(dark_current=40.0), False)])
    def test_budgets_for_spatial_plans_and_dark_current(self, noise: NoiseModel | str, spatial: bool) -> None:
        model = as_noise_model(noise)
        assert model is not None
        needed = 2.0**20 / tm.multishot.brightest_unwrapped(8, model, exposure=1.0)  # E_min reads one count there
        default = plan_exposures(20, 8, noise=model, spatial=spatial)
        for frames in range(3, len(default)):
            plan = plan_exposures(20, 8, noise=model, spatial=spatial, frames=frames)
            assert len(plan) <= frames and plan[0] == 1.0 and plan[-1] >= needed * (1 - 1e-9)

    def test_regression_a_budget_of_256_frames_searches_on(self) -> None:
        # A plan of 256 frames that a budget search had not yet ruled out raised "needs more than 256 exposures"
        # (naming the search's tolerance, 1) instead of moving on to the next plan.
        plan = plan_exposures(48, 4, noise="q16", min_ratio=1.1, tolerance=3.0, frames=256)
        assert len(plan) <= 256

    def test_a_budget_of_a_scene_one_frame_covers(self) -> None:
        assert plan_exposures(4, 8, noise="q16", frames=3) == [1.0] == plan_exposures(4, 8, noise="q16")

    def test_a_budget_the_largest_ratios_cannot_meet_is_refused_with_the_count(self) -> None:
        with pytest.raises(ValueError, match=r"frames=1 is too few: stops=16 .* needs \d+ exposures even with"):
            plan_exposures(16, 8, noise="q16", frames=1)
        with pytest.raises(ValueError, match=r"frames=2 is too few: stops=24 at bits=8 needs 4 exposures"):
            plan_exposures(24, 8, frames=2)

    def test_noise_free_budget_is_the_fewest_frame_plan(self) -> None:
        assert plan_exposures(24, 8, frames=5) == plan_exposures(24, 8)

    @pytest.mark.parametrize(("frames", "error"), [(0, ValueError), (2.5, TypeError), ("3", TypeError)])
    def test_bad_budget_named(self, frames: object, error: type[Exception]) -> None:
        with pytest.raises(error, match="frames"):
            plan_exposures(16, 8, noise="q16", frames=frames)  # type: ignore[arg-type]


class TestLongestFrames:
    @pytest.mark.parametrize("options", [{}, {"noise": "q16"}, {"noise": "q16", "spatial": True, "longest": 2.0}])
    def test_the_longest_exposure_is_repeated(self, options: dict[str, object]) -> None:
        plan = plan_exposures(16, 8, **options)  # type: ignore[arg-type]
        assert plan_exposures(16, 8, longest_frames=3, **options) == plan + [plan[-1]] * 2  # type: ignore[arg-type]

    def test_the_budget_counts_the_repeats(self) -> None:
        shorter = plan_exposures(20, 8, noise="q16", frames=5)
        plan = plan_exposures(20, 8, noise="q16", frames=6, longest_frames=2)
        assert plan == shorter + [shorter[-1]]

    def test_bad_values_are_named(self) -> None:
        with pytest.raises(ValueError, match="longest_frames"):
            plan_exposures(16, 8, noise="q16", longest_frames=0)
        with pytest.raises(TypeError, match="longest_frames"):
            plan_exposures(16, 8, noise="q16", longest_frames=1.5)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="longest_frames"):
            plan_exposures(16, 8, noise="q16", longest_frames=257)
        with pytest.raises(ValueError, match="193 exposures with longest_frames=100 holds 292 frames, more than 256"):
            plan_exposures(200, 8, max_ratio=2, longest_frames=100)  # 193 exposures and 99 repeats
        with pytest.raises(ValueError, match="frames=2 cannot hold the longest_frames=3"):
            plan_exposures(16, 8, noise="q16", frames=2, longest_frames=3)
        need = len(plan_exposures(30, 8, noise="q16", max_ratio=8, min_ratio=8)) + 1  # the largest ratios, 1 repeat
        with pytest.raises(ValueError, match=rf"frames=4 is too few: .* needs {need} exposures"):
            plan_exposures(30, 8, noise="q16", max_ratio=8, frames=4, longest_frames=2)
        with pytest.raises(ValueError, match=r"frames=3 is too few: .* needs 4 exposures"):
            plan_exposures(24, 8, max_ratio=256, frames=3, longest_frames=2)  # noise-free: 3 + 1

    def test_a_repeat_collects_light_where_the_pixels_decode(self) -> None:
        # A smooth 14-stop ramp under q16, decoded with spatial evidence: the second frame at the longest exposure
        # averages the noise of every pixel that decodes it.
        plan = plan_exposures(14, 8, noise="q16", spatial=True, longest=1.0)
        twice = plan_exposures(14, 8, noise="q16", spatial=True, longest=1.0, longest_frames=2)
        y, x = torch.meshgrid(torch.linspace(0, 1, 48), torch.linspace(0, 1, 48), indexing="ij")
        radiance = torch.exp2(14.0 * (x + y) / 2).to(torch.float64).expand(1, 1, 48, 48)
        errors = []
        for taus in (plan, twice):
            moduli = tm.sensors.SimulatedModuloSensor(8, "q16", seed=3)(radiance, taus).moduli
            decoded = tm.unwrap_multi(moduli, taus, 8, noise="q16", spatial=True)
            errors.append(float(((decoded - radiance).abs() / radiance).median()))
        assert errors[1] < 0.9 * errors[0], errors
