"""Tests for torch_modulo.singleshot.energy: the potential V (Eq. 5), representability (Eq. 4), the energy (Eq. 3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from torch_modulo.singleshot.energy import (
    EnergyParams,
    Potential,
    UnwrapEnergy,
    is_representable,
    pair_offsets,
    potential,
    unwrap_energy,
)
from torch_modulo.singleshot.graphcut import plane_energy

B8 = 0.1 * 128 - 1e-5 * 128**2  # b for bits=8: a1 x0 - a2 x0^2 = 12.63616


class TestEnergyParams:
    def test_defaults(self) -> None:
        p = EnergyParams.make(8)
        assert (p.bits, p.a1, p.a2, p.x0, p.period) == (8, 0.1, 1e-5, 128.0, 256)
        assert p.b == pytest.approx(B8)

    def test_x0_follows_bits(self) -> None:
        assert EnergyParams.make(12).x0 == 2048.0
        assert EnergyParams.make(1).x0 == 1.0

    @pytest.mark.parametrize(
        ("kwargs", "error", "text"),
        [
            ({"a1": -0.1}, ValueError, "-0.1"),
            ({"a2": -1.0}, ValueError, "-1.0"),
            ({"x0": 0.0}, ValueError, "0.0"),
            ({"x0": math.inf}, ValueError, "inf"),
            ({"a1": "big"}, TypeError, "big"),
            ({"a2": True}, TypeError, "True"),
            ({"bits": 0}, ValueError, "0"),
            ({"bits": 2.5}, TypeError, "2.5"),
        ],
    )
    def test_exceptions(self, kwargs: dict, error: type, text: str) -> None:
        with pytest.raises(error, match=text):
            EnergyParams.make(**kwargs)


class TestPotential:
    def test_smoke(self, device: torch.device, dtype: torch.dtype) -> None:
        x = torch.linspace(-600, 600, 25, device=device, dtype=dtype)
        v = potential(x)
        assert v.shape == x.shape and v.dtype == dtype and v.device == x.device
        assert bool((v >= 0).all())

    def test_unit(self) -> None:
        x = torch.tensor([0.0, 10.0, -100.0, 128.0, 200.0, -256.0], dtype=torch.float64)
        expected = torch.tensor([0.0, 1.0, 10.0, 12.8, 1e-5 * 200**2 + B8, 1e-5 * 256**2 + B8], dtype=torch.float64)
        torch.testing.assert_close(potential(x), expected)

    def test_continuous_at_x0(self) -> None:
        for bits in (4, 8, 12):
            x0 = 2.0 ** (bits - 1)
            eps = 1e-9 * x0
            v = potential(torch.tensor([x0 - eps, x0, x0 + eps], dtype=torch.float64), bits)
            assert float(v.max() - v.min()) < 1e-6

    def test_even_and_monotone(self) -> None:
        x = torch.arange(0.0, 2000.0, dtype=torch.float64)
        v = potential(x)
        torch.testing.assert_close(potential(-x), v)
        assert bool((v[1:] >= v[:-1]).all())

    def test_custom_parameters(self) -> None:
        v = potential(torch.tensor([3.0, 5.0], dtype=torch.float64), bits=4, a1=1.0, a2=0.5, x0=4.0)
        # b = 1 * 4 - 0.5 * 16 = -4; V(5) = 0.5 * 25 - 4
        torch.testing.assert_close(v, torch.tensor([3.0, 8.5], dtype=torch.float64))

    def test_gradcheck(self) -> None:
        x = torch.tensor([-300.0, -50.0, 20.0, 90.0, 400.0], dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(lambda t: potential(t), (x,))

    def test_module_equals_function(self) -> None:
        x = torch.linspace(-500, 500, 11)
        torch.testing.assert_close(Potential(bits=8, a1=0.2)(x), potential(x, 8, a1=0.2))

    def test_input_unmodified(self) -> None:
        x = torch.tensor([-5.0, 300.0])
        before = x.clone()
        potential(x)
        assert torch.equal(x, before)

    def test_exceptions(self) -> None:
        with pytest.raises(TypeError, match="int64"):
            potential(torch.tensor([1, 2]))
        with pytest.raises(TypeError, match="list"):
            potential([1.0, 2.0])  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="-1"):
            potential(torch.zeros(2), a1=-1.0)
        with pytest.raises(ValueError, match="-3"):
            Potential(bits=-3)


class TestIsRepresentable:
    def test_unit(self) -> None:
        # V(200) = 13.036; V(456) + V(-56) = 14.715 + 5.6 < 26.07: not representable. Small differences are.
        x = torch.tensor([0.0, 100.0, 128.0, 200.0, -200.0], dtype=torch.float64)
        assert is_representable(x).tolist() == [True, True, True, False, False]

    def test_larger_step(self) -> None:
        # With step 2: V(712) + V(-312) = 17.70 + 13.61 >= 2 V(200) = 26.07.
        assert bool(is_representable(torch.tensor([200.0]), step=2))

    def test_matches_definition(self) -> None:
        x = torch.arange(-1000.0, 1000.0, 7.0, dtype=torch.float64)
        v = potential(x)
        expected = potential(x + 256) + potential(x - 256) >= 2 * v
        assert torch.equal(is_representable(x), expected)

    def test_convex_potential_is_always_representable(self) -> None:
        # With x0 beyond every difference V is a1 |x|: convex, hence representable everywhere (paper Sec. 4.2).
        x = torch.arange(-1000.0, 1000.0, 3.0, dtype=torch.float64)
        assert bool(is_representable(x, x0=1e6).all())

    def test_exceptions(self) -> None:
        with pytest.raises(ValueError, match="0"):
            is_representable(torch.zeros(2), step=0)
        with pytest.raises(TypeError, match="int64"):
            is_representable(torch.zeros(2, dtype=torch.int64))


class TestUnwrapEnergy:
    def test_unit_4_and_8(self) -> None:
        img = torch.tensor([[0.0, 10.0], [20.0, 30.0]], dtype=torch.float64)
        # 4-neighbourhood: |10| + |20| (rows) ... 0.1 * (10 + 10 + 20 + 20) = 6
        assert float(unwrap_energy(img, neighborhood=4)) == pytest.approx(6.0)
        # diagonals add 0.1 * (30 + 10) = 4
        assert float(unwrap_energy(img, neighborhood=8)) == pytest.approx(10.0)

    def test_jump_uses_quadratic_part(self) -> None:
        img = torch.tensor([[0.0, 300.0]], dtype=torch.float64)
        assert float(unwrap_energy(img)) == pytest.approx(1e-5 * 300**2 + B8)

    @pytest.mark.parametrize(
        ("shape", "out"), [((5, 6), ()), ((3, 5, 6), (3,)), ((2, 3, 5, 6), (2, 3)), ((0, 3, 5, 6), (0, 3))]
    )
    def test_cardinality(self, shape: tuple, out: tuple, device: torch.device, dtype: torch.dtype) -> None:
        x = torch.rand(shape, device=device, dtype=dtype) * 1000
        e = unwrap_energy(x)
        assert e.shape == out and e.dtype == dtype and e.device == x.device

    def test_batched_equals_per_image(self) -> None:
        g = torch.Generator().manual_seed(0)
        x = torch.randint(0, 2000, (2, 3, 7, 9), generator=g).double()
        e = unwrap_energy(x)
        for b in range(2):
            for c in range(3):
                assert float(e[b, c]) == pytest.approx(float(unwrap_energy(x[b, c])))

    def test_matches_numpy_solver_energy(self) -> None:
        rng = np.random.default_rng(1)
        x = rng.integers(0, 3000, (9, 11))
        for nb in (4, 8):
            expected = plane_energy(x, EnergyParams.make(8), pair_offsets(nb))
            assert float(unwrap_energy(torch.from_numpy(x).double(), neighborhood=nb)) == pytest.approx(expected)

    def test_gradcheck(self) -> None:
        g = torch.Generator().manual_seed(2)
        # Differences stay away from 0 and from x0 = 128, where V has kinks.
        x = (torch.arange(12, dtype=torch.float64).reshape(3, 4) * 37 + 0.5).requires_grad_(True)
        x.data += torch.rand(3, 4, generator=g, dtype=torch.float64) * 0.1
        assert torch.autograd.gradcheck(lambda t: unwrap_energy(t), (x,))

    def test_module_equals_function(self) -> None:
        x = torch.rand(2, 1, 6, 6) * 900
        torch.testing.assert_close(UnwrapEnergy(neighborhood=4)(x), unwrap_energy(x, neighborhood=4))

    def test_input_unmodified(self) -> None:
        x = torch.rand(1, 1, 4, 4) * 500
        before = x.clone()
        unwrap_energy(x)
        assert torch.equal(x, before)

    def test_exceptions(self) -> None:
        with pytest.raises(ValueError, match="5"):
            unwrap_energy(torch.zeros(4, 4), neighborhood=5)
        with pytest.raises(ValueError, match=r"\(4,\)"):
            unwrap_energy(torch.zeros(4))
        with pytest.raises(ValueError, match="NaN"):
            unwrap_energy(torch.tensor([[0.0, math.nan]]))
        with pytest.raises(TypeError, match="int64"):
            unwrap_energy(torch.zeros(3, 3, dtype=torch.int64))
        with pytest.raises(ValueError, match="6"):
            UnwrapEnergy(neighborhood=6)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_regression_potential_and_is_representable_refuse_nan_and_inf(bad):
    x = torch.tensor([0.0, bad])
    with pytest.raises(ValueError, match="x must be finite"):
        potential(x, bits=8)
    with pytest.raises(ValueError, match="x must be finite"):
        is_representable(x, bits=8)


@pytest.mark.parametrize("half", [torch.float16, torch.bfloat16])
def test_half_precision_energy_is_summed_in_float32(half: torch.dtype) -> None:
    counts = torch.randint(0, 2000, (1, 1, 64, 64), generator=torch.Generator().manual_seed(0)).float()
    energy = unwrap_energy(counts.to(half))  # float16 sums overflowed to inf
    assert energy.dtype == torch.float32 and bool(torch.isfinite(energy).all())
    if half == torch.float16:  # these counts are exact in float16: the same energy as float32's
        assert torch.allclose(energy, unwrap_energy(counts), rtol=1e-5)
