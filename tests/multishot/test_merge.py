"""Tests for torch_modulo/multishot/merge.py: the conventional merge, noise-free and noise-weighted."""

from __future__ import annotations

import pytest
import torch
from multishot_helpers import stack

import torch_modulo as tm


class TestMergeIntensity:
    def test_unit_hand_computed(self, device: torch.device, dtype: torch.dtype) -> None:
        # 4 bits (top 15). Pixel 1: valid in both -> mean(5/1, 80/16) = 5; pixel 2: saturated at 16 -> 9/1.
        frames = torch.tensor([[[[5.0, 9.0]]], [[[80.0 % 16 + 0.0, 15.0]]]], device=device, dtype=dtype)
        frames[1, 0, 0, 0] = 15.0 - 1.0  # 14 counts at exposure 16 -> 0.875
        out = tm.merge_intensity(frames, [1.0, 16.0], bits=4)
        assert out.shape == (1, 1, 2)
        assert out[0, 0, 0].item() == pytest.approx((5.0 + 14.0 / 16.0) / 2)
        assert out[0, 0, 1].item() == pytest.approx(9.0)

    def test_fallbacks(self) -> None:
        frames = torch.tensor([[[[15.0, 0.0]]], [[[15.0, 0.0]]]])  # saturated everywhere; black everywhere
        out = tm.merge_intensity(frames, [2.0, 8.0], bits=4)
        assert out.flatten().tolist() == [7.5, 0.0]

    def test_hat_weights_and_module(self) -> None:
        frames = torch.tensor([[[[4.0]]], [[[12.0]]]])
        # hat weights min(I, 15 - I): 4 and 3 -> (4 * 4 + 3 * 12 / 4) / 7
        out = tm.IntensityMerge(bits=4, weights="hat")(frames, [1.0, 4.0])
        assert out.item() == pytest.approx((4 * 4.0 + 3 * 3.0) / 7)
        with pytest.raises(ValueError, match="'box'"):
            tm.merge_intensity(frames, [1.0, 4.0], bits=4, weights="box")

    @pytest.mark.parametrize("half", [torch.float16, torch.bfloat16], ids=str)
    @pytest.mark.parametrize("weights", ["binary", "hat"])
    def test_half_precision_frames_with_long_exposures(self, half: torch.dtype, weights: str) -> None:
        # An exposure of 65536 is inf in float16: computed in the frames' dtype this merged to 0 (and NaN).
        frames = torch.tensor([[[[0.0, 255.0]]], [[[0.0, 255.0]]], [[[65.0, 255.0]]]])
        taus = [1.0, 256.0, 65536.0]
        expected = tm.merge_intensity(frames.double(), taus, 8, weights=weights)
        out = tm.merge_intensity(frames.to(half), taus, 8, weights=weights)
        assert out.dtype == half
        assert torch.allclose(out.double(), expected, rtol=1e-2)
        assert out[0, 0, 0].item() == pytest.approx(65.0 / 65536.0, rel=1e-2)
        noisy = tm.merge_intensity(frames.to(half), taus, 8, noise="photon-counting")
        assert noisy.dtype == half and torch.isfinite(noisy).all() and noisy[0, 0, 0].item() > 0
        # Radiance beyond the dtype's range comes back as inf, not NaN or 0.
        bright = tm.merge_intensity(
            torch.tensor([[[[10.0]]], [[[160.0]]], [[[255.0]]]], dtype=half), [2**-16, 2**-12, 2**-8], 8
        )
        assert bright.item() == (float("inf") if half == torch.float16 else pytest.approx(655360.0, rel=1e-2))

    def test_modulo_beats_intensity_on_fig8_band(self) -> None:
        # Paper Fig. 8: a band 0..255 seen by 4-bit cameras; 2 modulo captures at ratio 16 beat 5 intensity captures.
        band = torch.linspace(0, 255, 2048, dtype=torch.float64).view(1, 1, 1, -1) / 16.0
        mod_taus = [1.0, 16.0]
        modulo = tm.unwrap_multi(stack(band, mod_taus, 4), mod_taus, 4)
        int_taus = [1.0, 2.0, 4.0, 8.0, 16.0]
        frames = torch.stack([tm.capture_intensity(band, t, 4) for t in int_taus], dim=1)
        intensity = tm.merge_intensity(frames, int_taus, 4)
        err_mod = float((modulo - band).abs().mean())
        err_int = float((intensity - band).abs().mean())
        assert err_mod < err_int / 2


class TestMergeIntensityUnderNoise:
    def test_noise_weighted_merge_is_unbiased_and_beats_binary(self) -> None:
        noise = tm.sensors.NoiseModel()
        gen = torch.Generator().manual_seed(0)
        radiance = torch.exp2(4 + 12 * torch.rand(1, 1, 64, 64, generator=gen, dtype=torch.float64))
        taus = [2.0**-8, 2.0**-6, 2.0**-4, 2.0**-2, 1.0]
        frames = tm.sensors.SimulatedIntensitySensor(8, noise, seed=2)(radiance, taus).frames
        weighted = tm.merge_intensity(frames, taus, 8, noise=noise)
        binary = tm.merge_intensity(frames, taus, 8)
        rel_w = (weighted - radiance) / radiance
        rel_b = (binary - radiance) / radiance
        assert abs(float(rel_w.mean())) < 0.01
        assert float(rel_w.abs().median()) < float(rel_b.abs().median())

    def test_module_takes_noise(self) -> None:
        frames = torch.tensor([[[[10.0]]], [[[160.0]]], [[[255.0]]]])
        layer = tm.IntensityMerge(bits=8, noise="photon-counting")
        expected = tm.merge_intensity(frames, [1.0, 16.0, 256.0], 8, noise=tm.sensors.NoiseModel())
        assert torch.equal(layer(frames, [1.0, 16.0, 256.0]), expected)
        assert "noise=NoiseModel" in repr(layer)
        # Saturated everywhere: the shortest frame's estimate (a lower bound).
        top = torch.full((2, 1, 1, 1), 255.0)
        assert tm.merge_intensity(top, [1.0, 2.0], 8, noise="q16").item() == pytest.approx(255.5)

    def test_bad_noise(self) -> None:
        with pytest.raises(TypeError, match="noise must be a NoiseModel or None; got int"):
            tm.merge_intensity(torch.zeros(2, 1, 1, 1), [1.0, 2.0], 8, noise=3)
