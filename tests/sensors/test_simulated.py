"""Tests for the simulated sensors: noise statistics against the model, determinism, fixed pattern, exactness
without noise, shapes and errors."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest
import torch

from torch_modulo import capture_intensity, capture_modulo
from torch_modulo.sensors import (
    FrameStack,
    NoiseModel,
    SimulatedIntensitySensor,
    SimulatedModuloSensor,
    fixed_pattern_gain,
    simulate_capture,
)


def exact_moments(lam: float, q: float, sigma: float, shot: bool = True) -> tuple[float, float]:
    """Mean and variance of max(floor((P + sigma Z) / q), 0), P ~ Poisson(lam) (or P = lam), Z ~ N(0, 1).

    Computed by summing the model's probabilities in float64, independently of the simulator's code.
    """
    if shot:
        spread = 12 * math.sqrt(lam) + 12
        p = torch.arange(max(0, math.floor(lam - spread)), math.ceil(lam + spread) + 1, dtype=torch.float64)
        log_pmf = p * math.log(lam) - lam - torch.lgamma(p + 1) if lam > 0 else torch.where(p == 0, 0.0, -math.inf)
        pmf = torch.exp(log_pmf)
    else:
        p = torch.tensor([lam], dtype=torch.float64)
        pmf = torch.ones(1, dtype=torch.float64)
    if sigma == 0:
        k = torch.floor(p / q).clamp(min=0)
        mean = float((pmf * k).sum())
        return mean, float((pmf * k**2).sum()) - mean**2
    lo = math.floor((float(p.min()) - 10 * sigma) / q) - 1
    hi = math.ceil((float(p.max()) + 10 * sigma) / q) + 1
    k = torch.arange(lo, hi + 1, dtype=torch.float64)
    normal = torch.distributions.Normal(0.0, 1.0)
    upper = normal.cdf((q * (k[None, :] + 1) - p[:, None]) / sigma)
    lower = normal.cdf((q * k[None, :] - p[:, None]) / sigma)
    prob = (pmf[:, None] * (upper - lower)).sum(0)  # P(floor = k)
    value = k.clamp(min=0)
    mean = float((prob * value).sum())
    return mean, float((prob * value**2).sum()) - mean**2


class TestNoiseStatistics:
    """Mean and variance of many pixels of a flat field match the model within statistical tolerance."""

    N = 160  # 160 x 160 = 25600 samples per case

    @pytest.mark.parametrize(
        "radiance, tau, noise",
        [
            (1000.0, 1.0, NoiseModel()),  # the default: shot noise, 1 e- read noise
            (500.0, 2.0, NoiseModel(electrons_per_count=4.0, read_noise=3.0)),
            (0.0, 3.0, NoiseModel(read_noise=0.0, dark_current=20.0)),  # a dark frame: Poisson(60) exactly
            (10.3, 1.0, NoiseModel(electrons_per_count=2.0, read_noise=2.5, shot_noise=False)),
            (0.5, 1.0, NoiseModel(read_noise=2.0)),  # low light: the counter clips at 0
            (40.0, 5.0, NoiseModel(electrons_per_count=0.5, read_noise=1.5, dark_current=2.0)),
        ],
    )
    def test_flat_field(self, radiance: float, tau: float, noise: NoiseModel) -> None:
        sensor = SimulatedIntensitySensor(bits=16, noise=noise, seed=11)
        frames = sensor(torch.full((1, 1, self.N, self.N), radiance, dtype=torch.float64), [tau]).frames
        q = noise.electrons_per_count
        lam = q * tau * radiance + noise.dark_current * tau
        mean, var = exact_moments(lam, q, noise.read_noise, noise.shot_noise)
        n = frames.numel()
        sample_mean = float(frames.mean())
        sample_var = float(frames.var())
        assert abs(sample_mean - mean) < 5 * math.sqrt(var / n) + 1e-9, (sample_mean, mean)
        assert abs(sample_var - var) < 5 * var * math.sqrt(2 / (n - 1)) + 1e-9, (sample_var, var)

    def test_model_differs_from_noise_free(self) -> None:
        """The test above can fail: a sensor without read noise does not match the moments with read noise."""
        frames = SimulatedIntensitySensor(bits=16, noise=NoiseModel(read_noise=0.0), seed=0)(
            torch.full((1, 1, self.N, self.N), 1000.0), [1.0]
        ).frames
        mean, var = exact_moments(1000.0, 1.0, 10.0)
        assert abs(float(frames.var()) - var) > 5 * var * math.sqrt(2 / (frames.numel() - 1))

    def test_modulo_is_wrapped_intensity(self) -> None:
        """Same seed, same draws: the modulo frames are the unclipped counts mod 2^bits."""
        radiance = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0)) * 3000
        noise = NoiseModel(electrons_per_count=2.0, read_noise=1.5, dark_current=1.0, prnu=0.02)
        counts = SimulatedIntensitySensor(bits=24, noise=noise, seed=5)(radiance, [1.0, 3.0]).frames
        assert float(counts.max()) < 2**24 - 1  # nothing clipped
        modulo = SimulatedModuloSensor(bits=8, noise=noise, seed=5)(radiance, [1.0, 3.0])
        assert torch.equal(modulo.moduli, torch.remainder(counts, 256))
        clipped = SimulatedIntensitySensor(bits=8, noise=noise, seed=5)(radiance, [1.0, 3.0])
        assert torch.equal(clipped.frames, counts.clamp(max=255))
        assert float(modulo.moduli.max()) <= 255 and float(modulo.moduli.min()) >= 0


class TestNoiseFree:
    @pytest.mark.parametrize(
        "noise", [None, NoiseModel(shot_noise=False, read_noise=0.0), NoiseModel(3.7, 0.0, 0.0, 0.0, False)]
    )
    def test_equals_capture_models(self, noise: NoiseModel | None, dtype: torch.dtype) -> None:
        g = torch.Generator().manual_seed(2)
        radiance = (torch.rand(3, 2, 9, 7, generator=g) * 5000).to(dtype)
        taus = torch.tensor([[1.0, 7.0, 49.0], [0.5, 3.0, 300.0], [2.0, 2.5, 3.0]])
        stack = SimulatedModuloSensor(bits=8, noise=noise)(radiance, taus)
        clipped = SimulatedIntensitySensor(bits=8, noise=noise)(radiance, taus)
        for i in range(3):
            expected = capture_modulo(radiance, taus[:, i].to(dtype), bits=8)
            assert torch.equal(stack.moduli[:, i], expected)
            assert torch.equal(clipped.frames[:, i], capture_intensity(radiance, taus[:, i].to(dtype), bits=8))
        assert stack.moduli.dtype == dtype

    def test_shared_exposures_and_per_image(self) -> None:
        radiance = torch.rand(4, 3, 5, 5, generator=torch.Generator().manual_seed(3)) * 900
        taus = [1.0, 10.0, 100.0]
        batched = simulate_capture(radiance, taus, bits=6)
        for b in range(4):
            assert torch.equal(batched[b], simulate_capture(radiance[b], taus, bits=6))
            for i, t in enumerate(taus):
                assert torch.equal(batched[b, i], capture_modulo(radiance[b], t, bits=6))

    def test_unit(self) -> None:
        radiance = torch.tensor([[[0.5, 30.0, 300.0]]])
        out = simulate_capture(radiance, [1.0, 4.0], bits=8)
        assert out.tolist() == [[[[0.0, 30.0, 44.0]]], [[[2.0, 120.0, 176.0]]]]  # floor(tau E) mod 256 by hand
        clip = simulate_capture(radiance, [1.0, 4.0], bits=8, wrap=False)
        assert clip.tolist() == [[[[0.0, 30.0, 255.0]]], [[[2.0, 120.0, 255.0]]]]

    def test_counts_beyond_float32(self) -> None:
        """Counts above 2^24 are computed in float64, so the low bits stay right for float32 radiance."""
        radiance = torch.tensor([[[[5000001.0]]]])  # exact in float32; 7x that is not
        noise = NoiseModel(read_noise=0.0, shot_noise=False, dark_current=0.001)  # adds 0.007 counts: no change
        out = simulate_capture(radiance, [7.0], bits=8, noise=noise)
        assert out.dtype == torch.float32
        assert out.item() == 35000007 % 256

    def test_half_precision_radiance(self) -> None:
        radiance = torch.full((1, 1, 4, 4), 3000.0, dtype=torch.float16)
        noise = NoiseModel(read_noise=0.0, shot_noise=False, dark_current=0.01)
        out = simulate_capture(radiance, [1.0], bits=11, noise=noise)
        assert out.dtype == torch.float16 and bool((out == 3000 % 2048).all())

    def test_prnu_only_is_deterministic_gain(self) -> None:
        radiance = torch.full((1, 2, 32, 32), 100.0, dtype=torch.float64)
        noise = NoiseModel(read_noise=0.0, shot_noise=False, prnu=0.05)
        sensor = SimulatedIntensitySensor(bits=16, noise=noise, fpn_seed=9)
        gain = fixed_pattern_gain((2, 32, 32), 0.05, seed=9, dtype=torch.float64)
        expected = torch.floor(radiance * gain * 2.0)
        assert torch.equal(sensor(radiance, [2.0]).frames[:, 0], expected)
        assert torch.equal(sensor(radiance, [2.0]).frames[:, 0], expected)  # fixed: same pattern every capture


class TestDeterminism:
    def _capture(self, seed: int) -> FrameStack:
        radiance = torch.rand(2, 3, 12, 12, generator=torch.Generator().manual_seed(0)) * 2000
        return SimulatedModuloSensor(bits=8, noise=NoiseModel(prnu=0.01), seed=seed)(radiance, [1.0, 8.0])

    def test_same_seed_same_frames(self) -> None:
        assert self._capture(3) == self._capture(3)
        assert self._capture(3) != self._capture(4)

    def test_stream_advances_and_resets(self) -> None:
        radiance = torch.full((1, 1, 16, 16), 500.0)
        sensor = SimulatedModuloSensor(bits=8, seed=1)
        first = sensor(radiance, [1.0]).moduli
        second = sensor(radiance, [1.0]).moduli
        assert not torch.equal(first, second)
        sensor.manual_seed(1)
        assert torch.equal(sensor(radiance, [1.0]).moduli, first)

    def test_same_frames_in_a_new_process(self) -> None:
        code = (
            "import torch;from torch_modulo.sensors import SimulatedModuloSensor, NoiseModel;"
            "r=torch.rand(2,3,12,12,generator=torch.Generator().manual_seed(0))*2000;"
            "s=SimulatedModuloSensor(bits=8,noise=NoiseModel(prnu=0.01),seed=3)(r,[1.0,8.0]);"
            "print(s.moduli.flatten().tolist())"
        )
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
        assert eval(out.stdout) == self._capture(3).moduli.flatten().tolist()

    def test_fixed_pattern_per_instance(self) -> None:
        radiance = torch.full((1, 1, 64, 64), 1000.0)
        noise = NoiseModel(shot_noise=False, read_noise=0.0, prnu=0.02)
        a = SimulatedIntensitySensor(bits=16, noise=noise, seed=0)
        b = SimulatedIntensitySensor(bits=16, noise=noise, seed=7, fpn_seed=a.fpn_seed)  # other noise, same pattern
        c = SimulatedIntensitySensor(bits=16, noise=noise, seed=0, fpn_seed=99)
        fa, fb, fc = (s(radiance, [1.0]).frames for s in (a, b, c))
        assert torch.equal(fa, fb)
        assert not torch.equal(fa, fc)
        rel = fa / 1000.0 - 1
        assert 0.015 < float(rel.std()) < 0.025  # the pattern has the requested spread

    def test_pixel_means_follow_the_pattern(self) -> None:
        """With shot noise too, averaging many captures recovers each pixel's fixed gain."""
        noise = NoiseModel(read_noise=1.0, prnu=0.05)
        sensor = SimulatedIntensitySensor(bits=16, noise=noise, seed=0)
        radiance = torch.full((1, 1, 16, 16), 2000.0)
        frames = sensor(radiance, [1.0] * 32).frames[0, :, 0]  # 32 captures
        gain = sensor.gain_map((1, 16, 16), "cpu", torch.float32)[0]
        corr = torch.corrcoef(torch.stack([frames.mean(0).flatten(), gain.flatten()]))[0, 1]
        assert float(corr) > 0.95

    def test_generator_argument(self) -> None:
        radiance = torch.full((1, 1, 8, 8), 300.0)
        a = simulate_capture(radiance, [1.0], noise=NoiseModel(), generator=torch.Generator().manual_seed(5))
        b = simulate_capture(radiance, [1.0], noise=NoiseModel(), generator=torch.Generator().manual_seed(5))
        assert torch.equal(a, b)


