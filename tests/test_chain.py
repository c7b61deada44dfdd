"""Layers that chain: capture_stack, MultiExposureCapture and ExposureStack (torch_modulo/capture.py), and
MultiExposureUnwrap taking what the capture layer returns (torch_modulo/multishot/unwrap.py)."""

from __future__ import annotations

import pickle

import pytest
import torch
from torch import nn
from torch.utils.data import DataLoader, Dataset

import torch_modulo as tm
from torch_modulo._chunks import CPU_CHUNK
from torch_modulo.sensors import FrameStack

TAUS = [1.0, 16.0, 256.0]


def _radiance(shape: tuple[int, ...], device: torch.device, dtype: torch.dtype, seed: int = 0) -> torch.Tensor:
    """Radiance spanning about 12 stops, so the longer exposures roll over many times."""
    gen = torch.Generator().manual_seed(seed)
    return torch.exp2(torch.rand(shape, generator=gen, dtype=torch.float64) * 12 - 6).to(device, dtype)


def _functional(radiance: torch.Tensor, taus: list[float], bits: int) -> torch.Tensor:
    """The functional path: one capture_modulo per exposure, stacked on dim 1, then unwrap_multi."""
    stack = torch.stack([tm.capture_modulo(radiance, t, bits) for t in taus], dim=1)
    return tm.unwrap_multi(stack, taus, bits)


