"""Scalar argument checks shared by every operation (torch_modulo/_checks.py)."""

from __future__ import annotations

import asyncio
import contextvars
import math
import threading
import warnings
from collections.abc import Iterator

import numpy as np
import pytest
import torch

import torch_modulo as tm
from torch_modulo._checks import (
    all_integers,
    check_bits,
    check_choice,
    check_finite,
    check_flag,
    check_floating,
    check_int,
    check_modulus,
    check_nonnegative,
    check_real,
    exposure_tensor,
    nonnegative_max,
)
from torch_modulo.cfa import demosaic, interpolate_wrapped


class TestCheckInt:
    @pytest.mark.parametrize("value", [3, np.int64(3)])
    def test_accepts_integers(self, value: object) -> None:
        assert check_int(value, "n", 1, 5) == 3
        assert type(check_int(value, "n")) is int

    @pytest.mark.parametrize("value", [True, 3.0, "3", None, [3]])
    def test_refuses_non_integers(self, value: object) -> None:
        with pytest.raises(TypeError, match="n must be an integer"):
            check_int(value, "n")

    def test_bounds_name_the_value(self) -> None:
        with pytest.raises(ValueError, match="n must be >= 1; got 0"):
            check_int(0, "n", 1)
        with pytest.raises(ValueError, match="n must be <= 5; got 6"):
            check_int(6, "n", high=5)


class TestCheckReal:
    @pytest.mark.parametrize("value", [2, 2.5, np.float32(2.5), np.int32(2)])
    def test_accepts_reals(self, value: object) -> None:
        assert check_real(value, "x") == float(value)

    @pytest.mark.parametrize("value", [False, "x", None, 1j])
    def test_refuses_non_reals(self, value: object) -> None:
        with pytest.raises(TypeError, match="x must be a number"):
            check_real(value, "x")

    def test_nan_and_inf(self) -> None:
        with pytest.raises(ValueError, match="finite; got nan"):
            check_real(math.nan, "x")
        with pytest.raises(ValueError, match="finite; got inf"):
            check_real(math.inf, "x")
        assert check_real(math.inf, "x", allow_inf=True) == math.inf
        with pytest.raises(ValueError, match="finite; got -inf"):
            check_real(-math.inf, "x", allow_inf=True)
        with pytest.raises(ValueError, match="x must be finite and >= 0; got nan"):
            check_real(math.nan, "x", 0.0)

    def test_bounds(self) -> None:
        with pytest.raises(ValueError, match="x must be finite and > 0; got 0.0"):
            check_real(0, "x", positive=True)
        with pytest.raises(ValueError, match="x must be finite and >= 1"):
            check_real(0.5, "x", 1)
        with pytest.raises(ValueError, match="x must be <= 1"):
            check_real(1.5, "x", high=1)


class TestCheckFlag:
    def test_accepts_bools(self) -> None:
        assert check_flag(True, "f") is True
        assert check_flag(np.bool_(False), "f") is False

    @pytest.mark.parametrize("value", ["no", "yes", 0, 1, None, 1.0])
    def test_refuses_truthy_stand_ins(self, value: object) -> None:
        with pytest.raises(TypeError, match="f must be a bool"):
            check_flag(value, "f")


class TestCheckChoice:
    def test_accepts_members(self) -> None:
        assert check_choice(8, "neighborhood", (4, 8)) == 8

    @pytest.mark.parametrize("value", [6, [8], "8", True, None])
    def test_refuses_others_naming_both(self, value: object) -> None:
        with pytest.raises(ValueError, match=r"neighborhood must be one of 4, 8; got"):
            check_choice(value, "neighborhood", (4, 8))


