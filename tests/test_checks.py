"""Scalar argument checks shared by every operation (torch_modulo/_checks.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torch_modulo._checks import (
    all_integers,
    check_bits,
    check_choice,
    check_flag,
    check_floating,
    check_int,
    check_real,
    exposure_tensor,
)


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
