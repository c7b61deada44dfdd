"""Tests for unwrap_single / SingleShotUnwrap: single-shot recovery (paper Sec. 4)."""

from __future__ import annotations

import itertools
import math
import warnings

import numpy as np
import pytest
import torch

from torch_modulo.metrics import exact_k_share
from torch_modulo.singleshot import SingleShotInfo, SingleShotUnwrap, unwrap_energy, unwrap_single
from torch_modulo.singleshot.energy import EnergyParams, pair_offsets
from torch_modulo.singleshot.graphcut import plane_energy


def scene(kind: str, size: int = 64, seed: int = 0) -> torch.Tensor:
    """Smooth synthetic counts (float64, (size, size)) with a dark region at k = 0; 10 to 13 stops above the darkest
    pixel at size 64 (smaller sizes are its top-left crop), no neighbour pair (diagonals included) 128 counts apart."""
    y, x = np.mgrid[0:64, 0:64].astype(np.float64)
    rng = np.random.default_rng(seed)

    def bump(cy: float, cx: float, s: float) -> np.ndarray:
        return np.exp(-((y - cy) ** 2 + (x - cx) ** 2) / (2 * s * s))

    if kind == "ramp":  # 1 .. 7561 counts: 12.9 stops; steepest pair (diagonal) 120
        img = 1 + 60 * x + 60 * y
    elif kind == "bumps":  # two Gaussian bumps on a dark floor of 1 count: 1 .. ~2000, 11 stops
        dy, dx = rng.uniform(-2, 2, 2)
        img = 1 + np.maximum(0, 2200 * bump(30 + dy, 34 + dx, 17) + 500 * bump(14, 14, 9) - 220)
    elif kind == "steps":  # a staircase of 100-count steps (below 2^(8-1)) on a gentle ramp: 10.8 stops
        img = 1 + 100 * (x // 4) + 5 * y
    elif kind == "mixed":  # ramp + staircase + bump: 11.2 stops
        img = 1 + np.maximum(0, 12 * x + 10 * y + 16 * ((x + y) // 12) + 1500 * bump(40, 36, 17) - 150)
    else:
        raise ValueError(kind)
    return torch.from_numpy(np.floor(img[:size, :size]).copy())


def stops(counts: torch.Tensor) -> float:
    return math.log2(float(counts.max()) / float(counts[counts > 0].min()))


class TestUnwrapSingle:
    def test_smoke(self) -> None:
        truth = scene("ramp", 16)
        out = unwrap_single(truth % 256)
        assert out.shape == truth.shape
        assert torch.equal(out, truth)

    @pytest.mark.parametrize(("small", "peak"), [(torch.float16, 2048), (torch.bfloat16, 256)])
    def test_warns_where_the_dtype_cannot_hold_the_counts(self, small: torch.dtype, peak: int) -> None:
        exact = torch.arange(0.0, peak + 1).reshape(1, -1)[:, :: peak // 64].repeat(4, 1)  # up to ``peak`` counts
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert torch.equal(unwrap_single((exact % 128).to(small), 7, method="guided").double(), exact.double())
        beyond = torch.arange(0.0, 2 * peak, peak / 64).reshape(1, -1).repeat(4, 1)
        with pytest.warns(UserWarning, match=rf"beyond what {small} holds exactly \({peak}\)"):
            unwrap_single((beyond % 128).to(small), 7, method="guided")

    def test_float32_beyond_its_integers_is_told_to_use_float64(self) -> None:
        # Regression: float32 users were told to "use float32 or float64".
        counts = torch.arange(0.0, 2.0**25, 2.0**18).reshape(1, -1).repeat(4, 1)  # up to twice 2**24
        with pytest.warns(UserWarning, match=r"beyond what torch.float32 holds exactly \(16777216\)") as record:
            out = unwrap_single((counts % 2**24).float(), 24, method="guided")
        message = str(record[0].message)
        assert "use float64" in message and "float32 or" not in message
        assert torch.equal(out.double(), counts)  # multiples of 2**18: float32 holds these ones

    def test_float64_beyond_2_to_53_says_what_holds(self) -> None:
        # Regression: float64 users at bits=53 were told to "use float32 or float64", which cannot help.
        counts = torch.arange(0.0, 2.0**54, 2.0**47, dtype=torch.float64).reshape(1, -1).repeat(4, 1)
        with pytest.warns(UserWarning, match=r"beyond what torch.float64 holds exactly \(9007199254740992\)") as record:
            out = unwrap_single(counts % 2**53, 53, method="guided")
        message = str(record[0].message)
        assert "no floating dtype holds them exactly" in message and "use float" not in message
        assert torch.equal(out, counts)

    def test_float16_counts_past_65504_become_inf_with_a_warning(self) -> None:
        # Regression: float16 counts above its largest finite value (65504) became inf with only the rounding warning.
        counts = torch.arange(0.0, 2.0**17, 512.0).reshape(1, -1).repeat(4, 1)  # up to 130560
        with pytest.warns(UserWarning) as record:
            out = unwrap_single((counts % 2048).half(), 11, method="guided")
        n_inf = int(torch.isinf(out).sum())
        assert n_inf == int((counts >= 65520).sum()) > 0  # what rounds past 65504 in float16
        messages = [str(w.message) for w in record]
        assert any(f"{n_inf} restored counts are above 65504" in m and "became inf" in m for m in messages), messages
        assert all("float16 or" not in m for m in messages)

    def test_requires_grad_modulus_gives_no_torch_warning(self) -> None:
        # Regression: the checks read a modulus that requires grad without detaching it, and torch warned.
        modulus = (scene("ramp", 16) % 256).requires_grad_()
        warn_always = torch.is_warn_always_enabled()
        torch.set_warn_always(True)  # torch gives that warning once per process: every time here
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                out = unwrap_single(modulus, method="guided")
                assert torch.equal(SingleShotUnwrap(method="guided")(modulus), out)
        finally:
            torch.set_warn_always(warn_always)
        assert torch.equal(out, scene("ramp", 16))

    @pytest.mark.parametrize("method", ["guided", "learned"])
    def test_channels_last_comes_back_channels_last(self, method: str) -> None:
        # Regression: a channels_last input came back contiguous from SingleShotUnwrap and unwrap_single.
        truth = (
            torch.stack([scene("ramp", 16), scene("steps", 16), scene("mixed", 16)]).float()[None].repeat(2, 1, 1, 1)
        )
        modulus = (truth % 256).contiguous(memory_format=torch.channels_last)
        out = SingleShotUnwrap(method=method)(modulus)
        assert out.is_contiguous(memory_format=torch.channels_last) and not out.is_contiguous()
        assert torch.equal(out, unwrap_single(modulus.contiguous(), method=method))
        assert unwrap_single(modulus, method=method).is_contiguous(memory_format=torch.channels_last)
        restored, info = unwrap_single(modulus, method="learned", return_info=True)
        assert info.confidence is not None and info.confidence.is_contiguous(memory_format=torch.channels_last)
        assert unwrap_single(modulus.contiguous(), method=method).is_contiguous()  # contiguous stays contiguous

    @pytest.mark.parametrize("kind", ["ramp", "bumps", "steps", "mixed"])
    @pytest.mark.parametrize("method", ["paper", "fast", "guided"])
    def test_recovers_smooth_scenes_exactly(self, kind: str, method: str) -> None:
        truth = scene(kind)
        assert 10 <= stops(truth) <= 13.5
        out = unwrap_single(truth % 256, bits=8, method=method)
        assert torch.equal(out, truth)

    @pytest.mark.parametrize("options", [{"init": "quality"}, {"init": "zeros"}, {"window": 0, "rel_tol": 0.0}])
    def test_fast_options_recover(self, options: dict) -> None:
        truth = scene("mixed")
        assert torch.equal(unwrap_single(truth % 256, method="fast", **options), truth)

    def test_auto_init_follows_residues(self) -> None:
        # A smooth scene has no residues: "auto" starts from path following, which is already the minimum, so
        # no move is accepted; from k = 0 it takes one accepted move per rollover level at least.
        truth = scene("ramp", 32)
        _, auto = unwrap_single(truth % 256, method="fast", return_info=True)
        _, zeros = unwrap_single(truth % 256, method="fast", init="zeros", return_info=True)
        assert int(auto.iterations[0, 0]) == 0
        assert int(zeros.iterations[0, 0]) >= int(truth.max()) // 256

    def test_four_neighbourhood_and_other_bits(self) -> None:
        truth = scene("bumps", 48)
        assert torch.equal(unwrap_single(truth % 256, neighborhood=4), truth)
        coarse = torch.floor(truth / 8)  # 8 bits' worth of range wrapped by a 5-bit counter
        assert torch.equal(unwrap_single(coarse % 32, bits=5), coarse)

    @pytest.mark.parametrize("shape", [(12, 10), (2, 12, 10), (2, 3, 12, 10), (0, 3, 12, 10), (2, 0, 12, 10)])
    def test_cardinality(self, shape: tuple, device: torch.device, dtype: torch.dtype) -> None:
        g = torch.Generator().manual_seed(0)
        modulus = torch.randint(0, 256, shape, generator=g).to(device=device, dtype=dtype)
        out = unwrap_single(modulus, workers=1)
        assert out.shape == modulus.shape and out.dtype == dtype and out.device == modulus.device
        # restored = modulus + k 2^bits with k >= 0
        k = (out - modulus) / 256
        assert bool((k >= 0).all()) and torch.equal(k, torch.round(k))

    def test_darkest_region_at_zero(self) -> None:
        truth = scene("bumps") + 512  # the same scene two rollovers brighter: k is only known up to a constant
        out = unwrap_single(truth % 256)
        assert torch.equal(out, truth - 512)
        assert float(out.min()) < 256

    def test_energy_never_increases(self) -> None:
        g = torch.Generator().manual_seed(1)
        noisy = scene("bumps", 32) + torch.randint(-40, 41, (32, 32), generator=g)
        modulus = noisy.clamp(min=0) % 256
        for method in ("paper", "fast"):
            out, info = unwrap_single(modulus, method=method, return_info=True)
            energies = info.energies[0][0]
            assert all(b < a for a, b in zip(energies, energies[1:], strict=False))
            assert int(info.iterations[0, 0]) == len(energies) - 1
            assert float(info.energy[0, 0]) == pytest.approx(float(unwrap_energy(out.double())))

    def test_info_layout(self) -> None:
        modulus = torch.stack([scene("ramp", 16), scene("steps", 16)]).unsqueeze(0) % 256  # (1, 2, 16, 16)
        out, info = unwrap_single(modulus, return_info=True)
        assert isinstance(info, SingleShotInfo) and info.method == "learned"
        assert info.iterations.shape == info.cuts.shape == info.energy.shape == info.seconds.shape == (1, 2)
        assert len(info.energies) == 1 and len(info.energies[0]) == 2
        assert bool((info.cuts >= info.iterations).all())
        _, info_hw = unwrap_single(modulus[0, 0], return_info=True)
        assert info_hw.iterations.shape == (1, 1)

    @pytest.mark.parametrize("seed", range(5))
    def test_matches_brute_force_minimum(self, seed: int) -> None:
        # 2 x 3 images, 3-bit counter: enumerate every k in {0..3}^6 and compare with the solver, up to a constant.
        rng = np.random.default_rng(seed)
        truth = np.cumsum(rng.integers(0, 4, (2, 3)), axis=1) + np.array([[0], [2]]) + 3 * rng.integers(0, 2)
        modulus = truth % 8
        p = EnergyParams.make(3)
        ks = np.array(list(itertools.product(range(4), repeat=6))).reshape(-1, 2, 3)
        energies = np.array([plane_energy(modulus + 8 * k, p, pair_offsets(8)) for k in ks])
        best = ks[energies.argmin()]
        for method in ("paper", "fast"):
            out = unwrap_single(torch.from_numpy(modulus).double(), bits=3, method=method).numpy().astype(np.int64)
            k = (out - modulus) // 8
            assert plane_energy(out, p, pair_offsets(8)) == pytest.approx(energies.min())
            assert np.all(k - best == (k - best).flat[0])

    def test_batched_equals_per_image(self) -> None:
        g = torch.Generator().manual_seed(2)
        noise = torch.randint(-30, 31, (2, 2, 20, 20), generator=g)
        batch = (torch.stack([scene("bumps", 20, s) for s in range(4)]).reshape(2, 2, 20, 20) + noise).clamp(min=0)
        modulus = batch % 256
        out = unwrap_single(modulus, workers=1)
        for b in range(2):
            for c in range(2):
                assert torch.equal(out[b, c], unwrap_single(modulus[b, c], workers=1))
        assert torch.equal(out[1], unwrap_single(modulus[1], workers=1))

    def test_input_unmodified(self) -> None:
        modulus = scene("ramp", 16) % 256
        before = modulus.clone()
        unwrap_single(modulus)
        assert torch.equal(modulus, before)

    def test_module_equals_function(self) -> None:
        modulus = (scene("mixed", 24) % 256).reshape(1, 1, 24, 24)
        module = SingleShotUnwrap(bits=8, method="fast", init="quality")
        assert torch.equal(module(modulus), unwrap_single(modulus, method="fast", init="quality"))
        assert torch.equal(SingleShotUnwrap()(modulus), unwrap_single(modulus))
        assert SingleShotUnwrap().method == "learned"  # the module and the function share their default
        guided = SingleShotUnwrap(method="guided", colour=False)
        assert torch.equal(guided(modulus), unwrap_single(modulus, method="guided", colour=False))
        assert torch.equal(
            unwrap_single(modulus, method="guided", denoise=np.float32(0.7), colour=np.bool_(True)),
            unwrap_single(modulus, method="guided", denoise=0.7),
        )

    def test_guided_colour_shares_the_tree(self) -> None:
        # Channel 0 rises by exactly one period at column 12: a step the wrapped image cannot show (it looks as
        # smooth as the ramp), except in a 3-row gap where it climbs gently. Channel 1 has the same edge at 100
        # counts, which its wrapped image shows as steep. Alone, channel 0's tree crosses the invisible step and
        # misses the rise; with the reliabilities of the channels summed, the tree goes through the gap.
        y, x = np.mgrid[0:24, 0:24].astype(np.float64)
        base = np.floor(30 * x + 4 * y)
        gap = np.abs(y - 12) <= 1
        rise = np.where(gap, np.clip((x - 8) / 8, 0, 1), (x >= 12).astype(float))
        truth = torch.from_numpy(np.floor(np.stack([base + 256 * rise, base + 100 * rise, 0.5 * base])))
        together = unwrap_single(truth % 256, method="guided")
        alone = unwrap_single(truth % 256, method="guided", colour=False)
        assert torch.equal(together, truth)
        assert float((alone[0] == truth[0]).double().mean()) < 0.6
        assert torch.equal(alone[1:], truth[1:])

    def test_guided_denoise_resists_noise_in_the_low_bits(self) -> None:
        # Gaussian noise of 45 counts rms on a smooth 11-stop scene: plain path following carries single noisy
        # steps down whole subtrees; smoothing the wrapped image's phasor first keeps most of the image right.
        plain, smoothed = [], []
        for seed in range(3):
            g = torch.Generator().manual_seed(seed)
            noise = 45 * torch.randn(64, 64, generator=g, dtype=torch.float64)
            noisy = torch.floor((scene("bumps") + noise).clamp(min=0))
            for out, options in ((plain, {}), (smoothed, {"denoise": 0.7})):
                restored = unwrap_single(noisy % 256, method="guided", **options)
                out.append(float(exact_k_share(restored[None, None], noisy[None, None], 8)[0]))
        assert np.mean(smoothed) > np.mean(plain) + 0.1
        truth = scene("mixed")  # noise-free and smooth: smoothing keeps it exact
        assert torch.equal(unwrap_single(truth % 256, method="guided", denoise=0.7), truth)

    def test_guided_info_and_batches(self) -> None:
        g = torch.Generator().manual_seed(4)
        noise = torch.randint(-30, 31, (2, 3, 20, 20), generator=g)
        batch = (torch.stack([scene("bumps", 20, s) for s in range(6)]).reshape(2, 3, 20, 20) + noise).clamp(min=0)
        out, info = unwrap_single(batch % 256, method="guided", return_info=True, workers=1)
        assert info.method == "guided" and bool((info.cuts == 0).all()) and bool((info.iterations == 0).all())
        assert info.energy.shape == (2, 3)
        for b in range(2):
            assert torch.equal(out[b], unwrap_single(batch[b] % 256, method="guided"))
            for c in range(3):
                assert float(info.energy[b, c]) == pytest.approx(float(unwrap_energy(out[b, c])))
        assert torch.equal(unwrap_single(batch % 256, method="guided", workers=2), out)

    @pytest.mark.parametrize(
        ("modulus", "kwargs", "error", "text"),
        [
            (torch.tensor([[0.0, 256.0]]), {}, ValueError, "256"),
            (torch.tensor([[0.0, -1.0]]), {}, ValueError, "-1"),
            (torch.tensor([[0.0, math.nan]]), {}, ValueError, "NaN"),
            (torch.tensor([[0.0, 2.5]]), {}, ValueError, "2.5"),
            (torch.zeros(0, 5), {}, ValueError, r"\(0, 5\)"),
            (torch.zeros(3, 0, 5), {}, ValueError, r"\(3, 0, 5\)"),
            (torch.zeros(1, 1, 0, 0), {"cfa": "RGGB"}, ValueError, r"empty image; got shape \(1, 1, 0, 0\)"),
            (torch.zeros(5), {}, ValueError, r"\(5,\)"),
            (torch.zeros(1, 1, 1, 4, 4), {}, ValueError, r"\(1, 1, 1, 4, 4\)"),
            (torch.zeros(4, 4, dtype=torch.int64), {}, TypeError, "int64"),
            (np.zeros((4, 4)), {}, TypeError, "ndarray"),
            (torch.zeros(4, 4), {"bits": 0}, ValueError, "0"),
            (torch.zeros(4, 4, dtype=torch.float16), {"bits": 12}, ValueError, "12"),
            (torch.zeros(4, 4), {"method": "magic"}, ValueError, "magic"),
            (torch.zeros(4, 4), {"neighborhood": 6}, ValueError, "6"),
            (torch.zeros(4, 4), {"sigma": 0}, ValueError, "0"),
            (torch.zeros(4, 4), {"max_iter": -1}, ValueError, "-1"),
            (torch.zeros(4, 4), {"max_iter": 2.0}, TypeError, "2.0"),
            (torch.zeros(4, 4), {"workers": 0}, ValueError, "0"),
            (torch.zeros(4, 4), {"a1": -0.1}, ValueError, "-0.1"),
            (torch.zeros(4, 4), {"return_info": 1}, TypeError, "1"),
            (torch.zeros(4, 4), {"method": "paper", "init": "zeros"}, TypeError, "init"),
            (torch.zeros(4, 4), {"method": "fast", "init": "random"}, ValueError, "random"),
            (torch.zeros(4, 4), {"method": "fast", "rel_tol": -1.0}, ValueError, "-1.0"),
            (torch.zeros(4, 4), {"method": "fast", "window": 1}, ValueError, "1"),
            (torch.zeros(4, 4), {"method": "fast", "contract": True}, TypeError, "contract"),
            (torch.zeros(4, 4), {"neighborhood": [8]}, ValueError, r"neighborhood must be one of 4, 8; got \[8\]"),
            (torch.zeros(4, 4), {"neighborhood": "8"}, ValueError, "'8'"),
            (torch.zeros(4, 4), {"method": "fast", "speed": 3}, TypeError, "speed"),
            (torch.zeros(4, 4), {"method": "guided", "colour": 1}, TypeError, "colour"),
            (torch.zeros(4, 4), {"method": "guided", "denoise": -1.0}, ValueError, "-1.0"),
            (torch.zeros(4, 4), {"method": "guided", "denoise": "a"}, TypeError, "'a'"),
            (torch.zeros(4, 4), {"method": "guided", "tile": 8}, TypeError, "tile"),
        ],
    )
    def test_exceptions(self, modulus: object, kwargs: dict, error: type, text: str) -> None:
        with pytest.raises(error, match=text):
            unwrap_single(modulus, **kwargs)  # type: ignore[arg-type]

    def test_neighborhood_list_is_a_value_error(self) -> None:
        # Regression: neighborhood=[8] raised "unhashable type: 'list'" instead of a ValueError naming the value.
        for call in (
            lambda: unwrap_single(torch.zeros(4, 4), neighborhood=[8]),
            lambda: SingleShotUnwrap(neighborhood=[8]),
        ):
            with pytest.raises(ValueError, match=r"neighborhood must be one of 4, 8; got \[8\]"):
                call()

    def test_module_validates_in_init(self) -> None:
        with pytest.raises(ValueError, match="magic"):
            SingleShotUnwrap(method="magic")
        with pytest.raises(TypeError, match="tile"):
            SingleShotUnwrap(method="paper", tile=8)


@pytest.mark.slow
def test_fast_energy_not_above_paper_on_a_real_scene(shared_hdr) -> None:  # noqa: ANN001
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(shared_hdr / "hdr-samples" / "memorial.hdr"))
    rgb = np.maximum(np.asarray(inp.read_image(0, 0, 0, 3, "float"), dtype=np.float64), 0)
    inp.close()
    y = (0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2])[::8, ::8]
    truth = torch.from_numpy(np.floor(np.clip(y / np.percentile(y, 99.9) * 4095, 0, 4095)))
    modulus = truth % 256
    paper = unwrap_single(modulus, method="paper")
    fast = unwrap_single(modulus, method="fast")
    assert float(unwrap_energy(fast)) <= float(unwrap_energy(paper)) * 1.001