class TestWhat:
    """``what=`` states the whole requirement in the message, for checks a single bound does not describe."""

    def test_real(self) -> None:
        for bad in (0.0, 2.0, math.nan, math.inf):
            with pytest.raises(ValueError, match=r"^eps must be in \(0, 1\); got "):
                check_real(bad, "eps", positive=True, high=1.0, what="in (0, 1)")
        with pytest.raises(TypeError, match="eps must be a number"):
            check_real("x", "eps", what="in (0, 1)")

    def test_int_and_choice(self) -> None:
        with pytest.raises(ValueError, match="^width must be a positive int; got 0$"):
            check_int(0, "width", 1, what="a positive int")
        with pytest.raises(ValueError, match="^byteorder must be 'little' or 'big'; got 'middle'$"):
            check_choice("middle", "byteorder", ("little", "big"), what="'little' or 'big'")


class TestNonnegativeMax:
    def test_returns_the_largest_value_or_raises(self) -> None:
        import torch

        from torch_modulo._checks import nonnegative_max

        assert nonnegative_max(torch.tensor([0.0, 2.5, 1.0]), "x") == 2.5
        assert nonnegative_max(torch.zeros(0), "x") == 0.0
        with pytest.raises(ValueError, match="x must be >= 0; got min -1.0"):
            nonnegative_max(torch.tensor([-1.0, 2.0]), "x")
        with pytest.raises(ValueError, match="1 NaN"):
            nonnegative_max(torch.tensor([math.nan, 2.0]), "x")


class TestNumpyInputs:
    """numpy scalars and arrays are numbers and sequences of numbers like any other."""

    @pytest.mark.parametrize("bits", [np.int64(8), np.int32(8), np.uint8(8), 8, 8.0])
    def test_bits(self, bits: object) -> None:
        assert check_bits(bits) == 8 and type(check_bits(bits)) is int

    @pytest.mark.parametrize("bits", [np.float64(8.5), True, np.bool_(True), "8"])
    def test_bad_bits(self, bits: object) -> None:
        with pytest.raises(TypeError, match="bits must be an integer"):
            check_bits(bits)

    def test_exposures(self) -> None:
        like = torch.zeros(2)
        for taus in (np.array([1.0, 16.0]), np.array([1, 16]), np.array([1.0, 16.0], dtype=np.float32)):
            assert exposure_tensor(taus, like).tolist() == [1.0, 16.0]
        assert exposure_tensor(np.array([[1.0, 4.0], [2.0, 8.0]]), like).shape == (2, 2)
        assert exposure_tensor(np.float32(0.5), like).item() == 0.5
        for bad, error in ((np.array([True]), TypeError), (np.array(["a"]), TypeError), (np.array([0.0]), ValueError)):
            with pytest.raises(error, match="exposures"):
                exposure_tensor(bad, like, "exposures")


class TestCheckFloating:
    def test_returns_the_tensor(self) -> None:
        x = torch.zeros(2)
        assert check_floating(x, "x") is x

    @pytest.mark.parametrize(
        ("value", "match"),
        [([0.0], "x must be a torch.Tensor; got list"), (torch.zeros(2, dtype=torch.long), "got dtype torch.int64")],
    )
    def test_refuses(self, value: object, match: str) -> None:
        with pytest.raises(TypeError, match=match):
            check_floating(value, "x")


class TestAllIntegers:
    @pytest.mark.parametrize("chunk", [1, 3, 16, 1 << 16])
    def test_any_chunk_size_finds_the_one_fraction(self, chunk: int) -> None:
        x = torch.arange(40, dtype=torch.float32)
        assert all_integers(x, chunk=chunk)
        for position in (0, 17, 39):  # first, middle and last chunk
            y = x.clone()
            y[position] += 0.5
            assert not all_integers(y, chunk=chunk), (chunk, position)

    def test_integer_dtypes_and_non_contiguous_input(self) -> None:
        assert all_integers(torch.tensor([1, 2, 3]))
        x = torch.arange(12.0).reshape(3, 4).t()
        x[1, 2] = 0.25
        assert not all_integers(x, chunk=5) and all_integers(x.floor(), chunk=5)


