"""Contract every tone-mapping operator keeps: shapes, range, batching, monotonicity, bad input."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
import torch
from tonemap_cases import GLOBAL, LUMINANCE_BASED, OPERATORS
from tonemap_cases import hdr as _hdr

import torch_modulo as tm
import torch_modulo.tonemap as tmo
from torch_modulo.tonemap import (
    tonemap_clahe,
    tonemap_gamma,
    tonemap_histogram,
    tonemap_log,
    tonemap_reinhard,
)


class TestContract:
    @pytest.mark.parametrize("name", list(OPERATORS))
    def test_smoke(self, name: str, device: torch.device, dtype: torch.dtype) -> None:
        out = OPERATORS[name](_hdr((1, 3, 8, 8), dtype=dtype).to(device))
        assert out.shape == (1, 3, 8, 8) and torch.isfinite(out).all()

    @pytest.mark.parametrize("name", list(OPERATORS))
    @pytest.mark.parametrize("shape", [(2, 3, 6, 7), (1, 1, 5, 9), (3, 6, 5), (1, 6, 5), (6, 5), (0, 3, 6, 6)])
    def test_cardinality(self, name: str, shape: tuple[int, ...], device: torch.device, dtype: torch.dtype) -> None:
        x = _hdr(shape, dtype=dtype).to(device)
        out = OPERATORS[name](x)
        assert out.shape == x.shape and out.dtype == dtype and out.device == x.device

    @pytest.mark.parametrize("name", list(OPERATORS))
    def test_range_and_input_unmodified(self, name: str, device: torch.device, dtype: torch.dtype) -> None:
        x = _hdr((2, 3, 12, 10), stops=30, dtype=dtype).to(device)
        x[0, :, 0, :3] = 0.0  # black pixels
        before = x.clone()
        out = OPERATORS[name](x)
        assert torch.equal(x, before)
        assert torch.isfinite(out).all() and float(out.min()) >= 0.0 and float(out.max()) <= 1.0
        assert float(out.max()) > 0.5  # not a degenerate all-black answer

    @pytest.mark.parametrize("name", list(OPERATORS))
    def test_srgb_option(self, name: str) -> None:
        x = _hdr((1, 3, 9, 9), seed=3)
        fn = {
            "histogram": tonemap_histogram,
            "reinhard": tonemap_reinhard,
            "gamma": tonemap_gamma,
            "log": tonemap_log,
            "clahe": lambda v, **kw: tonemap_clahe(v, grid_size=(2, 2), **kw),
        }[name]
        linear, encoded = fn(x), fn(x, srgb=True)
        import kornia

        assert torch.allclose(encoded, kornia.color.linear_rgb_to_rgb(linear).clamp(0, 1), atol=1e-12)
        grey = fn(x[:, :1], srgb=True)
        assert grey.shape == (1, 1, 9, 9) and float(grey.max()) <= 1.0

    @pytest.mark.parametrize("name", list(OPERATORS))
    def test_batched_equals_per_image(self, name: str, device: torch.device, dtype: torch.dtype) -> None:
        # Images of very different brightness and range: statistics must not leak across the batch.
        x = torch.cat(
            [
                _hdr((1, 3, 16, 12), seed=s, stops=st, dtype=dtype) * sc
                for s, st, sc in [(1, 4, 1e-3), (2, 20, 1.0), (3, 9, 5e3)]
            ]
        ).to(device)
        batched = OPERATORS[name](x)
        single = torch.cat([OPERATORS[name](x[i : i + 1]) for i in range(3)])
        assert torch.allclose(batched, single, atol=1e-6, rtol=0)
        assert OPERATORS[name](x[:0]).shape == (0, 3, 16, 12)

    @pytest.mark.parametrize("name", GLOBAL)
    def test_monotonic_grey(self, name: str, dtype: torch.dtype) -> None:
        # A shuffled log ramp over 24 stops: a global operator is one non-decreasing curve.
        gen = torch.Generator().manual_seed(5)
        values = torch.exp2(torch.linspace(-12, 12, 24 * 20, dtype=torch.float64))
        x = values[torch.randperm(values.numel(), generator=gen)].reshape(1, 1, 24, 20).to(dtype)
        out = OPERATORS[name](x).flatten()
        ordered = out[torch.argsort(x.flatten())]
        assert float(ordered.diff().min()) >= -1e-6
        assert float(ordered[-1] - ordered[0]) > 0.5

    @pytest.mark.parametrize("name", GLOBAL)
    def test_monotonic_fixed_colour(self, name: str) -> None:
        scales = torch.exp2(torch.linspace(-10, 10, 64, dtype=torch.float64))
        colour = torch.tensor([0.6, 1.0, 0.3], dtype=torch.float64)
        x = (colour[:, None] * scales[None]).reshape(1, 3, 8, 8)
        y = tmo.luminance(OPERATORS[name](x)).flatten()
        assert float(y.diff().min()) >= -1e-9

    @pytest.mark.parametrize("name", LUMINANCE_BASED)
    def test_colour_ratios_kept_where_nothing_clips(self, name: str) -> None:
        x = _hdr((1, 3, 16, 16), seed=7, stops=12)
        out = OPERATORS[name](x)
        keep = (out.amax(dim=1) < 0.999) & (out.amin(dim=1) > 1e-6)
        assert int(keep.sum()) > 50
        ratio_in = (x[:, 0] / x[:, 1])[keep]
        ratio_out = (out[:, 0] / out[:, 1])[keep]
        assert torch.allclose(ratio_out, ratio_in, rtol=1e-9)

    @pytest.mark.parametrize("name", GLOBAL)
    def test_autograd_path_equals_cpu_chunk_path(self, name: str) -> None:
        # Wide enough for several chunks, with a last partial chunk.
        x = _hdr((8, 3, 256, 611), seed=11, stops=20, dtype=torch.float32)
        x[3, :, 5, :17] = 0.0
        fast = OPERATORS[name](x)
        slow = OPERATORS[name](x.clone().requires_grad_(True))
        assert slow.requires_grad and not fast.requires_grad
        assert torch.allclose(fast, slow.detach(), atol=2e-6, rtol=0)

    @pytest.mark.parametrize("name", GLOBAL)
    def test_chunk_path_does_not_depend_on_thread_count(self, name: str) -> None:
        x = _hdr((8, 3, 64, 611), seed=12, dtype=torch.float32)  # several chunks, on one thread and on two
        threads = torch.get_num_threads()
        try:
            torch.set_num_threads(1)
            one = OPERATORS[name](x)
            torch.set_num_threads(2)
            two = OPERATORS[name](x)
        finally:
            torch.set_num_threads(threads)
        assert torch.equal(one, two)

    @pytest.mark.parametrize("name", list(OPERATORS))
    @pytest.mark.parametrize(
        ("bad", "error", "match"),
        [
            (torch.tensor([[[[-1.0, 2.0], [3.0, 4.0]]]]), ValueError, "must be >= 0; got min -1.0"),
            (torch.tensor([[1.0, float("nan")], [3.0, 4.0]]), ValueError, "1 NaN and 0 Inf"),
            (torch.tensor([[1.0, float("inf")], [3.0, 4.0]]), ValueError, "0 NaN and 1 Inf"),
            (torch.ones(1, 2, 4, 4), ValueError, "got 2 in shape \\(1, 2, 4, 4\\)"),
            (torch.ones(4, 4, 4), ValueError, "got 4 in shape \\(4, 4, 4\\)"),
            (torch.ones(4), ValueError, "got \\(4,\\)"),
            (torch.ones(1, 1, 3, 4, 4), ValueError, "got \\(1, 1, 3, 4, 4\\)"),
            (torch.ones(1, 3, 4, 4, dtype=torch.int64), TypeError, "int64"),
            ([[1.0, 2.0]], TypeError, "list"),
        ],
    )
    def test_bad_input(self, name: str, bad: object, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            OPERATORS[name](bad)


class TestFlagsAreBools:
    """Regression: flags were taken by truthiness, so ``srgb="no"`` switched the sRGB encoding on."""

    FUNCTIONS = {  # noqa: RUF012
        "histogram": tonemap_histogram,
        "reinhard": tonemap_reinhard,
        "gamma": tonemap_gamma,
        "log": tonemap_log,
        "clahe": lambda v, **kw: tonemap_clahe(v, grid_size=(2, 2), **kw),
    }

    @pytest.mark.parametrize("name", list(FUNCTIONS))
    @pytest.mark.parametrize("flag", ["no", 0, 1, None])
    def test_srgb_no_is_refused_by_the_function(self, name: str, flag: object) -> None:
        with pytest.raises(TypeError, match=f"srgb must be a bool; got {flag!r}"):
            self.FUNCTIONS[name](_hdr((1, 3, 8, 8)), srgb=flag)

    def test_numpy_bool_is_a_bool(self) -> None:
        x = _hdr((1, 3, 8, 8))
        assert torch.equal(tonemap_reinhard(x, srgb=np.bool_(True)), tonemap_reinhard(x, srgb=True))


class TestMemoryFormat:
    """Regression: channels-last input came back in the default layout; the result keeps the input's memory format
    (the output has the input's shape), with the same values."""

    CL = torch.channels_last

    @pytest.mark.parametrize("name", list(OPERATORS))
    @pytest.mark.parametrize("shape", [(2, 3, 12, 10), (3, 3, 64, 611)])  # the second spans several CPU chunks
    @pytest.mark.parametrize("grad", [False, True], ids=["chunked", "autograd"])
    def test_channels_last_kept(self, name: str, shape: tuple[int, ...], grad: bool, dtype: torch.dtype) -> None:
        x = _hdr(shape, seed=4, stops=20, dtype=dtype)
        xl = x.contiguous(memory_format=self.CL).requires_grad_(grad)
        out = OPERATORS[name](xl)
        assert out.is_contiguous(memory_format=self.CL) and not out.is_contiguous()
        assert torch.equal(out.detach(), OPERATORS[name](x.clone().requires_grad_(grad)).detach())
        if grad:
            out.sum().backward()
            assert xl.grad is not None and torch.isfinite(xl.grad).all()

    @pytest.mark.parametrize(
        ("fn", "module"),
        [
            (tonemap_reinhard, tmo.ReinhardToneMap),
            (tonemap_histogram, tmo.HistogramToneMap),
            (tonemap_log, tmo.LogToneMap),
            (tonemap_gamma, tmo.GammaToneMap),
        ],
    )
    def test_srgb_and_modules_keep_channels_last(
        self, fn: Callable[..., torch.Tensor], module: Callable[[], torch.nn.Module]
    ) -> None:
        x = _hdr((2, 3, 9, 7)).contiguous(memory_format=self.CL)
        assert fn(x, srgb=True).is_contiguous(memory_format=self.CL)
        assert module()(x).is_contiguous(memory_format=self.CL)

    @pytest.mark.parametrize("module", [tmo.ReinhardToneMap, tmo.LogToneMap, tmo.GammaToneMap])
    def test_compiled_keeps_channels_last(self, module: Callable[[], torch.nn.Module]) -> None:
        layer = module()
        x = _hdr((2, 3, 9, 7), dtype=torch.float32).contiguous(memory_format=self.CL)
        with tm.validation(False):
            out = torch.compile(layer, fullgraph=True, backend="eager")(x)
        assert out.is_contiguous(memory_format=self.CL)
        torch.testing.assert_close(out, layer(x))

    @pytest.mark.parametrize("name", list(OPERATORS))
    def test_default_layout_kept(self, name: str) -> None:
        x = _hdr((2, 3, 12, 10))
        assert OPERATORS[name](x).is_contiguous()
        grey = _hdr((2, 1, 12, 10)).contiguous(memory_format=self.CL)  # one channel: both layouts at once
        assert OPERATORS[name](grey).is_contiguous()
        assert OPERATORS[name](x[:0].contiguous(memory_format=self.CL)).shape == (0, 3, 12, 10)
