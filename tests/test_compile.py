"""Layers that compile: ``torch.compile(layer, fullgraph=True)`` as they are (the value checks are off while
torch.compile traces), and the validation switch (torch_modulo/_checks.py) that turns the value checks off in eager
code.

Most tests trace with ``backend="eager"`` (Dynamo only: it is what ``fullgraph=True`` is about, and it compiles in
well under a second) or ``"aot_eager"`` (adds AOT autograd and functionalisation); one slow test runs Inductor.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
import torch
from torch import nn

import torch_modulo as tm

TAUS = [1.0, 16.0, 256.0]


@pytest.fixture(autouse=True)
def _fresh_dynamo() -> Iterator[None]:
    """Each test starts from an empty compile cache, so recompile limits and earlier guards do not carry over."""
    torch._dynamo.reset()
    yield
    torch._dynamo.reset()


def _radiance(shape: tuple[int, ...], seed: int = 0, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return torch.exp2(torch.rand(shape, generator=gen, dtype=torch.float64) * 12 - 6).to(dtype)


def _x() -> torch.Tensor:
    return _radiance((2, 3, 8, 8))


def _stack() -> tm.ExposureStack:
    return tm.MultiExposureCapture(TAUS, bits=8)(_x())


def _noisy(spatial: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
    """Noisy moduli of a noise-aware plan (for the decoder with spatial evidence: ``spatial``) and its exposures."""
    plan = tm.plan_exposures(12, 8, noise="q16", spatial=spatial)
    taus = torch.tensor(plan, dtype=torch.float64) / plan[-1]
    radiance = _x() * 2.0**6 / float(taus[0])
    return tm.sensors.SimulatedModuloSensor(8, "q16", seed=0)(radiance, taus).moduli, taus


#: name -> (layer factory, inputs factory, exact): exact layers compute integers and match eager bit for bit; the
#: tone maps match to float rounding (on the CPU the eager path runs in chunks with another operation order).
CASES: dict[str, tuple[Callable[[], nn.Module], Callable[[], tuple[object, ...]], bool]] = {
    "ModuloWrap": (lambda: tm.ModuloWrap(bits=8), lambda: (torch.floor(_x() * 97),), True),
    "ModuloCapture": (lambda: tm.ModuloCapture(exposure=40.0, bits=8), lambda: (_x(),), True),
    "IntensityCapture": (lambda: tm.IntensityCapture(exposure=40.0, bits=8), lambda: (_x(),), True),
    "MultiExposureCapture": (lambda: tm.MultiExposureCapture(TAUS, bits=8), lambda: (_x(),), True),
    "MultiExposureUnwrap": (lambda: tm.MultiExposureUnwrap(bits=8), lambda: (_stack(),), True),
    "MultiExposureUnwrap-pair": (lambda: tm.MultiExposureUnwrap(bits=8), lambda: tuple(_stack()), True),
    "MultiExposureUnwrap-paper": (lambda: tm.MultiExposureUnwrap(bits=8, method="paper"), lambda: (_stack(),), True),
    "chain": (
        lambda: nn.Sequential(tm.MultiExposureCapture(TAUS, bits=8), tm.MultiExposureUnwrap(bits=8)),
        lambda: (_x(),),
        True,
    ),
    "MultiExposureUnwrap-noise": (lambda: tm.MultiExposureUnwrap(bits=8, noise="q16"), lambda: _noisy(), False),
    "MultiExposureUnwrap-spatial": (
        lambda: tm.MultiExposureUnwrap(bits=8, noise="q16", spatial=True),
        lambda: _noisy(spatial=True),
        False,
    ),
    "GammaToneMap": (lambda: tm.GammaToneMap(), lambda: (_x(),), False),
    "GammaToneMap-percentile-srgb": (
        lambda: tm.GammaToneMap(gamma=1.0, exposure=-1.5, percentile=99.0, srgb=True),
        lambda: (_x(),),
        False,
    ),
    "LogToneMap": (lambda: tm.LogToneMap(), lambda: (_x(),), False),
    "LogToneMap-float64-fallback": (lambda: tm.LogToneMap(exposure=120.0), lambda: (_x() * 100,), False),
    "ReinhardToneMap": (lambda: tm.ReinhardToneMap(), lambda: (_x(),), False),
    "ReinhardToneMap-white-grey": (lambda: tm.ReinhardToneMap(key=0.36, white=2.0), lambda: (_x()[:, :1],), False),
}


def _assert_same(out: object, ref: object, exact: bool) -> None:
    if isinstance(ref, tuple):
        assert isinstance(out, tuple) and type(out) is type(ref)
        for o, r in zip(out, ref, strict=True):
            _assert_same(o, r, exact)
        return
    assert isinstance(out, torch.Tensor) and isinstance(ref, torch.Tensor)
    assert out.shape == ref.shape and out.dtype == ref.dtype
    if exact:
        assert torch.equal(out, ref)
    else:
        torch.testing.assert_close(out, ref)


class TestFullGraph:
    @pytest.mark.parametrize("name", list(CASES))
    def test_fullgraph_equals_eager(self, name: str) -> None:
        make, inputs, exact = CASES[name]
        layer, args = make(), inputs()
        out = torch.compile(layer, fullgraph=True, backend="eager")(*args)
        _assert_same(out, layer(*args), exact)

    @pytest.mark.parametrize(
        "name",
        [
            "ModuloCapture",
            "MultiExposureCapture",
            "chain",
            "LogToneMap",
            "ReinhardToneMap",
            "MultiExposureUnwrap-spatial",
        ],
    )
    def test_aot_eager(self, name: str) -> None:
        make, inputs, exact = CASES[name]
        layer, args = make(), inputs()
        out = torch.compile(layer, fullgraph=True, backend="aot_eager")(*args)
        _assert_same(out, layer(*args), exact)

    def test_no_graph_break(self) -> None:
        for name in (
            "ModuloWrap",
            "MultiExposureCapture",
            "MultiExposureUnwrap",
            "MultiExposureUnwrap-noise",
            "MultiExposureUnwrap-spatial",
            "LogToneMap",
        ):
            make, inputs, _ = CASES[name]
            explained = torch._dynamo.explain(make())(*inputs())
            assert explained.graph_break_count == 0, (name, explained.break_reasons)

    def test_layers_with_other_options_compile_in_the_same_process(self) -> None:
        # A second compile of the same forward with new float options makes them symbolic: still one graph.
        x = _x()
        for layer in (tm.LogToneMap(), tm.LogToneMap(q=2.5, k=3.5, exposure=1.25), tm.LogToneMap(exposure=120.0)):
            torch.testing.assert_close(torch.compile(layer, fullgraph=True, backend="eager")(x * 100), layer(x * 100))
        for layer in (tm.GammaToneMap(), tm.GammaToneMap(gamma=1.7, exposure=1.5)):
            torch.testing.assert_close(torch.compile(layer, fullgraph=True, backend="eager")(x), layer(x))
        for layer in (tm.ReinhardToneMap(), tm.ReinhardToneMap(key=0.09, white=float("inf"), delta=1e-4)):
            torch.testing.assert_close(torch.compile(layer, fullgraph=True, backend="eager")(x), layer(x))

    def test_unwrap_unsorted_and_per_batch_exposures(self) -> None:
        x = _x()
        taus = torch.tensor([[256.0, 1.0, 16.0], [4.0, 1024.0, 64.0]], dtype=torch.float64)
        moduli = tm.capture_stack(x, taus, 8)
        layer = tm.MultiExposureUnwrap(bits=8, return_counts=True)
        out = torch.compile(layer, fullgraph=True, backend="eager")(moduli, taus)
        assert torch.equal(out, layer(moduli, taus))

    def test_unbatched_chain(self) -> None:
        chain = nn.Sequential(tm.MultiExposureCapture(TAUS, bits=8), tm.MultiExposureUnwrap(bits=8))
        x = _x()[0]
        out = torch.compile(chain, fullgraph=True, backend="eager")(x)
        assert out.shape == x.shape and torch.equal(out, chain(x))

    def test_straight_through_gradient(self) -> None:
        layer = tm.MultiExposureCapture(TAUS, bits=8, straight_through=True)
        x = _radiance((1, 3, 4, 4), dtype=torch.float64).requires_grad_()
        torch.compile(layer, fullgraph=True, backend="aot_eager")(x).moduli.sum().backward()
        assert torch.allclose(x.grad, torch.full_like(x, sum(TAUS)))

    @pytest.mark.slow
    def test_inductor(self) -> None:
        names = ("ModuloWrap", "ModuloCapture", "MultiExposureCapture", "chain", "GammaToneMap", "LogToneMap")
        for name in (*names, "MultiExposureUnwrap-noise", "MultiExposureUnwrap-spatial"):
            make, inputs, exact = CASES[name]
            layer, args = make(), inputs()
            out = torch.compile(layer, fullgraph=True)(*args)
            _assert_same(out, layer(*args), exact)


class TestValidationSwitch:
    def test_on_by_default(self) -> None:
        assert tm.validation_enabled() is True

    def test_off_skips_the_value_checks(self) -> None:
        negative = torch.full((1, 1, 2, 2), -1.0)
        with tm.validation(False):
            assert not tm.validation_enabled()
            tm.capture_modulo(negative, 1.0, 8)
            tm.capture_stack(negative, TAUS, 8)
            tm.tonemap_reinhard(negative)
            tm.unwrap_multi(torch.full((1, 2, 1, 2, 2), 300.0), [1.0, 16.0], 8)
            tm.ModuloCapture(exposure=1.0)(torch.tensor([float("nan")]))
        assert tm.validation_enabled()
        with pytest.raises(ValueError, match="radiance must be >= 0; got min -1.0"):
            tm.capture_modulo(negative, 1.0, 8)

    def test_off_keeps_the_free_checks(self) -> None:
        with tm.validation(False):
            with pytest.raises(TypeError, match="radiance must be a floating-point tensor"):
                tm.capture_modulo(torch.ones(2, dtype=torch.int64))
            with pytest.raises(ValueError, match="bits must be >= 1; got 0"):
                tm.modulo_wrap(torch.ones(2), bits=0)
            with pytest.raises(ValueError, match="gamma must be a positive finite number"):
                tm.tonemap_gamma(torch.ones(2, 2), gamma=0.0)

    def test_compiled_code_skips_the_value_checks(self) -> None:
        # The value checks read tensor values: compiled code skips them by itself, whatever the switch; eager code
        # still checks. Types, shapes and arguments are checked in both.
        layer = tm.ModuloCapture(exposure=2.0, bits=8)
        compiled = torch.compile(layer, fullgraph=True, backend="eager")
        negative = torch.full((1, 1, 2, 2), -1.0)
        with tm.validation(True):  # unchecked: floor(2 x -1) mod 256, as eager code with the checks off gives
            assert torch.equal(compiled(negative), torch.full((1, 1, 2, 2), 254.0))
        with pytest.raises(ValueError, match="radiance must be >= 0; got min -1.0"):
            layer(negative)
        with pytest.raises(TypeError, match="radiance must be a floating-point tensor"):  # (a graph break raises it)
            torch.compile(layer, backend="eager")(torch.ones(1, 1, 2, 2, dtype=torch.int64))

    def test_set_validation_returns_previous(self) -> None:
        try:
            assert tm.set_validation(False) is True
            assert tm.set_validation(False) is False
        finally:
            tm.set_validation(True)
        assert tm.validation_enabled()

    def test_restored_after_an_exception_and_nesting(self) -> None:
        with pytest.raises(RuntimeError, match="boom"), tm.validation(False):
            with tm.validation(True):
                assert tm.validation_enabled()
            assert not tm.validation_enabled()
            raise RuntimeError("boom")
        assert tm.validation_enabled()

    def test_decorator(self) -> None:
        @tm.validation(False)
        def capture(x: torch.Tensor) -> torch.Tensor:
            return tm.capture_modulo(x, 1.0, 8)

        capture(torch.full((2,), -1.0))
        assert tm.validation_enabled()

    @pytest.mark.parametrize("value", ["no", 0, 1, None])
    def test_refuses_non_bools(self, value: object) -> None:
        with pytest.raises(TypeError, match=f"enabled must be a bool; got {value!r}"):
            tm.set_validation(value)  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="enabled must be a bool"), tm.validation(value):  # type: ignore[arg-type]
            pass
        assert tm.validation_enabled()
