"""Tests for FrameStack: validation, shapes, conversion, indexing, equality."""

from __future__ import annotations

import pickle
import re

import numpy as np
import pytest
import torch

from torch_modulo import ExposureStack, capture_modulo
from torch_modulo.sensors import FrameStack


def _stack(b: int = 2, m: int = 3, c: int = 1, h: int = 4, w: int = 5, bits: int = 8, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randint(0, 2**bits, (b, m, c, h, w), generator=g).float()


class TestFrameStack:
    def test_smoke(self) -> None:
        moduli = _stack()
        stack = FrameStack(moduli, [1.0, 4.0, 16.0], bits=8, metadata={"camera": "sim"})
        assert stack.frames is moduli  # no copy
        assert stack.moduli is moduli  # the same tensor under the modulo name
        assert stack.exposures.dtype == torch.float64
        assert stack.exposures.tolist() == [1.0, 4.0, 16.0]
        assert stack.bits == 8 and stack.kind == "modulo"
        assert stack.metadata == {"camera": "sim"}
        assert len(stack) == 2 and stack.batch_size == 2 and stack.num_exposures == 3
        assert stack.shape == (2, 3, 1, 4, 5) and stack.dtype == torch.float32 and stack.device.type == "cpu"
        assert "FrameStack(frames=(2, 3, 1, 4, 5) float32" in repr(stack)

    @pytest.mark.parametrize("shape", [(1, 1, 1, 1, 1), (3, 2, 3, 8, 6), (0, 2, 1, 3, 3)])
    def test_cardinality(self, shape: tuple[int, ...]) -> None:
        moduli = torch.zeros(shape)
        stack = FrameStack(moduli, torch.arange(1, shape[1] + 1), bits=4)
        assert stack.shape == shape
        assert stack.exposure_matrix().shape == shape[:2]

    def test_unbatched_stack(self) -> None:
        moduli = _stack()[0]
        stack = FrameStack(moduli, [1.0, 2.0, 4.0])
        assert stack.shape == (1, 3, 1, 4, 5)
        assert torch.equal(stack.moduli[0], moduli)

    def test_per_item_exposures(self) -> None:
        taus = torch.tensor([[1.0, 2.0, 4.0], [1.0, 3.0, 9.0]])
        stack = FrameStack(_stack(), taus)
        assert torch.equal(stack.exposures, taus.double())
        assert torch.equal(stack[1].exposures, taus[1:].double())

    def test_metadata_copied(self) -> None:
        meta = {"list": [1, 2]}
        stack = FrameStack(_stack(), [1.0, 2.0, 4.0], metadata=meta)
        meta["list"].append(3)
        assert stack.metadata == {"list": [1, 2]}

    def test_intensity_kind(self) -> None:
        frames = torch.full((1, 2, 1, 2, 2), 255.0)
        stack = FrameStack(frames, [1.0, 2.0], bits=8, kind="intensity")
        assert stack.kind == "intensity"
        assert stack.frames is frames and stack.moduli is frames  # the old name still works, without a warning
        assert "kind='intensity'" in repr(stack)

    def test_pickles(self) -> None:
        stack = FrameStack(_stack(), [1.0, 2.0, 4.0], bits=8, metadata={"camera": "sim"}, kind="intensity")
        assert pickle.loads(pickle.dumps(stack)) == stack


class TestToExposureStack:
    """The sensors' form of a stack to the layers' form, and back."""

    def test_fields_are_the_frames_and_exposures(self) -> None:
        moduli = _stack()
        stack = FrameStack(moduli, [1.0, 4.0, 16.0], bits=8, metadata={"camera": "sim"})
        layer_form = stack.to_exposure_stack()
        assert type(layer_form) is ExposureStack
        assert layer_form.moduli is moduli and layer_form.exposures is stack.exposures  # no copy
        assert layer_form.exposures.tolist() == [1.0, 4.0, 16.0]

    def test_per_item_exposures(self) -> None:
        taus = torch.tensor([[1.0, 2.0, 4.0], [1.0, 3.0, 9.0]], dtype=torch.float64)
        assert torch.equal(FrameStack(_stack(), taus).to_exposure_stack().exposures, taus)

    def test_round_trip(self) -> None:
        stack = FrameStack(_stack(), [1.0, 4.0, 16.0], bits=8)
        assert FrameStack(*stack.to_exposure_stack(), bits=8) == stack

    def test_intensity_stack_is_refused(self) -> None:
        stack = FrameStack(torch.full((1, 2, 1, 2, 2), 255.0), [1.0, 2.0], bits=8, kind="intensity")
        with pytest.raises(ValueError, match=r"holds modulus images; this stack is of kind='intensity' \(merge"):
            stack.to_exposure_stack()


class TestFrameStackErrors:
    def test_moduli_type(self) -> None:
        with pytest.raises(TypeError, match="moduli must be a torch.Tensor; got list"):
            FrameStack([[0.0]], [1.0])  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="floating-point tensor; got dtype torch.int64"):
            FrameStack(torch.zeros(1, 1, 1, 2, 2, dtype=torch.long), [1.0])

    @pytest.mark.parametrize("shape", [(2, 2), (1, 2, 2), (1, 1, 1, 1, 2, 2), (1, 0, 1, 2, 2)])
    def test_moduli_shape(self, shape: tuple[int, ...]) -> None:
        with pytest.raises(ValueError, match=r"moduli must .*got (shape )?" + re.escape(str(tuple(shape)))):
            FrameStack(torch.zeros(shape), [1.0])

    def test_values(self) -> None:
        with pytest.raises(ValueError, match=r"integers in \[0, 256\) for bits=8; got min 0.0, max 256.0"):
            FrameStack(torch.tensor([[[[[0.0, 256.0]]]]]), [1.0], bits=8)
        with pytest.raises(ValueError, match="non-integer value 1.5"):
            FrameStack(torch.tensor([[[[[0.0, 1.5]]]]]), [1.0], bits=8)
        with pytest.raises(ValueError, match="1 NaN"):
            FrameStack(torch.tensor([[[[[0.0, float("nan")]]]]]), [1.0], bits=8)
        with pytest.raises(ValueError, match="bits=12 exceeds what torch.float16"):
            FrameStack(torch.zeros(1, 1, 1, 1, 1, dtype=torch.float16), [1.0], bits=12)

    def test_exposures(self) -> None:
        moduli = _stack(b=2, m=3)
        with pytest.raises(ValueError, match="exposures must be positive; got 0.0"):
            FrameStack(moduli, [1.0, 0.0, 2.0])
        with pytest.raises(ValueError, match=r"\(M,\) = \(3,\) or \(B, M\) = \(2, 3\).*got \(2,\)"):
            FrameStack(moduli, [1.0, 2.0])
        with pytest.raises(ValueError, match=r"got \(3, 3\)"):
            FrameStack(moduli, torch.ones(3, 3))
        with pytest.raises(ValueError, match="must be finite; got inf"):
            FrameStack(moduli, [1.0, float("inf"), 2.0])
        with pytest.raises(
            TypeError, match=r"exposures must hold real numbers, not bools or strings; got \['a', 'b', 'c'\]"
        ):
            FrameStack(moduli, ["a", "b", "c"])

    def test_kind_and_metadata(self) -> None:
        with pytest.raises(ValueError, match="kind must be one of .*got 'hdr'"):
            FrameStack(_stack(), [1.0, 2.0, 3.0], kind="hdr")
        with pytest.raises(TypeError, match="metadata must be a dict; got list"):
            FrameStack(_stack(), [1.0, 2.0, 3.0], metadata=[1])  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="bits must be an integer; got '8'"):
            FrameStack(_stack(), [1.0, 2.0, 3.0], bits="8")  # type: ignore[arg-type]


