"""Tests for torch_modulo/tonemap.py: Larson et al. 1997 histogram adjustment, Reinhard 2002, gamma, log, CLAHE.

Independent references:
    - colour-hdri (test-only dependency, ``pip install colour-hdri``; tests skip without it):
      ``tonemapping_operator_gamma`` and ``tonemapping_operator_logarithmic`` for the gamma and logarithmic
      mappings, and ``log_average`` + ``tonemapping_operator_simple`` for Reinhard's operator without a white
      point. Agreement within 1e-4 absolute (float32) / 1e-6 (float64); colour-hdri computes luminance from the
      sRGB primaries (0.21264, 0.71517, 0.07219), which differs from the rounded Rec.709 weights at 1e-5.
    - Neither colour-hdri nor OpenCV implements Larson's operator or Reinhard's 2002 white point (OpenCV's
      TonemapReinhard and colour-hdri's Reinhard2004 are Reinhard and Devlin 2005, a different operator), so
      those are checked against NumPy references written here from the papers' equations and the 1997
      paper's histogram_ceiling pseudo-code (explicit loops, numpy.histogram, numpy.interp): the same author
      wrote both, so they guard against implementation slips, not against misreading the paper. Agreement
      within 1e-6 (float64) and 2e-4 (float32).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import torch_modulo.tonemap as tmo
from torch_modulo.tonemap import (
    ClaheToneMap,
    GammaToneMap,
    HistogramToneMap,
    LogToneMap,
    ReinhardToneMap,
    fovea_shape,
    tonemap_clahe,
    tonemap_gamma,
    tonemap_histogram,
    tonemap_log,
    tonemap_reinhard,
)

LUMA = np.array([0.2126, 0.7152, 0.0722])


def _hdr(
    shape: tuple[int, ...], seed: int = 0, stops: float = 16.0, dtype: torch.dtype = torch.float64
) -> torch.Tensor:
    """Log-uniform radiance spanning ``stops`` stops, with some colour."""
    gen = torch.Generator().manual_seed(seed)
    return torch.exp2(torch.rand(shape, generator=gen, dtype=torch.float64) * stops - stops / 2).to(dtype)


OPERATORS = {
    "histogram": lambda x: tonemap_histogram(x),
    "reinhard": lambda x: tonemap_reinhard(x),
    "gamma": lambda x: tonemap_gamma(x, percentile=99.0),
    "log": lambda x: tonemap_log(x),
    "clahe": lambda x: tonemap_clahe(x, grid_size=(2, 2)),
}
GLOBAL = ["histogram", "reinhard", "gamma", "log"]


LUMINANCE_BASED = ["histogram", "reinhard", "log", "clahe"]


# ---------------------------------------------------------------------------------------------- shared contract


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
    def test_autograd_path_equals_cpu_tile_path(self, name: str) -> None:
        # Wide enough for several tiles, with a last partial tile.
        x = _hdr((8, 3, 256, 611), seed=11, stops=20, dtype=torch.float32)
        x[3, :, 5, :17] = 0.0
        fast = OPERATORS[name](x)
        slow = OPERATORS[name](x.clone().requires_grad_(True))
        assert slow.requires_grad and not fast.requires_grad
        assert torch.allclose(fast, slow.detach(), atol=2e-6, rtol=0)

    @pytest.mark.parametrize("name", GLOBAL)
    def test_tile_path_does_not_depend_on_thread_count(self, name: str) -> None:
        x = _hdr((8, 3, 64, 611), seed=12, dtype=torch.float32)  # 10 tiles: two threads
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


# ---------------------------------------------------------------------------------------------- Larson et al. 1997


def _fovea_reference(y: np.ndarray, fh: int, fw: int) -> np.ndarray:
    """Block means over the windows adaptive average pooling uses: [floor(i H / n), ceil((i + 1) H / n))."""
    h, w = y.shape
    out = np.empty((fh, fw))
    for i in range(fh):
        r0, r1 = (i * h) // fh, -((-(i + 1) * h) // fh)
        for j in range(fw):
            c0, c1 = (j * w) // fw, -((-(j + 1) * w) // fw)
            out[i, j] = y[r0:r1, c0:c1].mean()
    return out


def larson_reference(
    rgb: np.ndarray,
    ld_min: float = 1.0,
    ld_max: float = 100.0,
    bins: int = 100,
    fov: float = 40.0,
    fovea: float = 1.0,
    tolerance: float = 0.025,
) -> np.ndarray:
    """Larson, Rushmeier and Piatko 1997 with the linear ceiling, for one (C, H, W) image, in plain NumPy."""
    y = rgb[0] if rgb.shape[0] == 1 else np.tensordot(LUMA, rgb, axes=1)
    h, w = y.shape
    longer = max(h, w)
    across = 2 * math.tan(math.radians(fov) / 2) / math.radians(fovea)
    fh = min(h, max(2, int(across * h / longer + 0.5)))
    fw = min(w, max(2, int(across * w / longer + 0.5)))
    samples = _fovea_reference(y, fh, fw).ravel()
    samples = samples[samples > 0]
    bright = np.log(samples)
    log_dmin, log_dmax = math.log(ld_min), math.log(ld_max)
    span = log_dmax - log_dmin
    b_min, b_max = bright.min(), bright.max()

    def linear() -> np.ndarray:
        ld = y * math.sqrt(ld_min * ld_max) / math.exp(bright.mean())
        return np.clip((ld - ld_min) / (ld_max - ld_min), 0, 1)

    display = None
    if b_max - b_min <= span:
        display = linear()
    else:
        hist = np.histogram(bright, bins=bins, range=(b_min, b_max))[0].astype(float)
        limit = tolerance * hist.sum()
        delta_b = (b_max - b_min) / bins
        while True:  # histogram_ceiling()
            total = hist.sum()
            if total < limit:
                display = linear()
                break
            ceiling = total * delta_b / span
            trimmings = 0.0
            for i in range(bins):
                if hist[i] > ceiling:
                    trimmings += hist[i] - ceiling
                    hist[i] = ceiling
            if trimmings <= limit:
                break
        if display is None:
            cdf = np.concatenate([[0.0], np.cumsum(hist)]) / hist.sum()
            with np.errstate(divide="ignore"):
                p = np.interp(np.log(y), np.linspace(b_min, b_max, bins + 1), cdf)
            ld = np.exp(log_dmin + span * p)
            display = (ld - ld_min) / (ld_max - ld_min)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(y > 0, display / y, 0.0)
    return np.clip(rgb * ratio, 0, 1)


class TestHistogram:
    def test_unit_hand_computed_ceiling(self, device: torch.device, dtype: torch.dtype) -> None:
        # 4 bins of one decade each over [1, 1e4] (log range 2x the 100:1 display, so the ceiling is T / 2).
        # Counts [5, 1, 1, 1]: the first bin is trimmed 5 -> 4 -> 3.5 -> 3.25 -> 3.125, where the trimmings
        # (0.125) fall below 2.5% of the original 8 samples (0.2).
        x = torch.tensor([[1.0, 2.0, 3.0, 4.0], [5.0, 50.0, 500.0, 10000.0]], device=device, dtype=dtype)
        out = tonemap_histogram(x, 1.0, 100.0, bins=4)
        cdf = [0.0, 3.125 / 6.125, 4.125 / 6.125, 5.125 / 6.125, 1.0]
        expected = []
        for v in x.flatten().tolist():
            u = math.log10(v)  # bin position: one bin per decade
            i = min(int(u), 3)
            p = cdf[i] + (u - i) * (cdf[i + 1] - cdf[i])
            expected.append((100.0**p - 1.0) / 99.0)
        tol = 1e-6 if dtype == torch.float64 else 2e-5
        assert torch.allclose(out.flatten().cpu().double(), torch.tensor(expected, dtype=torch.float64), atol=tol)
        assert float(out[1, 3]) == 1.0 and float(out[0, 0]) == 0.0

    def test_unit_scene_within_display_range_is_linear(self, dtype: torch.dtype) -> None:
        # 8:1 < 100:1: linear, the log average (2^1.5) shown at sqrt(1 * 100) = 10.
        x = torch.tensor([[1.0, 2.0], [4.0, 8.0]], dtype=dtype)
        ld = x.double() * 10.0 / 2.0**1.5
        expected = (ld - 1.0) / 99.0
        assert torch.allclose(tonemap_histogram(x).double(), expected, atol=1e-6)

    def test_unit_ceiling_empties_histogram_falls_back_to_linear(self) -> None:
        # Four samples, 100 bins: every trim removes 90%, the total drops below 2.5% -> linear mapping.
        x = torch.tensor([[1.0, 10.0], [1000.0, 1e5]], dtype=torch.float64)
        b_avg = float(torch.log(x).mean())
        e = (torch.log(x) - (b_avg - math.log(100.0) / 2)).clamp(0, math.log(100.0))
        expected = torch.expm1(e) / 99.0
        assert torch.allclose(tonemap_histogram(x), expected, atol=1e-12)

    def test_scale_invariant(self) -> None:
        x = _hdr((2, 3, 40, 30), seed=4, stops=20)
        assert torch.allclose(tonemap_histogram(x * 1e4), tonemap_histogram(x), atol=1e-9)

    def test_ceiling_never_exaggerates_contrast(self) -> None:
        # 80% of the scene in a narrow band: plain equalisation would stretch that band far beyond the world's
        # contrast; with the linear ceiling, display contrast (d log Ld / d log Lw) stays about 1 or below.
        gen = torch.Generator().manual_seed(9)
        n = 60 * 60
        band = 10.0 * torch.exp2(torch.rand(int(n * 0.8), generator=gen, dtype=torch.float64) * 0.3)
        rest = torch.exp2(torch.rand(n - band.numel(), generator=gen, dtype=torch.float64) * 20 - 6)
        values = torch.cat([band, rest])[torch.randperm(n, generator=gen)]
        x = values.reshape(1, 1, 60, 60)
        out = tonemap_histogram(x, bins=100, fov=100.0).flatten()  # fovea = every pixel
        log_lw, order = torch.sort(torch.log(values))
        log_ld = torch.log(1.0 + out[order] * 99.0)  # Ld = Ld_min + d (Ld_max - Ld_min)
        width = float(log_lw[-1] - log_lw[0]) / 100
        step = 40
        slope = (log_ld[step:] - log_ld[:-step]) / (log_lw[step:] - log_lw[:-step])
        wide = (log_lw[step:] - log_lw[:-step]) > 2 * width
        assert float(slope[wide].max()) <= 1.05
        assert float(slope[wide].min()) < 0.5  # compressed: not the linear fallback (slope 1 everywhere)
        # ... while plain histogram equalisation of the same samples would exceed the world's contrast 3-fold.
        hist = np.histogram(log_lw.numpy(), bins=100)[0]
        assert hist.max() / hist.sum() * 100 * math.log(100.0) / (float(log_lw[-1] - log_lw[0])) > 3

    @pytest.mark.parametrize("channels", [1, 3])
    def test_matches_numpy_reference(self, channels: int) -> None:
        x = _hdr((2, channels, 45, 70), seed=21, stops=22)
        x[1] *= 1e-3
        x[0, :, :4, :6] = 0.0
        out = tonemap_histogram(x)
        for i in range(2):
            ref = larson_reference(x[i].numpy())
            assert np.allclose(out[i].numpy(), ref, atol=1e-6)

    def test_matches_numpy_reference_float32(self) -> None:
        x = _hdr((1, 3, 120, 90), seed=22, stops=18)
        out = tonemap_histogram(x.float(), ld_min=0.5, ld_max=200.0, bins=50, fov=60.0)
        ref = larson_reference(x[0].numpy(), ld_min=0.5, ld_max=200.0, bins=50, fov=60.0)
        assert np.abs(out[0].double().numpy() - ref).max() < 2e-4

    def test_real_scene_matches_numpy_reference(self, shared_hdr) -> None:
        oiio = pytest.importorskip("OpenImageIO")
        path = shared_hdr / "hdr-samples" / "memorial.hdr"
        if not path.is_file():
            pytest.skip(f"{path} not found")
        inp = oiio.ImageInput.open(str(path))
        pixels = inp.read_image(oiio.FLOAT)
        inp.close()
        rgb = np.clip(np.asarray(pixels, dtype=np.float64)[..., :3], 0, None).transpose(2, 0, 1)
        out = tonemap_histogram(torch.from_numpy(rgb)[None])
        assert np.allclose(out[0].numpy(), larson_reference(rgb), atol=1e-6)
        # The paper's operator on a 15-stop scene: a full display range, most pixels neither black nor white.
        y = tmo.luminance(out)
        assert float(y.max()) > 0.95 and 0.05 < float(y.median()) < 0.8

    def test_fovea_shape(self) -> None:
        assert fovea_shape(768, 512) == (42, 28)
        assert fovea_shape(512, 768) == (28, 42)
        assert fovea_shape(4, 8) == (4, 8)  # never upsampled
        assert fovea_shape(1000, 10) == (42, 2)  # at least 2 samples
        assert fovea_shape(1000, 1000, fov=90.0, fovea=2.0) == (57, 57)

    def test_gradcheck(self) -> None:
        x = _hdr((1, 3, 5, 6), seed=31, stops=14).requires_grad_(True)
        # The histogram path, not the linear fallback: the cumulative distribution is not uniform.
        _, _, cumf, _ = tmo._histogram_tables(tmo.luminance(x.detach()).reshape(1, -1), 1.0, 100.0, 10, 0.025, 100)
        assert not torch.allclose(cumf, torch.linspace(0, 1, 11, dtype=cumf.dtype), atol=1e-3)
        assert torch.autograd.gradcheck(lambda v: tonemap_histogram(v, bins=10), (x,), atol=1e-6)

    def test_gradient_reaches_statistics(self) -> None:
        # Moving the darkest pixel moves the histogram's range, which moves every other pixel's display value.
        x = _hdr((1, 1, 4, 5), seed=32, stops=14).requires_grad_(True)
        tonemap_histogram(x, bins=10)[0, 0].sum().backward()
        darkest = int(x.detach().flatten().argmin())
        assert x.grad is not None and float(x.grad.flatten()[darkest].abs()) > 0

    def test_module_equals_function(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _hdr((2, 3, 20, 30), seed=33, dtype=dtype).to(device)
        module = HistogramToneMap(ld_min=2.0, ld_max=300.0, bins=64, fov=50.0, fovea=2.0, srgb=True).to(device)
        expected = tonemap_histogram(x, 2.0, 300.0, bins=64, fov=50.0, fovea=2.0, srgb=True)
        assert torch.equal(module(x), expected)
        assert "bins=64" in repr(module)

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"ld_min": 0.0}, ValueError, "ld_min must be a positive finite number; got 0.0"),
            ({"ld_min": 100.0, "ld_max": 10.0}, ValueError, "ld_max must be greater than ld_min"),
            ({"ld_max": float("inf")}, ValueError, "ld_max must be a positive finite number; got inf"),
            ({"bins": 1}, ValueError, "bins must be >= 2; got 1"),
            ({"bins": 10.0}, TypeError, "bins must be an integer; got 10.0"),
            ({"fov": 180.0}, ValueError, "fov must be below 180 degrees; got 180.0"),
            ({"fovea": -1.0}, ValueError, "fovea must be a positive finite number; got -1.0"),
            ({"tolerance": 1.0}, ValueError, "tolerance must be in \\(0, 1\\); got 1.0"),
            ({"max_iter": 0}, ValueError, "max_iter must be >= 1; got 0"),
            ({"srgb": "yes"}, TypeError, "srgb must be True or False; got 'yes'"),
        ],
    )
    def test_bad_arguments(self, kwargs: dict, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            HistogramToneMap(**kwargs)
        if "srgb" not in kwargs:
            with pytest.raises(error, match=match):
                tonemap_histogram(torch.ones(1, 3, 4, 4), **kwargs)


# ---------------------------------------------------------------------------------------------- Reinhard 2002


def reinhard_reference(rgb: np.ndarray, key: float, white: float | None, delta: float) -> np.ndarray:
    """Reinhard et al. 2002, Eqs. 1, 2 and 4, for one (C, H, W) image."""
    y = rgb[0] if rgb.shape[0] == 1 else np.tensordot(LUMA, rgb, axes=1)
    log_avg = np.exp(np.mean(np.log(delta + y)))
    big_l = key / log_avg * y
    l_white = big_l.max() if white is None else white
    ld = big_l * (1 + big_l / l_white**2) / (1 + big_l)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(y > 0, ld / y, 0.0)
    return np.clip(rgb * ratio, 0, 1)


class TestReinhard:
    def test_unit_hand_computed(self, device: torch.device, dtype: torch.dtype) -> None:
        x = torch.tensor([[1.0, 4.0], [16.0, 64.0]], device=device, dtype=dtype)  # log average 8
        # key 0.5: L = x / 16 = 1/16, 1/4, 1, 4.
        simple = tonemap_reinhard(x, key=0.5, white=float("inf"), delta=1e-12)
        assert torch.allclose(
            simple.cpu().double(), torch.tensor([[1 / 17, 0.2], [0.5, 0.8]], dtype=torch.float64), atol=1e-6
        )
        # white = 2: Ld = L (1 + L / 4) / (1 + L).
        white = tonemap_reinhard(x, key=0.5, white=2.0, delta=1e-12)
        expected = [[65 / (64 * 17), 0.25 * (1 + 1 / 16) / 1.25], [1.25 / 2, 1.0]]
        assert torch.allclose(white.cpu().double(), torch.tensor(expected, dtype=torch.float64), atol=1e-6)
        # white = None: the maximum, L = 4, maps to exactly 1; L = 1 to (1 + 1/16) / 2.
        auto = tonemap_reinhard(x, key=0.5, delta=1e-12)
        assert float(auto[1, 1]) == pytest.approx(1.0, abs=1e-6)
        assert float(auto[1, 0]) == pytest.approx(17 / 32, abs=1e-6)

    @pytest.mark.parametrize("white", [None, 3.0, float("inf")])
    def test_matches_numpy_reference(self, white: float | None) -> None:
        x = _hdr((2, 3, 17, 23), seed=41, stops=18)
        x[0, :, 0, :5] = 0.0
        out = tonemap_reinhard(x, key=0.36, white=white, delta=1e-4)
        for i in range(2):
            assert np.allclose(out[i].numpy(), reinhard_reference(x[i].numpy(), 0.36, white, 1e-4), atol=1e-9)

    def test_matches_colour_hdri_simple_operator(self) -> None:
        colour_hdri = pytest.importorskip("colour_hdri")
        from colour.constants import EPSILON
        from colour_hdri.tonemapping.global_operators.operators import log_average

        grey = _hdr((1, 1, 20, 30), seed=42, stops=14)
        a = 0.18
        scaled = a / log_average(grey.numpy(), EPSILON) * grey.numpy()
        ref = colour_hdri.tonemapping_operator_simple(scaled)
        for dtype, tol in [(torch.float64, 1e-6), (torch.float32, 1e-4)]:
            out = tonemap_reinhard(grey.to(dtype), key=a, white=float("inf"), delta=EPSILON)
            assert np.abs(out.double().numpy() - ref).max() < tol

    def test_gradcheck(self) -> None:
        x = _hdr((1, 3, 4, 5), seed=43, stops=8).requires_grad_(True)
        assert torch.autograd.gradcheck(lambda v: tonemap_reinhard(v, white=5.0), (x,))
        g = _hdr((1, 1, 4, 5), seed=44, stops=8).requires_grad_(True)
        assert torch.autograd.gradcheck(lambda v: tonemap_reinhard(v, key=0.09), (g,))  # through the maximum

    def test_module_equals_function(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _hdr((2, 3, 9, 8), seed=45, dtype=dtype).to(device)
        module = ReinhardToneMap(key=0.36, white=4.0, delta=1e-3)
        assert torch.equal(module(x), tonemap_reinhard(x, 0.36, 4.0, delta=1e-3))
        assert "key=0.36" in repr(module)

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"key": 0.0}, ValueError, "key must be a positive finite number; got 0.0"),
            ({"key": "0.18"}, TypeError, "key must be a real number; got '0.18'"),
            ({"white": -1.0}, ValueError, "white must be a positive number; got -1.0"),
            ({"delta": float("nan")}, ValueError, "delta must be a positive finite number; got nan"),
        ],
    )
    def test_bad_arguments(self, kwargs: dict, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            ReinhardToneMap(**kwargs)
        with pytest.raises(error, match=match):
            tonemap_reinhard(torch.ones(1, 3, 4, 4), **kwargs)


# ---------------------------------------------------------------------------------------------- gamma and log


class TestGamma:
    def test_unit_hand_computed(self, device: torch.device, dtype: torch.dtype) -> None:
        x = torch.tensor([[0.0, 0.25], [1.0, 8.0]], device=device, dtype=dtype)
        assert tonemap_gamma(x, gamma=2.0).cpu().tolist() == [[0.0, 0.5], [1.0, 1.0]]
        assert torch.allclose(
            tonemap_gamma(x, 2.0, exposure=-2.0).cpu(), torch.tensor([[0.0, 0.25], [0.5, 1.0]], dtype=dtype)
        )
        # percentile=100: the maximum luminance (8) reaches 1.
        auto = tonemap_gamma(x, gamma=1.0, percentile=100.0).cpu()
        assert torch.allclose(auto, torch.tensor([[0.0, 1 / 32], [1 / 8, 1.0]], dtype=dtype))

    def test_percentile_is_per_image(self) -> None:
        x = _hdr((1, 3, 10, 10), seed=51)
        x = torch.cat([x, x * 1000.0])
        out = tonemap_gamma(x, gamma=1.0, percentile=50.0)
        assert torch.allclose(out[0], out[1], atol=1e-12)
        assert float((tmo.luminance(out) >= 1.0 - 1e-12).double().mean()) <= 0.51

    def test_matches_colour_hdri(self) -> None:
        colour_hdri = pytest.importorskip("colour_hdri")
        x = _hdr((1, 3, 12, 14), seed=52, stops=10)
        for gamma, ev in [(2.2, -3.0), (1.0, 0.0), (1.8, -1.5)]:
            ref = np.clip(colour_hdri.tonemapping_operator_gamma(x[0].numpy().transpose(1, 2, 0), gamma, ev), 0, 1)
            out = tonemap_gamma(x, gamma, ev)[0].numpy().transpose(1, 2, 0)
            assert np.abs(out - ref).max() < 1e-9
            out32 = tonemap_gamma(x.float(), gamma, ev)[0].double().numpy().transpose(1, 2, 0)
            assert np.abs(out32 - ref).max() < 1e-4

    def test_gradcheck(self) -> None:
        x = torch.rand(1, 3, 4, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(53)) * 0.9 + 0.05
        x.requires_grad_(True)
        assert torch.autograd.gradcheck(lambda v: tonemap_gamma(v, 2.2), (x,))
        assert torch.autograd.gradcheck(lambda v: tonemap_gamma(v, 2.2, percentile=100.0), (x,))

    def test_module_equals_function(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _hdr((2, 3, 9, 8), seed=54, dtype=dtype).to(device)
        module = GammaToneMap(gamma=1.8, exposure=-1.0, percentile=95.0)
        assert torch.equal(module(x), tonemap_gamma(x, 1.8, -1.0, percentile=95.0))
        assert "percentile=95.0" in repr(module)

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"gamma": 0.0}, ValueError, "gamma must be a positive finite number; got 0.0"),
            ({"exposure": float("inf")}, ValueError, "exposure must be finite; got inf"),
            ({"percentile": 0.0}, ValueError, "percentile must be in \\(0, 100\\]; got 0.0"),
            ({"percentile": 101}, ValueError, "percentile must be in \\(0, 100\\]; got 101"),
            ({"exposure": None}, TypeError, "exposure must be a real number; got None"),
        ],
    )
    def test_bad_arguments(self, kwargs: dict, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            GammaToneMap(**kwargs)
        with pytest.raises(error, match=match):
            tonemap_gamma(torch.ones(1, 3, 4, 4), **kwargs)


class TestLog:
    def test_unit_hand_computed(self, device: torch.device, dtype: torch.dtype) -> None:
        x = torch.tensor([[0.0, 1.0], [3.0, 15.0]], device=device, dtype=dtype)
        assert torch.allclose(tonemap_log(x).cpu(), torch.tensor([[0.0, 0.25], [0.5, 1.0]], dtype=dtype))
        # exposure +1 doubles L: log(1 + 2x) / log(31).
        expected = torch.log1p(2 * x.cpu().double()) / math.log(31.0)
        assert torch.allclose(tonemap_log(x, exposure=1.0).cpu().double(), expected, atol=1e-6)
        # q = 3, k = 1: log(1 + 3x) / log(16), clipped at 1.
        expected = (torch.log1p(3 * x.cpu().double()) / math.log(16.0)).clamp(max=1.0)
        assert torch.allclose(tonemap_log(x, q=3.0).cpu().double(), expected, atol=1e-6)

    def test_matches_colour_hdri(self) -> None:
        colour_hdri = pytest.importorskip("colour_hdri")
        x = _hdr((1, 3, 12, 14), seed=61, stops=14) * 10
        for q, k in [(1.0, 1.0), (1.0, 4.0), (2.0, 8.0)]:
            ref = colour_hdri.tonemapping_operator_logarithmic(x[0].numpy().transpose(1, 2, 0), q, k)
            ref = np.clip(ref, 0, 1)
            out = tonemap_log(x, q, k)[0].numpy().transpose(1, 2, 0)
            assert np.abs(out - ref).max() < 1e-4  # luminance weights differ at 1e-5
            out32 = tonemap_log(x.float(), q, k)[0].double().numpy().transpose(1, 2, 0)
            assert np.abs(out32 - ref).max() < 2e-4

    def test_gradcheck(self) -> None:
        x = _hdr((1, 3, 4, 4), seed=62, stops=10).requires_grad_(True)
        assert torch.autograd.gradcheck(lambda v: tonemap_log(v, q=1.0, k=2.0, exposure=1.0), (x,))

    def test_module_equals_function(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _hdr((2, 3, 9, 8), seed=63, dtype=dtype).to(device)
        module = LogToneMap(q=2.0, k=3.0, exposure=-2.0)
        assert torch.equal(module(x), tonemap_log(x, 2.0, 3.0, -2.0))
        assert "q=2.0" in repr(module)

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"q": 0.0}, ValueError, "q must be a positive finite number; got 0.0"),
            ({"k": -2}, ValueError, "k must be a positive finite number; got -2"),
            ({"exposure": float("nan")}, ValueError, "exposure must be finite; got nan"),
            ({"q": True}, TypeError, "q must be a real number; got True"),
        ],
    )
    def test_bad_arguments(self, kwargs: dict, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            LogToneMap(**kwargs)
        with pytest.raises(error, match=match):
            tonemap_log(torch.ones(1, 3, 4, 4), **kwargs)


# ---------------------------------------------------------------------------------------------- CLAHE


class TestClahe:
    def test_unit_equals_kornia_on_normalised_log_luminance(self, device: torch.device, dtype: torch.dtype) -> None:
        import kornia

        x = _hdr((2, 3, 24, 20), seed=71, stops=16, dtype=dtype).to(device)
        y = tmo.luminance(x)
        b = torch.log(y)
        lo = b.amin(dim=(1, 2, 3), keepdim=True)
        hi = b.amax(dim=(1, 2, 3), keepdim=True)
        level = ((b - lo) / (hi - lo)).clamp(0, 1)
        eq = kornia.enhance.equalize_clahe(level, 3.0, (4, 4))
        expected = (x * eq / y).clamp(0, 1)
        assert torch.allclose(tonemap_clahe(x, 3.0, (4, 4)), expected, atol=1e-6)

    def test_global_grid_is_monotonic(self) -> None:
        values = torch.exp2(torch.linspace(-12, 12, 400, dtype=torch.float64))
        x = values[torch.randperm(400, generator=torch.Generator().manual_seed(72))].reshape(1, 1, 20, 20)
        out = tonemap_clahe(x, clip_limit=2.0, grid_size=(1, 1)).flatten()
        assert float(out[torch.argsort(x.flatten())].diff().min()) >= 0.0

    def test_scale_invariant(self) -> None:
        x = _hdr((1, 3, 32, 32), seed=73, stops=16)
        assert torch.allclose(tonemap_clahe(x * 1e3), tonemap_clahe(x), atol=1e-9)

    def test_black_pixels_take_the_equalised_value_as_grey(self) -> None:
        x = _hdr((1, 3, 16, 16), seed=74)
        x[0, :, 2, 3] = 0.0
        out = tonemap_clahe(x, grid_size=(2, 2))
        assert torch.equal(out[0, 0, 2, 3], out[0, 1, 2, 3]) and torch.equal(out[0, 1, 2, 3], out[0, 2, 2, 3])

    def test_differentiable_path(self) -> None:
        x = _hdr((1, 3, 12, 12), seed=75, stops=10).requires_grad_(True)
        out = tonemap_clahe(x, grid_size=(2, 2), differentiable=True)
        out.sum().backward()
        assert x.grad is not None and torch.isfinite(x.grad).all() and float(x.grad.abs().sum()) > 0

    def test_module_equals_function(self, device: torch.device, dtype: torch.dtype) -> None:
        x = _hdr((2, 3, 20, 24), seed=76, dtype=dtype).to(device)
        module = ClaheToneMap(clip_limit=4.0, grid_size=(3, 4), srgb=True)
        assert torch.equal(module(x), tonemap_clahe(x, 4.0, (3, 4), srgb=True))
        assert "grid_size=(3, 4)" in repr(module)

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"clip_limit": -1.0}, ValueError, "clip_limit must be >= 0 \\(0 disables clipping\\); got -1.0"),
            ({"grid_size": (0, 8)}, ValueError, "grid_size\\[0\\] must be >= 1; got 0"),
            ({"grid_size": 8}, TypeError, "grid_size must be a pair of integers \\(rows, columns\\); got 8"),
            ({"differentiable": 1}, TypeError, "differentiable must be True or False; got 1"),
        ],
    )
    def test_bad_arguments(self, kwargs: dict, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            ClaheToneMap(**kwargs)
        with pytest.raises(error, match=match):
            tonemap_clahe(torch.ones(1, 3, 16, 16), **kwargs)

    def test_image_smaller_than_grid(self) -> None:
        with pytest.raises(ValueError, match="larger than grid_size=\\(8, 8\\) along each axis; got 8x20"):
            tonemap_clahe(torch.ones(1, 3, 8, 20))
