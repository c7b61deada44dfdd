"""Tests for torch_modulo/tonemap/histogram.py: Larson, Rushmeier and Piatko 1997 histogram adjustment.

Neither colour-hdri nor OpenCV implements Larson's operator, so it is checked against a NumPy reference written
here from the paper's equations and its histogram_ceiling pseudo-code (explicit loops, numpy.histogram,
numpy.interp): the same author wrote both, so it guards against implementation slips, not against misreading the
paper. Agreement within 1e-6 (float64) and 2e-4 (float32).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from tonemap_cases import LUMA
from tonemap_cases import hdr as _hdr

import torch_modulo.tonemap as tmo
from torch_modulo.tonemap import (
    HistogramToneMap,
    fovea_shape,
    tonemap_histogram,
)
from torch_modulo.tonemap.histogram import _histogram_tables


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
        _, _, cumf, _ = _histogram_tables(tmo.luminance(x.detach()).reshape(1, -1), 1.0, 100.0, 10, 0.025, 100)
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
            ({"srgb": "yes"}, TypeError, "srgb must be a bool; got 'yes'"),
        ],
    )
    def test_bad_arguments(self, kwargs: dict, error: type[Exception], match: str) -> None:
        with pytest.raises(error, match=match):
            HistogramToneMap(**kwargs)
        if "srgb" not in kwargs:
            with pytest.raises(error, match=match):
                tonemap_histogram(torch.ones(1, 3, 4, 4), **kwargs)


class TestHistogramPrecision:
    """Regression: dim half-precision input gave NaN and a wrong mapping.

    In float16 the pixels were clamped at float16's smallest normal number (6e-5), the ratio
    ``expm1(span P) / Y`` overflowed 65504 for them (and ``0 * inf`` gave NaN in a black channel), and log
    brightness carried only 11 significant bits. The operator documents that scaling the input does not change
    the output.
    """

    @pytest.mark.parametrize("grad", [False, True], ids=["chunked", "autograd"])
    @pytest.mark.parametrize(("narrow", "tol"), [(torch.float16, 2e-3), (torch.bfloat16, 8e-3)])
    @pytest.mark.parametrize("scale", [1e-4, 3e-3, 1.0, 100.0])
    def test_half_equals_float32(self, scale: float, narrow: torch.dtype, tol: float, grad: bool) -> None:
        x = (_hdr((2, 3, 24, 40), seed=34, stops=16) * scale).to(narrow)  # 2**-8 .. 2**8 times the scale
        x[0, 1, :, :5] = 0.0  # a black channel in coloured pixels
        expected = tonemap_histogram(x.float())
        out = tonemap_histogram(x.clone().requires_grad_(grad))
        assert out.dtype == narrow and out.shape == x.shape
        assert torch.isfinite(out).all()
        assert float((out.detach().float() - expected).abs().max()) < tol

    def test_half_real_scene(self, shared_hdr) -> None:  # noqa: ANN001
        from torch_modulo.io import read_image

        x = read_image(shared_hdr / "polyhaven-cc0" / "apartment.exr")[None].clamp_min(0.0)
        expected = tonemap_histogram(x)
        for scale in (1e-4, 1e-3, 1.0):
            out = tonemap_histogram((x * scale).half())
            assert out.dtype == torch.float16 and torch.isfinite(out).all()
            assert float((out.float() - expected).abs().max()) < 2e-3, scale

    @pytest.mark.parametrize("grad", [False, True], ids=["chunked", "autograd"])
    def test_float32_invariant_to_scale(self, grad: bool) -> None:
        x = _hdr((1, 3, 24, 40), seed=35, stops=16)  # 2**-8 .. 2**8
        expected = tonemap_histogram(x)
        for scale in (1e-30, 1e-20, 1e-6, 1e6, 1e20, 1e30):
            out = tonemap_histogram((x * scale).float().requires_grad_(grad)).detach()
            assert torch.isfinite(out).all()
            assert float((out.double() - expected).abs().max()) < 1e-4, scale

    @pytest.mark.parametrize("grad", [False, True], ids=["chunked", "autograd"])
    def test_float16_invariant_to_scale(self, grad: bool) -> None:
        # Powers of two that keep every value a normal float16 scale the half input exactly, so the result is the
        # float32 result of the unscaled input up to float16 rounding.
        x = _hdr((1, 3, 24, 40), seed=36, stops=8).half()  # 2**-4 .. 2**4
        expected = tonemap_histogram(x.float())
        for scale in (2.0**-10, 2.0**-5, 1.0, 2.0**5, 2.0**11):
            out = tonemap_histogram((x * scale).requires_grad_(grad)).detach()
            assert out.dtype == torch.float16 and torch.isfinite(out).all()
            assert float((out.float() - expected).abs().max()) < 2e-3, scale


def test_display_contrast_beyond_the_work_dtype_is_refused() -> None:
    x = torch.rand(1, 3, 8, 8)
    x[:, 0] = 0.0  # a black channel: 0 * inf was NaN there
    with pytest.raises(ValueError, match=r"ld_max / ld_min must be at most 1e\+30 .*ld_max=1e\+40"):
        tmo.tonemap_histogram(x, ld_max=1e40)
    out = tmo.tonemap_histogram(x, ld_max=1e30)
    assert bool(torch.isfinite(out).all()) and float(out.max()) <= 1.0