class TestFrameStackOps:
    def test_to(self, device: torch.device) -> None:
        stack = FrameStack(_stack(), [1.0, 2.0, 4.0], metadata={"a": 1})
        moved = stack.to(device, torch.float64)
        assert moved.device.type == device.type and moved.dtype == torch.float64
        assert moved.exposures.device.type == device.type
        assert torch.equal(moved.moduli.cpu(), stack.moduli.double())
        assert moved.metadata == {"a": 1}
        assert stack.dtype == torch.float32  # the original is unchanged
        with pytest.raises(ValueError, match="bits=12 exceeds"):
            FrameStack(_stack(bits=12), [1.0, 2.0, 4.0], bits=12).to(dtype=torch.float16)

    def test_indexing(self) -> None:
        moduli = _stack(b=4)
        stack = FrameStack(moduli, [1.0, 2.0, 4.0])
        one = stack[2]
        assert one.shape == (1, 3, 1, 4, 5) and torch.equal(one.moduli[0], moduli[2])
        assert torch.equal(stack[-1].moduli[0], moduli[3])
        assert stack[1:3].batch_size == 2
        with pytest.raises(IndexError, match="batch index 4 out of range for a FrameStack of 4 items"):
            stack[4]
        with pytest.raises(TypeError, match="int or a slice; got str"):
            stack["a"]  # type: ignore[index]
        with pytest.raises(TypeError, match="int or a slice; got bool"):
            stack[True]
        assert stack[np.int64(2)] == one and stack[torch.tensor(2)] == one  # what samplers give
        with pytest.raises(ValueError, match=r"step forward \(step >= 1\); got slice\(None, None, -1\)"):
            stack[::-1]

    def test_nested_list_exposures(self) -> None:
        moduli = _stack(b=2)
        nested = FrameStack(moduli, [[1.0, 2.0, 4.0], [1.0, 3.0, 9.0]])
        assert nested == FrameStack(moduli, torch.tensor([[1.0, 2.0, 4.0], [1.0, 3.0, 9.0]]))
        with pytest.raises(TypeError, match="exposures must be a sequence of numbers"):
            FrameStack(moduli, [[1.0, 2.0, 4.0], [1.0]])

    def test_equality(self) -> None:
        moduli = _stack()
        a = FrameStack(moduli, [1.0, 2.0, 4.0], metadata={"x": float("nan")})
        assert a == FrameStack(moduli.clone(), torch.tensor([1.0, 2.0, 4.0]), metadata={"x": float("nan")})
        assert a != FrameStack(moduli, [1.0, 2.0, 5.0], metadata={"x": float("nan")})
        assert a != FrameStack(moduli, [1.0, 2.0, 4.0], bits=9, metadata={"x": float("nan")})
        assert a != FrameStack(moduli.double(), [1.0, 2.0, 4.0], metadata={"x": float("nan")})
        assert a != FrameStack(moduli, torch.tensor([[1.0, 2.0, 4.0]] * 2), metadata={"x": float("nan")})
        changed = moduli.clone()
        changed[0, 0, 0, 0, 0] = (changed[0, 0, 0, 0, 0] + 1) % 256
        assert a != FrameStack(changed, [1.0, 2.0, 4.0], metadata={"x": float("nan")})
        assert a != FrameStack(moduli, [1.0, 2.0, 4.0], metadata={"x": 1.0})
        assert a != "a frame stack"

    def test_feeds_unwrap(self) -> None:
        """The fields plug straight into the multi-shot unwrapper (data flows one way)."""
        multishot = pytest.importorskip("torch_modulo.multishot")
        radiance = torch.rand(2, 1, 6, 6, generator=torch.Generator().manual_seed(1)) * 200
        taus = [1.0, 32.0, 1024.0]
        moduli = torch.stack([capture_modulo(radiance, t, bits=8) for t in taus], dim=1)
        stack = FrameStack(moduli, taus, bits=8)
        counts = multishot.unwrap_multi(stack.moduli, stack.exposures, stack.bits, return_counts=True)
        assert torch.equal(counts, torch.floor(radiance * 1024.0))