class TestValidationPerThreadAndContext:
    """The validation switch is per thread and per context (a ``ContextVar``, like ``torch.no_grad``)."""

    def test_interleaved_threads_leave_the_checks_on(self) -> None:
        # Regression: A enters validation(False), B enters validation(True), A exits, B exits. With one process-wide
        # setting, B's exit restored the False it had found, and the checks stayed off for the whole process.
        a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
        seen: dict[str, bool] = {}

        def a() -> None:
            with tm.validation(False):
                a_in.set()
                b_in.wait(10)
                seen["a"] = tm.validation_enabled()
            a_out.set()

        def b() -> None:
            a_in.wait(10)
            with tm.validation(True):
                b_in.set()
                a_out.wait(10)
                seen["b"] = tm.validation_enabled()

        threads = [threading.Thread(target=f) for f in (a, b)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(10)
        assert seen == {"a": False, "b": True}
        assert tm.validation_enabled()
        with pytest.raises(ValueError, match=r"modulus must hold integers in \[0, 256\) for bits=8; got min 300.0"):
            tm.unwrap_single(torch.full((2, 2), 300.0), 8)

    def test_one_thread_off_leaves_the_other_threads_on(self) -> None:
        inside, release = threading.Event(), threading.Event()

        def off() -> None:
            with tm.validation(False):
                inside.set()
                release.wait(10)

        t = threading.Thread(target=off)
        t.start()
        try:
            assert inside.wait(10)
            assert tm.validation_enabled()
            with pytest.raises(ValueError, match="radiance must be >= 0; got min -1.0"):
                check_nonnegative(torch.tensor([-1.0]), "radiance")
        finally:
            release.set()
            t.join(10)

    def test_asyncio_tasks_keep_their_own_setting(self) -> None:
        async def off(entered: asyncio.Event, release: asyncio.Event) -> bool:
            with tm.validation(False):
                entered.set()
                await release.wait()
                return tm.validation_enabled()

        async def other(entered: asyncio.Event) -> bool:
            await entered.wait()
            return tm.validation_enabled()

        async def main() -> tuple[bool, bool]:
            entered, release = asyncio.Event(), asyncio.Event()
            first = asyncio.create_task(off(entered, release))
            second = asyncio.create_task(other(entered))
            seen_by_other = await second
            release.set()
            return await first, seen_by_other

        assert asyncio.run(main()) == (False, True)
        assert tm.validation_enabled()

    def test_set_validation_sets_the_current_context_only(self) -> None:
        context = contextvars.copy_context()
        assert context.run(tm.set_validation, False) is True
        assert context.run(tm.validation_enabled) is False
        assert tm.validation_enabled()
        assert context.run(tm.set_validation, True) is False

    def test_compiled_code_skips_the_checks_in_every_thread(self) -> None:
        # While torch.compile traces, the value checks are off whatever a thread's setting: the same compiled layer
        # gives the unchecked result in this thread (checks off) and in another (checks on), where eager code raises.
        torch._dynamo.reset()
        try:
            layer = tm.ModuloCapture(exposure=2.0, bits=8)
            compiled = torch.compile(layer, backend="eager")
            negative = torch.full((1, 1, 2, 2), -1.0)
            results: list[object] = []

            def call() -> None:
                results.append(compiled(negative))
                try:
                    layer(negative)
                except ValueError as error:
                    results.append(str(error))

            with tm.validation(False):
                first = compiled(negative)
                t = threading.Thread(target=call)
                t.start()
                t.join(60)
            assert torch.equal(first, torch.full((1, 1, 2, 2), 254.0))
            assert torch.equal(results[0], first) and results[1] == "radiance must be >= 0; got min -1.0"
        finally:
            torch._dynamo.reset()


class TestRequiresGrad:
    """Regression: a modulus that requires grad made torch warn "Converting a tensor with requires_grad=True to a
    scalar" from the checks; they read detached values."""

    @pytest.fixture(autouse=True)
    def _warn_always(self) -> Iterator[None]:
        """torch gives that warning once per process; make it every time, so the test sees it whatever ran first."""
        before = torch.is_warn_always_enabled()
        torch.set_warn_always(True)
        yield
        torch.set_warn_always(before)

    def test_checks_read_detached_values(self) -> None:
        m = torch.tensor([[3.0, 200.0]], requires_grad=True)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert check_modulus(m, 8) is m
            check_nonnegative(m, "radiance")
            check_finite(m, "radiance")
            assert nonnegative_max(m, "radiance") == 200.0
            assert all_integers(m)
            exposure_tensor(torch.tensor([1.0, 2.0], requires_grad=True), m)
            with pytest.raises(ValueError, match="got non-integer value 3.5"):
                check_modulus(m + 0.5, 8)
            with pytest.raises(ValueError, match=r"got min -1.0, max 196.0"):
                check_modulus(m - 4, 8)
            with pytest.raises(ValueError, match="1 NaN and 0 Inf"):
                check_finite(m * torch.tensor([[math.nan, 1.0]]), "radiance")
            with pytest.raises(ValueError, match="exposure must be positive; got -1.0"):
                exposure_tensor(torch.tensor([-1.0, 2.0], requires_grad=True), m)
            with tm.validation(False):
                assert nonnegative_max(m, "radiance") == 200.0


class TestMetaDevice:
    """Regression: tensors on the ``meta`` device (no values) raised ``RuntimeError: Tensor.item() cannot be called on
    meta tensors`` from the value checks; they raise a ``ValueError`` that names the device."""

    META = "is on the meta device, which holds no values"

    def test_value_checks_name_the_device(self) -> None:
        meta = torch.zeros(1, 1, 4, 4, device="meta")
        for call in (
            lambda: check_modulus(meta, 8),
            lambda: check_finite(meta, "radiance"),
            lambda: check_nonnegative(meta, "radiance"),
            lambda: exposure_tensor(torch.ones(2, device="meta"), meta, "exposures"),
            lambda: exposure_tensor(torch.ones(2, device="meta"), torch.zeros(2), "exposures"),
        ):
            with pytest.raises(ValueError, match=self.META):
                call()
        # Exposures given as numbers have values: checked on the host, then put on ``like``'s device.
        assert exposure_tensor([1.0, 2.0], meta, "exposures").device.type == "meta"
        with pytest.raises(ValueError, match="exposures must be positive; got 0.0"):
            exposure_tensor([0.0, 2.0], meta, "exposures")

    @pytest.mark.parametrize("enabled", [True, False])
    def test_readers_name_the_device_with_checks_on_or_off(self, enabled: bool) -> None:
        meta = torch.zeros(1, 1, 4, 4, device="meta")
        with tm.validation(enabled):
            with pytest.raises(ValueError, match=f"radiance {self.META}"):
                nonnegative_max(meta, "radiance")
            with pytest.raises(ValueError, match=self.META):
                all_integers(meta)
            for method in ("learned", "guided", "lsq"):
                with pytest.raises(ValueError, match=f"modulus {self.META}"):
                    tm.unwrap_single(meta, 8, method=method)
            with pytest.raises(ValueError, match=f"modulus {self.META}"):
                tm.SingleShotUnwrap(8, method="guided")(meta)

    def test_public_operations_with_the_checks_on(self) -> None:
        meta = torch.zeros(1, 1, 4, 4, device="meta")
        for call, name in (
            (lambda: tm.modulo_wrap(meta, 8), "counts"),
            (lambda: tm.capture_modulo(meta, 1.0, 8), "radiance"),
            (lambda: tm.capture_intensity(meta, 1.0, 8), "radiance"),
            (lambda: tm.capture_stack(meta, [1.0, 4.0], 8), "radiance"),
            (lambda: tm.ModuloCapture(exposure=2.0)(meta), "radiance"),
            (lambda: interpolate_wrapped(meta, "RGGB", 8), "modulus"),
        ):
            with pytest.raises(ValueError, match=f"{name} {self.META}"):
                call()

    @pytest.mark.parametrize("enabled", [True, False])
    def test_decoders_and_tone_maps_name_the_device(self, enabled: bool) -> None:
        meta = torch.zeros(1, 3, 4, 4, device="meta")
        with tm.validation(enabled):
            with pytest.raises(ValueError, match=f"moduli {self.META}"):
                tm.unwrap_multi(torch.zeros(1, 2, 1, 4, 4, device="meta"), [1.0, 4.0], 8)
            with pytest.raises(ValueError, match=f"moduli {self.META}"):
                tm.unwrap_multi(torch.zeros(1, 2, 1, 4, 4, device="meta"), [1.0, 4.0], 8, noise="q16")
            for tonemap in (tm.tonemap_reinhard, tm.tonemap_histogram, tm.tonemap_gamma, tm.tonemap_log):
                with pytest.raises(ValueError, match=self.META):
                    tonemap(meta)

    def test_wrap_traces_with_the_checks_off(self) -> None:
        with tm.validation(False):
            assert tm.modulo_wrap(torch.zeros(2, 3, device="meta"), 8).device.type == "meta"

    def test_shape_only_operations_still_trace_with_the_checks_off(self) -> None:
        # Without the value checks nothing reads a value: the capture runs on meta tensors (shapes, dtypes).
        meta = torch.zeros(2, 3, 4, 4, device="meta")
        with tm.validation(False):
            assert tm.capture_stack(meta, [1.0, 4.0], 8).shape == (2, 2, 3, 4, 4)
        assert demosaic(meta[:, :1], "RGGB").device.type == "meta"


class TestOneRuleForExposures:
    """Exposures are real numbers, in every form: a bool or a string is refused as a scalar, in a list or in an
    array; a tensor or array of any integer or floating dtype is taken as real numbers."""

    @pytest.mark.parametrize(
        "bad",
        [True, "1", [True, True], ["1", "16"], [1.0, True], [[1.0, 4.0], [2.0, "8"]], (b"1",), [np.bool_(True)]],
    )
    def test_bools_and_strings_refused_in_every_form(self, bad: object) -> None:
        with pytest.raises(TypeError, match="exposures must "):
            exposure_tensor(bad, torch.zeros(2), "exposures")  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="exposures must "):
            tm.capture_stack(torch.ones(1, 1, 2, 2), bad, 8)  # type: ignore[arg-type]

    def test_refusal_names_the_value(self) -> None:
        with pytest.raises(
            TypeError, match=r"exposures must hold real numbers, not bools or strings; got \[1.0, True\]"
        ):
            exposure_tensor([1.0, True], torch.zeros(2), "exposures")

    @pytest.mark.parametrize("int_dtype", [torch.uint8, torch.int8, torch.int16, torch.int32, torch.int64])
    def test_integer_tensors_are_real_numbers(self, int_dtype: torch.dtype) -> None:
        taus = torch.tensor([1, 16], dtype=int_dtype)
        assert exposure_tensor(taus, torch.zeros(2), "exposures").tolist() == [1.0, 16.0]
        x = torch.full((1, 1, 2, 2), 3.0)
        assert torch.equal(tm.capture_stack(x, taus, 8), tm.capture_stack(x, [1.0, 16.0], 8))

    def test_integer_arrays_of_any_width_too(self) -> None:
        for taus in (np.array([1, 16], dtype=np.uint8), np.array([1, 16], dtype=np.uint16)):
            assert exposure_tensor(taus, torch.zeros(2), "exposures").tolist() == [1.0, 16.0]

    @pytest.mark.parametrize("bad", [torch.tensor([True]), torch.tensor([1 + 1j])])
    def test_bool_and_complex_tensors_refused(self, bad: torch.Tensor) -> None:
        with pytest.raises(TypeError, match=f"exposures must hold real numbers; got dtype {bad.dtype}"):
            exposure_tensor(bad, torch.zeros(2), "exposures")

    def test_zero_in_an_integer_tensor_is_a_value_error(self) -> None:
        with pytest.raises(ValueError, match="exposures must be positive; got 0.0"):
            exposure_tensor(torch.tensor([0, 4], dtype=torch.uint8), torch.zeros(2), "exposures")
