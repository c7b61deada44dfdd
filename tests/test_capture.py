"""Tests for torch_modulo/capture.py: Eq. 1 and the quantised capture models."""

from __future__ import annotations

from collections.abc import Callable

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch import nn

import torch_modulo as tm
from torch_modulo._chunks import CPU_CHUNK, chunk_on_cpu, column_chunks


def _radiance(shape: tuple[int, ...], device: torch.device, dtype: torch.dtype, seed: int = 0) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return (torch.exp2(torch.rand(shape, generator=gen, dtype=torch.float64) * 12 - 4)).to(device, dtype)


class TestModuloWrap:
    def test_smoke(self, device: torch.device, dtype: torch.dtype) -> None:
        out = tm.modulo_wrap(torch.tensor([3.0, 300.0], device=device, dtype=dtype), bits=8)
        assert out.tolist() == [3.0, 44.0]

    def test_unit_hand_computed(self, device: torch.device, dtype: torch.dtype) -> None:
        counts = torch.tensor([0.0, 1.0, 15.0, 16.0, 17.0, 31.0, 32.0, 1000.0], device=device, dtype=dtype)
        assert tm.modulo_wrap(counts, bits=4).tolist() == [0.0, 1.0, 15.0, 0.0, 1.0, 15.0, 0.0, 8.0]

    def test_negative_and_fractional_values_wrap_like_python(self, device: torch.device) -> None:
        counts = torch.tensor([-1.0, -16.5, 2.25, -1e-12], device=device, dtype=torch.float64)
        out = tm.modulo_wrap(counts, bits=4)
        expected = [(-1.0) % 16, (-16.5) % 16, 2.25, 0.0]
        assert out[:3].tolist() == expected[:3]
        assert 0.0 <= float(out[3]) < 16.0

    @pytest.mark.parametrize("shape", [(5,), (2, 3), (3, 4, 5), (2, 3, 4, 5), (0, 3, 4, 4)])
    def test_cardinality(self, shape: tuple[int, ...], device: torch.device, dtype: torch.dtype) -> None:
        counts = torch.floor(_radiance(shape, device, dtype) * 50)
        out = tm.modulo_wrap(counts, 8)
        assert out.shape == counts.shape and out.dtype == dtype and out.device == counts.device

    def test_large_tensor_uses_chunks_and_matches_remainder(self) -> None:
        # More than one CPU chunk, with rows of unequal chunks, checked against torch.remainder.
        counts = torch.floor(_radiance((3, 1, 7, CPU_CHUNK // 5), torch.device("cpu"), torch.float32) * 97)
        assert torch.equal(tm.modulo_wrap(counts, 8), torch.remainder(counts, 256.0))

    def test_gradient_passes_through(self, device: torch.device) -> None:
        counts = (torch.rand(2, 3, 4, 4, dtype=torch.float64, device=device) * 1000).requires_grad_()
        assert torch.autograd.gradcheck(lambda x: tm.modulo_wrap(x + 0.5, 8), (counts,))
        tm.modulo_wrap(counts, 8).sum().backward()
        assert torch.equal(counts.grad, torch.ones_like(counts))

    def test_module_equals_function(self, device: torch.device, dtype: torch.dtype) -> None:
        counts = torch.floor(_radiance((2, 3, 5, 5), device, dtype) * 1000)
        assert torch.equal(tm.ModuloWrap(bits=6)(counts), tm.modulo_wrap(counts, 6))

    @pytest.mark.parametrize(
        ("bits", "error", "match"),
        [(0, ValueError, "bits must be >= 1; got 0"), (25, ValueError, "float64"), (2.5, TypeError, "2.5")],
    )
    def test_bad_bits(self, bits: object, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            tm.modulo_wrap(torch.zeros(3), bits)  # type: ignore[arg-type]

    def test_bad_input(self) -> None:
        with pytest.raises(TypeError, match="list"):
            tm.modulo_wrap([1.0, 2.0], 8)  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="int64"):
            tm.modulo_wrap(torch.tensor([1, 2]), 8)
        with pytest.raises(ValueError, match="1 NaN and 1 Inf"):
            tm.modulo_wrap(torch.tensor([1.0, float("nan"), float("inf")]), 8)

    def test_float64_accepts_more_bits(self) -> None:
        counts = torch.tensor([2.0**40 + 5.0], dtype=torch.float64)
        assert tm.modulo_wrap(counts, bits=32).item() == 5.0


class TestCaptureModulo:
    def test_unit_hand_computed(self, device: torch.device, dtype: torch.dtype) -> None:
        radiance = torch.tensor([0.0, 0.49, 0.5, 127.9, 128.0, 1000.0], device=device, dtype=dtype)
        out = tm.capture_modulo(radiance, exposure=2.0, bits=8)
        assert out.tolist() == [0.0, 0.0, 1.0, 255.0, 0.0, 208.0]

    def test_per_batch_exposure(self, device: torch.device, dtype: torch.dtype) -> None:
        radiance = _radiance((3, 2, 4, 4), device, dtype)
        taus = torch.tensor([1.0, 10.0, 300.0], device=device)
        out = tm.capture_modulo(radiance, taus, bits=8)
        for i, tau in enumerate(taus.tolist()):
            assert torch.equal(out[i], tm.capture_modulo(radiance[i], tau, bits=8))

    @pytest.mark.parametrize("shape", [(4,), (3, 5, 6), (2, 3, 5, 6), (0, 3, 5, 6), (2, 1, 1, CPU_CHUNK + 7)])
    def test_matches_definition(self, shape: tuple[int, ...], device: torch.device, dtype: torch.dtype) -> None:
        radiance = _radiance(shape, device, dtype)
        expected = torch.remainder(torch.floor(radiance * 37.0), 256.0)
        out = tm.capture_modulo(radiance, 37.0, bits=8)
        assert torch.equal(out, expected)
        assert out.dtype == dtype and out.device == radiance.device

    def test_non_contiguous_input(self, device: torch.device) -> None:
        radiance = _radiance((2, 4, 6, 3), device, torch.float32).permute(0, 3, 1, 2)
        expected = torch.remainder(torch.floor(radiance * 9.0), 16.0)
        assert torch.equal(tm.capture_modulo(radiance, 9.0, bits=4), expected)

    def test_input_not_modified(self, device: torch.device) -> None:
        radiance = _radiance((2, 3, 4, 4), device, torch.float32)
        before = radiance.clone()
        tm.capture_modulo(radiance, 100.0, 8)
        tm.capture_intensity(radiance, 100.0, 8)
        tm.modulo_wrap(radiance, 8)
        assert torch.equal(radiance, before)

    def test_gradient_default_is_zero_and_straight_through_is_exposure(self) -> None:
        radiance = (torch.rand(1, 1, 3, 3, dtype=torch.float64) * 100).requires_grad_()
        tm.capture_modulo(radiance, 3.0, 8).sum().backward()
        assert torch.equal(radiance.grad, torch.zeros_like(radiance))
        radiance.grad = None
        tm.capture_modulo(radiance, 3.0, 8, straight_through=True).sum().backward()
        assert torch.allclose(radiance.grad, torch.full_like(radiance, 3.0))

    def test_straight_through_forward_equals_plain(self) -> None:
        radiance = (torch.rand(2, 3, 4, 4) * 1000).requires_grad_()
        plain = tm.capture_modulo(radiance.detach(), 3.0, 8)
        st_out = tm.capture_modulo(radiance, 3.0, 8, straight_through=True)
        assert torch.equal(st_out.detach(), plain)

    def test_module_equals_function_and_moves_with_to(self, device: torch.device) -> None:
        radiance = _radiance((2, 3, 4, 4), device, torch.float32)
        layer = tm.ModuloCapture(exposure=torch.tensor([5.0, 50.0]), bits=8).to(device)
        assert layer.exposure.device == radiance.device
        assert torch.equal(layer(radiance), tm.capture_modulo(radiance, torch.tensor([5.0, 50.0]), 8))

    @pytest.mark.parametrize(
        ("radiance", "exposure", "error", "match"),
        [
            (torch.tensor([-1.0, 2.0]), 1.0, ValueError, "radiance must be >= 0; got min -1.0"),
            (torch.tensor([float("nan")]), 1.0, ValueError, "1 NaN"),
            (torch.tensor([1.0]), 0.0, ValueError, "exposure must be positive; got 0.0"),
            (torch.tensor([1.0]), -2.0, ValueError, "-2.0"),
            (torch.tensor([1.0]), float("inf"), ValueError, "finite"),
            (torch.tensor([1.0]), "1", TypeError, "exposure"),
            (torch.ones(2, 1, 2, 2), torch.ones(3), ValueError, r"shape \(3,\)"),
            (torch.tensor([1, 2]), 1.0, TypeError, "floating-point"),
        ],
    )
    def test_bad_input(self, radiance: torch.Tensor, exposure: object, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            tm.capture_modulo(radiance, exposure, 8)  # type: ignore[arg-type]
        with pytest.raises(error, match=match):
            tm.capture_intensity(radiance, exposure, 8)  # type: ignore[arg-type]

    @settings(max_examples=50, deadline=None)
    @given(
        bits=st.integers(1, 16),
        tau=st.floats(0.01, 1e4),
        values=st.lists(st.floats(0, 1e3, allow_subnormal=False), min_size=1, max_size=20),
    )
    def test_property_in_range_and_congruent(self, bits: int, tau: float, values: list[float]) -> None:
        radiance = torch.tensor(values, dtype=torch.float64)
        counts = torch.floor(radiance * tau)
        out = tm.capture_modulo(radiance, tau, bits)
        assert bool(((out >= 0) & (out < 2**bits)).all())
        assert torch.equal(torch.remainder(counts - out, 2.0**bits), torch.zeros_like(out))


class TestCaptureIntensity:
    def test_unit_hand_computed(self, device: torch.device, dtype: torch.dtype) -> None:
        radiance = torch.tensor([0.0, 0.5, 127.9, 128.0, 1000.0], device=device, dtype=dtype)
        assert tm.capture_intensity(radiance, 2.0, bits=8).tolist() == [0.0, 1.0, 255.0, 255.0, 255.0]

    def test_agrees_with_modulo_below_saturation(self, device: torch.device, dtype: torch.dtype) -> None:
        radiance = _radiance((2, 3, 8, 8), device, dtype)
        mod = tm.capture_modulo(radiance, 10.0, 12)
        inten = tm.capture_intensity(radiance, 10.0, 12)
        below = torch.floor(radiance * 10.0) < 4095
        assert torch.equal(mod[below], inten[below])
        assert bool((inten[~below] == 4095).all())

    def test_straight_through_gradient_is_zero_where_clipped(self) -> None:
        radiance = torch.tensor([1.0, 100.0], dtype=torch.float64, requires_grad=True)
        tm.capture_intensity(radiance, 2.0, bits=4, straight_through=True).sum().backward()
        assert radiance.grad.tolist() == [2.0, 0.0]

    def test_module_equals_function(self) -> None:
        radiance = _radiance((2, 3, 4, 4), torch.device("cpu"), torch.float32)
        assert torch.equal(tm.IntensityCapture(7.0, bits=10)(radiance), tm.capture_intensity(radiance, 7.0, 10))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu() -> None:
    radiance = _radiance((2, 3, 16, 16), torch.device("cpu"), torch.float32)
    for fn in (tm.capture_modulo, tm.capture_intensity):
        assert torch.equal(fn(radiance.cuda(), 33.0, 8).cpu(), fn(radiance, 33.0, 8))


class TestFloat32CountLimit:
    """Regression: ``capture_modulo`` in float32 above 2**24 counts silently lost the low bits it keeps."""

    def test_counts_beyond_float32_warn_naming_the_count_and_float64(self) -> None:
        radiance = torch.tensor([[[[1.0, 2.0**25 + 4]]]])
        with pytest.warns(
            UserWarning, match=r"counts reach 33554436, beyond what torch.float32 holds exactly.*float64"
        ):
            tm.capture_modulo(radiance, 1.0, bits=8)
        with pytest.warns(UserWarning, match=r"counts reach 33554432"):
            tm.ModuloCapture(exposure=4.0, bits=8)(torch.full((1, 1, 1, 1), 2.0**23))

    def test_within_the_limit_or_in_float64_is_silent(self, recwarn: pytest.WarningsRecorder) -> None:
        tm.capture_modulo(torch.tensor([2.0**24]), 1.0, bits=8)
        exact = tm.capture_modulo(torch.tensor([2.0**25 + 3], dtype=torch.float64), 1.0, bits=8)
        tm.capture_intensity(torch.tensor([2.0**30]), 1.0, bits=8)  # clips at 255: exact
        assert exact.tolist() == [3.0] and not recwarn.list


class TestExposuresKeepFloat64ThroughDtypeCasts:
    """Regression: ``.half()`` / ``.to(dtype)`` on a capture layer converted its exposure buffer.

    ``MultiExposureCapture([1, 300, 90000]).half()`` held an infinite exposure (and refused every input), and
    ``ModuloCapture(1/3).to(torch.bfloat16)`` held 0.33398, so a float32 radiance of 3000 read 233, not 232.
    """

    def test_an_exposure_made_a_parameter_is_converted_like_one(self) -> None:
        layer = tm.ModuloCapture(2.0)
        layer.exposure = nn.Parameter(torch.tensor(2.0, dtype=torch.float64))  # to learn it: no longer a buffer
        assert layer.to("cpu").half().exposure.dtype == torch.float16  # a parameter's usual conversion

    CASTS = {  # noqa: RUF012
        "half": lambda m: m.half(),
        "bfloat16": lambda m: m.bfloat16(),
        "float": lambda m: m.float(),
        "to-float16": lambda m: m.to(torch.float16),
        "to-bfloat16": lambda m: m.to(dtype=torch.bfloat16),
        "type-float16": lambda m: m.type(torch.float16),
    }

    @pytest.mark.parametrize("cast", list(CASTS))
    def test_single_exposure_layers(self, cast: str) -> None:
        for make in (tm.ModuloCapture, tm.IntensityCapture):
            for exposure, peak in ((1 / 3, 3000.0), (torch.tensor([1 / 3]), 3000.0), (90000.0, 3.0)):
                radiance = torch.tensor([[[[peak, 0.5, 0.2 * peak]]]])
                before = make(exposure, bits=11)
                expected = before(radiance)
                layer = self.CASTS[cast](make(exposure, bits=11))
                assert layer.exposure.dtype == torch.float64
                assert torch.equal(layer.exposure, before.exposure)
                assert torch.equal(layer(radiance), expected)
        assert tm.ModuloCapture(1 / 3).to(torch.bfloat16)(torch.tensor([3000.0])).tolist() == [232.0]

    @pytest.mark.parametrize("cast", list(CASTS))
    def test_multi_exposure_capture_and_chain(self, cast: str) -> None:
        radiance = _radiance((2, 3, 5, 4), torch.device("cpu"), torch.float32) * 0.01
        taus = [1.0, 300.0, 90000.0]
        before = tm.MultiExposureCapture(taus, bits=9)
        layer = self.CASTS[cast](tm.MultiExposureCapture(taus, bits=9))
        assert layer.exposures.dtype == torch.float64 and layer.exposures.tolist() == taus
        out, ref = layer(radiance), before(radiance)
        assert torch.equal(out.moduli, ref.moduli) and torch.equal(out.exposures, ref.exposures)
        chain = self.CASTS[cast](nn.Sequential(tm.MultiExposureCapture(taus, bits=9), tm.MultiExposureUnwrap(9)))
        plain = nn.Sequential(tm.MultiExposureCapture(taus, bits=9), tm.MultiExposureUnwrap(9))
        assert torch.equal(chain(radiance), plain(radiance))

    @pytest.mark.parametrize(
        ("make", "name"),
        [
            (lambda: tm.ModuloCapture(1 / 3), "exposure"),
            (lambda: tm.IntensityCapture(torch.tensor([2.0, 1 / 3])), "exposure"),
            (lambda: tm.MultiExposureCapture([1.0, 1 / 3, 90000.0]), "exposures"),
        ],
        ids=["ModuloCapture", "IntensityCapture", "MultiExposureCapture"],
    )
    def test_still_move_with_the_device(self, make: Callable[[], nn.Module], name: str, device: torch.device) -> None:
        expected = getattr(make(), name)
        for target in (device, torch.device("meta")):
            layer = make().to(target, torch.float16)
            tau = getattr(layer, name)
            assert tau.dtype == torch.float64 and tau.device.type == target.type
            if target.type != "meta":
                assert torch.equal(tau.cpu(), expected)
            assert layer.state_dict() == {}  # a configuration, not learned state: nothing saved or loaded


class TestStraightThroughIsABool:
    """Regression: ``straight_through="no"`` switched the straight-through gradient on."""

    @pytest.mark.parametrize("flag", ["no", 0, 1, None])
    def test_functions_and_modules_refuse_stand_ins(self, flag: object) -> None:
        radiance = torch.ones(1, 1, 2, 2)
        for fn in (tm.capture_modulo, tm.capture_intensity):
            with pytest.raises(TypeError, match=f"straight_through must be a bool; got {flag!r}"):
                fn(radiance, 1.0, 8, straight_through=flag)  # type: ignore[arg-type]
        for module in (tm.ModuloCapture, tm.IntensityCapture):
            with pytest.raises(TypeError, match="straight_through must be a bool"):
                module(1.0, 8, straight_through=flag)  # type: ignore[arg-type]


class TestChunks:
    """The CPU chunks of the element-wise kernels (torch_modulo/_chunks.py)."""

    def test_column_chunks_cover_the_columns(self) -> None:
        chunks = column_chunks(CPU_CHUNK * 3 + 5, 1)
        assert chunks == [slice(i * CPU_CHUNK, min((i + 1) * CPU_CHUNK, CPU_CHUNK * 3 + 5)) for i in range(4)]
        assert column_chunks(0, 4) == []

    def test_column_chunks_share_the_elements_between_rows(self) -> None:
        # 8 elements per chunk over 2 rows: 4 columns each, the last one shorter.
        assert column_chunks(10, 2, chunk=8, min_width=1) == [slice(0, 4), slice(4, 8), slice(8, 10)]
        # min_width wins over a chunk too small for the rows; a single wide chunk when n is below it.
        assert column_chunks(10, 100, chunk=8, min_width=3) == [slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 10)]
        assert column_chunks(5, 1, chunk=8, min_width=64) == [slice(0, 5)]

    def test_chunk_on_cpu(self) -> None:
        x = torch.ones(3)
        assert chunk_on_cpu(x, x.clone())
        assert not chunk_on_cpu(x, x.clone().requires_grad_())
        with torch.no_grad():
            assert chunk_on_cpu(x.clone().requires_grad_())
        assert not chunk_on_cpu(torch.ones(3, device="meta"))


@pytest.mark.parametrize("capture", [tm.capture_modulo, tm.capture_intensity])
@pytest.mark.parametrize("exposure", [torch.empty(0), torch.empty(0, 1, 1, 1)])
def test_empty_batch_with_one_exposure_per_item(capture: Callable, exposure: torch.Tensor) -> None:
    out = capture(torch.empty(0, 3, 4, 4), exposure, 8)
    assert out.shape == (0, 3, 4, 4)


@pytest.mark.parametrize("capture", [tm.capture_modulo, lambda x, t, b: tm.capture_stack(x, [1.0, t], b)])
def test_float16_counts_beyond_its_range_are_refused_not_nan(capture: Callable) -> None:
    x = torch.full((1, 1, 2, 2), 1000.0, dtype=torch.float16)
    with pytest.raises(ValueError, match=r"counts reach 100000, beyond the largest torch.float16"):
        capture(x, 100.0, 8)
    with pytest.warns(UserWarning, match="low bits"):  # inside the range: inexact, but a modulus
        out = capture(x, 10.0, 8)
    assert bool(torch.isfinite(out).all())
    assert torch.equal(tm.capture_intensity(x, 100.0, 8), torch.full_like(x, 255.0))  # clipping never overflows


def test_nested_list_exposures_are_a_batch_of_stacks() -> None:
    x = torch.rand(2, 1, 4, 4) * 50
    nested = tm.capture_stack(x, [[1.0, 4.0], [2.0, 8.0]], 8)
    assert torch.equal(nested, tm.capture_stack(x, torch.tensor([[1.0, 4.0], [2.0, 8.0]]), 8))
    with pytest.raises(TypeError, match=r"exposures must be a sequence of numbers .*\[\[1.0, 4.0\], \[2.0\]\]"):
        tm.capture_stack(x, [[1.0, 4.0], [2.0]], 8)


def test_exposures_as_any_numbers() -> None:
    from fractions import Fraction

    x = torch.rand(1, 1, 4, 4) * 50
    expected = tm.capture_stack(x, [0.5, 3.0], 8)
    for exposures in ([Fraction(1, 2), Fraction(3)], [torch.tensor([0.5]), torch.tensor([3.0])], (0.5, 3)):
        assert torch.equal(tm.capture_stack(x, exposures, 8), expected)