class _Captures(torch.utils.data.Dataset):
    """Noisy captures of one flat scene, made in DataLoader workers by one sensor the workers each copy."""

    def __init__(self) -> None:
        self.sensor = SimulatedModuloSensor(bits=8, noise=NoiseModel(), seed=3)

    def __len__(self) -> int:
        return 4

    def __getitem__(self, index: int) -> torch.Tensor:
        return self.sensor(torch.full((1, 1, 8, 8), 900.0), [1.0]).moduli[0, 0]


def _epochs(workers: int) -> list[torch.Tensor]:
    torch.manual_seed(0)
    loader = torch.utils.data.DataLoader(_Captures(), batch_size=1, num_workers=workers)
    return [torch.cat(list(loader)) for _ in range(2)]


def test_dataloader_workers_do_not_repeat_each_others_noise() -> None:
    first, second = _epochs(2)
    assert not torch.equal(first[0], first[1])  # items 0 and 1 come from the two workers' first draws
    assert not torch.equal(first, second)  # a new epoch, new noise
    again = _epochs(2)
    assert torch.equal(again[0], first) and torch.equal(again[1], second)  # repeatable for a given seed


@pytest.mark.parametrize("name", ["seed", "fpn_seed"])
def test_seed_out_of_the_generators_range(name: str) -> None:
    with pytest.raises(ValueError, match=rf"{name} must be in \[-2\*\*63, 2\*\*64\); got 18446744073709551616"):
        SimulatedModuloSensor(**{name: 2**64})
    assert SimulatedModuloSensor(seed=2**64 - 1).fpn_seed == 0