class TestCaptureStack:
    @pytest.mark.parametrize("shape", [(1, 1, 1, 3), (2, 3, 5, 7), (0, 3, 4, 4)])
    def test_equals_stacked_capture_modulo(
        self, shape: tuple[int, ...], device: torch.device, dtype: torch.dtype
    ) -> None:
        x = _radiance(shape, device, dtype)
        expected = torch.stack([tm.capture_modulo(x, t, 8) for t in TAUS], dim=1)
        out = tm.capture_stack(x, TAUS, 8)
        assert out.shape == (shape[0], len(TAUS), *shape[1:]) and out.dtype == dtype and out.device == x.device
        assert torch.equal(out, expected)

    def test_several_chunks_and_non_contiguous_input(self) -> None:
        cpu = torch.device("cpu")
        x = _radiance((2, 3, 5, CPU_CHUNK // 11), cpu, torch.float32)
        expected = torch.stack([tm.capture_modulo(x, t, 8) for t in TAUS], dim=1)
        assert torch.equal(tm.capture_stack(x, TAUS, 8), expected)
        xt = x.transpose(-1, -2)
        expected_t = torch.stack([tm.capture_modulo(xt, t, 8) for t in TAUS], dim=1)
        assert torch.equal(tm.capture_stack(xt, TAUS, 8), expected_t)

    def test_per_batch_exposures(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _radiance((2, 1, 3, 4), device, dtype)
        taus = torch.tensor([[1.0, 8.0], [2.0, 32.0]], device=device)
        expected = torch.stack([tm.capture_modulo(x, taus[:, i], 8) for i in range(2)], dim=1)
        assert torch.equal(tm.capture_stack(x, taus, 8), expected)

    def test_unbatched_input_gives_unbatched_stack(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _radiance((3, 4, 5), device, dtype)
        out = tm.capture_stack(x, TAUS, 8)
        assert out.shape == (3, 3, 4, 5)
        assert torch.equal(out, tm.capture_stack(x[None], TAUS, 8)[0])

    def test_input_is_not_modified(self, device: torch.device) -> None:
        x = _radiance((1, 3, 4, 4), device, torch.float32)
        before = x.clone()
        tm.capture_stack(x, TAUS, 8)
        assert torch.equal(x, before)

    def test_straight_through_gradient_matches_per_exposure(self, device: torch.device) -> None:
        x = _radiance((1, 2, 3, 3), device, torch.float64).requires_grad_()
        tm.capture_stack(x, TAUS, 8, straight_through=True).sum().backward()
        assert torch.allclose(x.grad, torch.full_like(x, sum(TAUS)))
        y = x.detach().clone().requires_grad_()
        out = tm.capture_stack(y, TAUS, 8)
        assert torch.equal(out, torch.stack([tm.capture_modulo(y, t, 8) for t in TAUS], dim=1))

    def test_warns_when_counts_lose_bits(self) -> None:
        with pytest.warns(UserWarning, match="use float64"):
            tm.capture_stack(torch.full((1, 1, 1, 1), 1e6), [1.0, 1e3], 8)

    @pytest.mark.parametrize(
        ("radiance", "exposures", "error", "match"),
        [
            (torch.ones(4, 4), TAUS, ValueError, r"radiance must have shape \(B, C, H, W\) or \(C, H, W\)"),
            (torch.ones(1, 1, 2, 2, dtype=torch.int64), TAUS, TypeError, "floating-point"),
            (torch.full((1, 1, 2, 2), -1.0), TAUS, ValueError, "radiance must be >= 0; got min -1.0"),
            (torch.ones(1, 1, 2, 2), [1.0, -2.0], ValueError, "exposures must be positive; got -2.0"),
            (torch.ones(1, 1, 2, 2), 4.0, ValueError, r"exposures must have shape .*; got \(\)"),
            (torch.ones(1, 1, 2, 2), [], ValueError, r"M >= 1; got \(0,\)"),
            (torch.ones(2, 1, 2, 2), torch.ones(3, 2), ValueError, r"B = 2 and M >= 1; got \(3, 2\)"),
            (torch.ones(1, 2, 2), torch.ones(1, 2), ValueError, r"must have shape \(M,\) and M >= 1; got \(1, 2\)"),
        ],
    )
    def test_exceptions(self, radiance: torch.Tensor, exposures: object, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            tm.capture_stack(radiance, exposures, 8)  # type: ignore[arg-type]

    def test_bad_flag(self) -> None:
        with pytest.raises(TypeError, match="straight_through must be a bool; got 1"):
            tm.capture_stack(torch.ones(1, 1, 1, 1), TAUS, 8, straight_through=1)  # type: ignore[arg-type]


class TestMultiExposureCapture:
    def test_returns_exposure_stack(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _radiance((2, 3, 4, 4), device, dtype)
        out = tm.MultiExposureCapture(TAUS, bits=8).to(device)(x)
        assert isinstance(out, tm.ExposureStack)
        moduli, exposures = out
        assert torch.equal(moduli, tm.capture_stack(x, TAUS, 8))
        assert exposures.tolist() == TAUS and exposures.dtype == torch.float64 and exposures.device == x.device

    def test_module_equals_function(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _radiance((1, 3, 6, 5), device, dtype)
        layer = tm.MultiExposureCapture(torch.tensor([2.0, 30.0]), bits=6, straight_through=True)
        assert torch.equal(layer(x).moduli, tm.capture_stack(x, [2.0, 30.0], 6, straight_through=True))

    def test_exposures_are_a_buffer(self) -> None:
        layer = tm.MultiExposureCapture(TAUS, bits=8)
        assert "exposures" in dict(layer.named_buffers())
        assert "exposures" not in layer.state_dict()  # like ModuloCapture: a configuration, not a learned state
        assert repr(layer) == "MultiExposureCapture(exposures=[1.0, 16.0, 256.0], bits=8, straight_through=False)"
        assert layer.to("meta").exposures.device.type == "meta"

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"exposures": [1.0, 0.0]}, ValueError, "exposures must be positive; got 0.0"),
            ({"exposures": 4.0}, ValueError, r"sequence or \(M,\) tensor with M >= 1; got shape \(\)"),
            ({"exposures": torch.ones(1, 2)}, ValueError, r"got shape \(1, 2\)"),
            ({"exposures": "16"}, TypeError, "exposures must be a positive number"),
            ({"exposures": TAUS, "bits": 0}, ValueError, "bits must be >= 1; got 0"),
            ({"exposures": TAUS, "straight_through": "no"}, TypeError, "straight_through must be a bool"),
        ],
    )
    def test_exceptions(self, kwargs: dict[str, object], error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            tm.MultiExposureCapture(**kwargs)  # type: ignore[arg-type]


class TestChain:
    @pytest.mark.parametrize("bits", [8, 10])
    def test_sequential_equals_functional_path(self, bits: int, device: torch.device, dtype: torch.dtype) -> None:
        x = _radiance((2, 3, 8, 8), device, dtype)
        chain = nn.Sequential(tm.MultiExposureCapture(exposures=TAUS, bits=bits), tm.MultiExposureUnwrap(bits=bits))
        assert torch.equal(chain.to(device)(x), _functional(x, TAUS, bits))

    def test_issue_example(self) -> None:
        radiance = _radiance((1, 3, 16, 16), torch.device("cpu"), torch.float32)
        chain = nn.Sequential(
            tm.MultiExposureCapture(exposures=[1.0, 16.0, 256.0], bits=8), tm.MultiExposureUnwrap(bits=8)
        )
        restored = chain(radiance)
        assert torch.equal(restored, _functional(radiance, [1.0, 16.0, 256.0], 8))
        # Eq. 7's convention: the lower edge of the final cell, within one count of the longest exposure.
        assert bool(((radiance - restored) * 256.0).lt(1.0).all()) and bool(restored.le(radiance).all())

    def test_unwrap_still_takes_moduli_and_exposures(self, device: torch.device) -> None:
        x = _radiance((1, 3, 4, 4), device, torch.float32)
        moduli, exposures = tm.MultiExposureCapture(TAUS, bits=8)(x)
        layer = tm.MultiExposureUnwrap(bits=8)
        expected = _functional(x, TAUS, 8)
        assert torch.equal(layer(moduli, exposures), expected)
        assert torch.equal(layer(moduli, TAUS), expected)
        assert torch.equal(layer((moduli, exposures)), expected)
        assert torch.equal(layer(tm.ExposureStack(moduli, exposures)), expected)

    def test_unwrap_takes_a_frame_stack(self) -> None:
        x = _radiance((2, 1, 4, 4), torch.device("cpu"), torch.float32)
        stack = FrameStack(tm.capture_stack(x, TAUS, 8), TAUS, bits=8)
        assert torch.equal(tm.MultiExposureUnwrap(bits=8)(stack), _functional(x, TAUS, 8))
        with pytest.raises(ValueError, match="stack holds bits=8 frames but this layer decodes bits=10"):
            tm.MultiExposureUnwrap(bits=10)(stack)
        frames = torch.stack([tm.capture_intensity(x, t, 8) for t in TAUS], dim=1)
        with pytest.raises(ValueError, match="decodes modulo frames; got a stack of kind='intensity'"):
            tm.MultiExposureUnwrap(bits=8)(FrameStack(frames, TAUS, bits=8, kind="intensity"))

    def test_unwrap_without_exposures_says_what_to_pass(self) -> None:
        with pytest.raises(TypeError, match="needs the exposures: call it with .*; got Tensor alone"):
            tm.MultiExposureUnwrap(bits=8)(torch.zeros(1, 3, 1, 2, 2))

    def test_noise_aware_decoder_chains(self) -> None:
        x = _radiance((1, 1, 8, 8), torch.device("cpu"), torch.float64) * 40
        taus = tm.plan_exposures(12, bits=8, noise="photon-counting")
        stack = tm.MultiExposureCapture(taus, bits=8)(x)
        layer = tm.MultiExposureUnwrap(bits=8, noise="photon-counting")
        assert torch.equal(layer(stack), tm.unwrap_multi(stack.moduli, taus, 8, noise="photon-counting"))

    def test_return_counts_and_paper(self) -> None:
        x = _radiance((1, 1, 4, 4), torch.device("cpu"), torch.float64)
        stack = tm.MultiExposureCapture(TAUS, bits=8)(x)
        for kwargs in ({"return_counts": True}, {"method": "paper"}):
            layer = tm.MultiExposureUnwrap(bits=8, **kwargs)  # type: ignore[arg-type]
            assert torch.equal(layer(stack), tm.unwrap_multi(stack.moduli, TAUS, 8, **kwargs))  # type: ignore[arg-type]


class TestStackForms:
    """One stack, three forms: the function's tensor, the layer's ExposureStack, the sensor's FrameStack."""

    def test_function_gives_the_layers_moduli_as_a_tensor(self) -> None:
        x = _radiance((2, 3, 4, 4), torch.device("cpu"), torch.float32)
        moduli = tm.capture_stack(x, TAUS, 8)
        layer_form = tm.MultiExposureCapture(TAUS, bits=8)(x)
        assert type(moduli) is torch.Tensor and type(layer_form) is tm.ExposureStack
        assert torch.equal(layer_form.moduli, moduli)
        assert torch.equal(layer_form.exposures, torch.tensor(TAUS, dtype=torch.float64))

    def test_conversions_decode_the_same(self) -> None:
        x = _radiance((2, 3, 4, 4), torch.device("cpu"), torch.float32)
        layer_form = tm.MultiExposureCapture(TAUS, bits=8)(x)
        sensor_form = FrameStack(*layer_form, bits=8)
        back = sensor_form.to_exposure_stack()
        assert back.moduli is layer_form.moduli and torch.equal(back.exposures, layer_form.exposures)
        expected = _functional(x, TAUS, 8)
        unwrap = tm.MultiExposureUnwrap(bits=8)
        for form in (layer_form, sensor_form, back):
            assert torch.equal(unwrap(form), expected)
        assert torch.equal(tm.unwrap_multi(sensor_form.frames, sensor_form.exposures, sensor_form.bits), expected)

    def test_unwrap_with_exposures_refuses_a_stack(self) -> None:
        # Explicit exposures go with a moduli tensor; a stack alongside them is refused as unwrap_multi refuses it.
        layer_form = tm.MultiExposureCapture(TAUS, bits=8)(_radiance((1, 1, 2, 2), torch.device("cpu"), torch.float32))
        with pytest.raises(TypeError, match="moduli must be a torch.Tensor; got ExposureStack"):
            tm.MultiExposureUnwrap(bits=8)(layer_form, TAUS)


class _Scenes(Dataset):
    """Radiance samples (C, H, W), captured by the layer inside the worker."""

    def __init__(self, capture: nn.Module) -> None:
        self.capture = capture

    def __len__(self) -> int:
        return 4

    def __getitem__(self, i: int) -> tuple[tm.ExposureStack, torch.Tensor]:
        x = _radiance((3, 4, 4), torch.device("cpu"), torch.float32, seed=i)
        return self.capture(x), x


class TestPickleAndDataLoader:
    def test_layers_and_stack_pickle(self) -> None:
        x = _radiance((1, 3, 4, 4), torch.device("cpu"), torch.float32)
        chain = nn.Sequential(tm.MultiExposureCapture(TAUS, bits=8), tm.MultiExposureUnwrap(bits=8))
        clone = pickle.loads(pickle.dumps(chain))
        assert torch.equal(clone(x), chain(x))
        stack = pickle.loads(pickle.dumps(chain[0](x)))
        assert isinstance(stack, tm.ExposureStack) and torch.equal(stack.moduli, chain[0](x).moduli)

    def test_dataloader_workers_collate_the_stack(self) -> None:
        loader = DataLoader(_Scenes(tm.MultiExposureCapture(TAUS, bits=8)), batch_size=2, num_workers=1)
        unwrap = tm.MultiExposureUnwrap(bits=8)
        for stack, radiance in loader:
            assert isinstance(stack, tm.ExposureStack)
            assert stack.moduli.shape == (2, 3, 3, 4, 4) and stack.exposures.shape == (2, 3)
            assert torch.equal(unwrap(stack), _functional(radiance, TAUS, 8))


class TestChannelsLast:
    """Regression: channels-last radiance came back from capture -> unwrap in the default layout. Every layer keeps
    the memory format where its output has the input's shape; the stack's frames keep it, and so the decoded image."""

    CL = torch.channels_last

    @staticmethod
    def _frames_channels_last(moduli: torch.Tensor) -> bool:
        frame = moduli[0, 0]
        return frame.permute(1, 2, 0).is_contiguous() and not frame.is_contiguous()

    @pytest.mark.parametrize("shape", [(2, 3, 6, 5), (2, 3, 40, CPU_CHUNK // 60)])  # the second spans CPU chunks
    def test_capture_layers_keep_channels_last(self, shape: tuple[int, ...]) -> None:
        x = _radiance(shape, torch.device("cpu"), torch.float32).contiguous(memory_format=self.CL)
        for layer in (tm.ModuloCapture(4.0, 8), tm.IntensityCapture(4.0, 8)):
            assert layer(x).is_contiguous(memory_format=self.CL)
        assert tm.ModuloWrap(8)(torch.floor(x * 300)).is_contiguous(memory_format=self.CL)
        assert self._frames_channels_last(tm.MultiExposureCapture(TAUS, 8)(x).moduli)

    @pytest.mark.parametrize(
        ("shape", "noise"),
        [
            ((1, 3, 6, 5), None),
            ((2, 3, 6, 5), None),
            ((2, 3, 40, CPU_CHUNK // 60), None),  # spans the CPU chunks
            ((2, 3, 6, 5), "photon-counting"),
        ],
    )
    def test_chain_keeps_channels_last(self, shape: tuple[int, ...], noise: str | None) -> None:
        x = _radiance(shape, torch.device("cpu"), torch.float32)
        taus = TAUS if noise is None else [1.0, 4.0, 16.0]  # ratios the noise model decodes without a warning
        chain = nn.Sequential(tm.MultiExposureCapture(taus, 8), tm.MultiExposureUnwrap(8, noise=noise))
        out = chain(x.contiguous(memory_format=self.CL))
        assert out.is_contiguous(memory_format=self.CL) and not out.is_contiguous()
        assert torch.equal(out, chain(x))

    def test_layer_with_gradients_and_per_batch_exposures(self) -> None:
        x = _radiance((2, 3, 4, 5), torch.device("cpu"), torch.float64).contiguous(memory_format=self.CL)
        stack = tm.MultiExposureCapture(TAUS, 8, straight_through=True)(x.requires_grad_(True))
        out = tm.MultiExposureUnwrap(8)(stack)
        assert out.is_contiguous(memory_format=self.CL)
        assert torch.equal(out, tm.unwrap_multi(stack.moduli, stack.exposures, 8))
        taus = torch.tensor([[1.0, 16.0, 256.0], [2.0, 32.0, 512.0]], dtype=torch.float64)
        moduli = tm.capture_stack(x.detach(), taus, 8)
        assert tm.MultiExposureUnwrap(8)(moduli, taus).is_contiguous(memory_format=self.CL)

    def test_default_layout_kept(self) -> None:
        x = _radiance((2, 3, 6, 5), torch.device("cpu"), torch.float32)
        assert tm.MultiExposureUnwrap(8)(tm.MultiExposureCapture(TAUS, 8)(x)).is_contiguous()
        grey = _radiance((2, 1, 6, 5), torch.device("cpu"), torch.float32).contiguous(memory_format=self.CL)
        assert tm.MultiExposureUnwrap(8)(tm.MultiExposureCapture(TAUS, 8)(grey)).is_contiguous()
        unbatched = _radiance((3, 6, 5), torch.device("cpu"), torch.float32)
        assert tm.MultiExposureUnwrap(8)(tm.MultiExposureCapture(TAUS, 8)(unbatched)).shape == (3, 6, 5)

    def test_compiled_chain_keeps_channels_last(self) -> None:
        x = _radiance((2, 3, 6, 5), torch.device("cpu"), torch.float32).contiguous(memory_format=self.CL)
        chain = nn.Sequential(tm.MultiExposureCapture(TAUS, 8), tm.MultiExposureUnwrap(8))
        with tm.validation(False):
            out = torch.compile(chain, fullgraph=True, backend="eager")(x)
        assert out.is_contiguous(memory_format=self.CL) and torch.equal(out, chain(x))