class TestSensorContract:
    def test_smoke_and_metadata(self) -> None:
        sensor = SimulatedModuloSensor(bits=10, seed=2)
        stack = sensor(torch.rand(2, 3, 4, 5) * 100, [1.0, 4.0])
        assert isinstance(stack, FrameStack)
        assert stack.shape == (2, 2, 3, 4, 5) and stack.bits == 10 and stack.kind == "modulo"
        assert stack.metadata["sensor"] == "SimulatedModuloSensor"
        assert stack.metadata["noise"] == NoiseModel().to_dict()
        assert stack.metadata["seed"] == 2
        dark = sensor.capture(torch.zeros(3, 4, 5), 2.0).moduli  # read noise makes a few counts in the dark
        assert dark.shape == (1, 1, 3, 4, 5) and 0 < float(dark.mean()) < 1
        noiseless = SimulatedModuloSensor(bits=10, noise=None).capture(torch.zeros(3, 4, 5), 2.0)
        assert torch.equal(noiseless.moduli, torch.zeros(1, 1, 3, 4, 5))
        assert "bits=10" in repr(sensor)

    @pytest.mark.parametrize("shape", [(3, 4, 5), (1, 1, 1, 1), (2, 3, 8, 6), (0, 3, 4, 4)])
    def test_cardinality(self, shape: tuple[int, ...]) -> None:
        out = simulate_capture(torch.ones(shape) * 50, [1.0, 2.0, 4.0], noise=NoiseModel())
        expected = (3, *shape) if len(shape) == 3 else (shape[0], 3, *shape[1:])
        assert out.shape == expected

    def test_input_unmodified_dtype_device(self, device: torch.device, dtype: torch.dtype) -> None:
        radiance = (torch.rand(2, 1, 6, 6) * 400).to(device=device, dtype=dtype)
        copy = radiance.clone()
        stack = SimulatedModuloSensor(bits=8, noise=NoiseModel(prnu=0.01))(radiance, [1.0, 3.0])
        assert torch.equal(radiance, copy)
        assert stack.moduli.dtype == dtype and stack.moduli.device.type == device.type

    def test_explicit_gain(self) -> None:
        radiance = torch.full((1, 1, 2, 2), 10.0)
        gain = torch.tensor([[1.0, 2.0], [0.5, 0.0]])
        out = simulate_capture(radiance, [1.0], noise=NoiseModel(read_noise=0.0, shot_noise=False), gain=gain)
        assert out[0, 0, 0].tolist() == [[10.0, 20.0], [5.0, 0.0]]
        assert torch.equal(simulate_capture(radiance, [1.0], gain=gain), out)  # a gain map alone, noise=None
        with pytest.raises(ValueError, match=r"gain of shape \(3,\) does not broadcast"):
            simulate_capture(radiance, [1.0], noise=NoiseModel(), gain=torch.ones(3))
        with pytest.raises(ValueError, match="gain must be >= 0; got min -1.0"):
            simulate_capture(radiance, [1.0], noise=NoiseModel(), gain=-torch.ones(1))

    def test_errors(self) -> None:
        good = torch.ones(1, 1, 2, 2)
        with pytest.raises(ValueError, match="radiance must be >= 0; got min -1.0"):
            simulate_capture(-good, [1.0])
        with pytest.raises(ValueError, match="1 NaN"):
            simulate_capture(torch.tensor([[[float("nan")]]]), [1.0], noise=NoiseModel())
        with pytest.raises(TypeError, match="floating-point tensor; got dtype torch.int64"):
            simulate_capture(torch.ones(1, 1, 2, 2, dtype=torch.long), [1.0])
        with pytest.raises(ValueError, match=r"radiance must have shape .*got \(2, 2\)"):
            simulate_capture(torch.ones(2, 2), [1.0])
        with pytest.raises(ValueError, match="exposures must be positive; got -1.0"):
            simulate_capture(good, [1.0, -1.0])
        with pytest.raises(ValueError, match=r"exposures must have shape \(M,\) or \(B, M\) with B = 1.*\(2, 2\)"):
            simulate_capture(good, torch.ones(2, 2))
        with pytest.raises(TypeError, match="noise must be a NoiseModel or None; got dict"):
            simulate_capture(good, [1.0], noise={"read_noise": 1.0})  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="noise must be a NoiseModel or None; got float"):
            SimulatedModuloSensor(noise=0.0)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="bits must be >= 1; got 0"):
            SimulatedModuloSensor(bits=0)
        with pytest.raises(TypeError, match="seed must be an int; got 1.5"):
            SimulatedModuloSensor(seed=1.5)  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="seed must be an int; got 'a'"):
            SimulatedModuloSensor().manual_seed("a")  # type: ignore[arg-type]

    @pytest.mark.parametrize(
        "kwargs, error, message",
        [
            ({"electrons_per_count": 0.0}, ValueError, "electrons_per_count must be > 0; got 0.0"),
            ({"electrons_per_count": -1.0}, ValueError, "electrons_per_count must be finite and >= 0; got -1.0"),
            ({"read_noise": -0.5}, ValueError, "read_noise must be finite and >= 0; got -0.5"),
            ({"dark_current": float("nan")}, ValueError, "dark_current must be finite and >= 0; got nan"),
            ({"prnu": "1%"}, TypeError, "prnu must be a number; got '1%'"),
            ({"read_noise": True}, TypeError, "read_noise must be a number; got True"),
            ({"shot_noise": 1}, TypeError, "shot_noise must be a bool; got 1"),
        ],
    )
    def test_noise_model_errors(self, kwargs: dict, error: type[Exception], message: str) -> None:
        with pytest.raises(error, match=message):
            NoiseModel(**kwargs)

    def test_noise_model_values(self) -> None:
        model = NoiseModel(electrons_per_count=2, read_noise=1)
        assert model.electrons_per_count == 2.0 and isinstance(model.read_noise, float)
        assert not model.is_noiseless and NoiseModel(read_noise=0, shot_noise=False).is_noiseless
        with pytest.raises(AttributeError):
            model.read_noise = 3.0  # type: ignore[misc]

    @pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
    def test_cuda_generator(self) -> None:
        radiance = torch.full((1, 1, 32, 32), 500.0, device="cuda")
        a = SimulatedModuloSensor(bits=8, seed=4)(radiance, [1.0, 4.0])
        b = SimulatedModuloSensor(bits=8, seed=4)(radiance, [1.0, 4.0])
        assert a == b and a.device.type == "cuda"
