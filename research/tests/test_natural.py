"""Tests of research.natural: the natural-image model for single-shot unwrapping."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from research.natural import (
    NaturalOptions,
    NaturalUnwrap,
    fit_bounds,
    natural_energy,
    unwrap_natural,
    unwrap_natural_torch,
)
from torch_modulo.singleshot.energy import unwrap_energy


def _smooth_scene(channels: int = 1, h: int = 24, w: int = 32, seed: int = 0) -> np.ndarray:
    """A smooth positive scene (ramps and a wide bump) whose neighbour steps stay well below half a period."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:h, :w].astype(np.float64)
    out = []
    for c in range(channels):
        base = 40 + 30 * xx + 12 * yy + 600 * np.exp(-((yy - h / 2) ** 2 + (xx - w / 3) ** 2) / 60.0)
        out.append(np.floor(base * (1 + 0.1 * c) + rng.uniform(0, 3, (h, w))))
    return np.stack(out)


def _disk_scene() -> tuple[np.ndarray, np.ndarray]:
    """A textured bright disk (about 3000 counts) inside a steep edge on a textured background (about 300)."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:32, :32]
    disk = (yy - 16) ** 2 + (xx - 16) ** 2 < 64
    truth = np.floor(np.where(disk, 3000.0, 300.0) * (1 + 0.05 * rng.standard_normal((32, 32))))
    return truth[None], disk


# ------------------------------------------------------------------------------------------------ smoke


@pytest.mark.parametrize(
    "options",
    [{}, {"potential": "linear", "links": (64.0, 0.0)}, {"potential": "linear", "links": (16.0,), "max_step": 2}],
)
def test_smooth_scene_recovered_exactly(options: dict) -> None:
    truth = _smooth_scene()
    assert truth.max() > 4 * 256  # several rollovers
    restored, info = unwrap_natural(np.mod(truth, 256), 8, **options)
    np.testing.assert_array_equal(restored, truth)
    assert info["energy"] <= info["energy_init"] + 1e-9


def test_colour_smooth_scene_recovered_exactly() -> None:
    truth = _smooth_scene(channels=3)
    restored, _ = unwrap_natural(np.mod(truth, 256), 8, colour=1.0, smooth=1.0, rho="laplace", links=(64.0, 0.0))
    np.testing.assert_array_equal(restored, truth)


@pytest.mark.parametrize("shape", [(1, 5, 7), (3, 6, 4), (2, 1, 9), (9, 8)])
def test_shapes(shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(1)
    m = rng.integers(0, 256, size=shape).astype(np.float64)
    restored, info = unwrap_natural(m, 8, return_confidence=True)
    assert restored.shape == m.shape
    assert info["confidence"].shape == m.shape
    # Restored values keep the modulus and have k >= 0.
    np.testing.assert_array_equal(np.mod(restored, 256), m)
    assert restored.min() >= 0


def test_max_count_bounds_k() -> None:
    rng = np.random.default_rng(2)
    m = rng.integers(0, 256, size=(1, 12, 12)).astype(np.float64)
    restored, _ = unwrap_natural(m, 8, max_count=1023)
    assert restored.max() <= 1023
    np.testing.assert_array_equal(np.mod(restored, 256), m)


def test_fit_bounds_hand_computed() -> None:
    k = np.array([[3, 4, 5], [9, 4, 3]])
    kmax = np.full(k.shape, 2)
    # Shift -3 puts 5 of 6 values in [0, 2] (3, 4, 5 -> 0, 1, 2; 4, 3 -> 1, 0); 9 -> 6 is clipped to 2.
    np.testing.assert_array_equal(fit_bounds(k, kmax), [[0, 1, 2], [2, 1, 0]])


def test_confidence_marks_the_ambiguous_region() -> None:
    truth = _smooth_scene()
    _, info = unwrap_natural(np.mod(truth, 256), 8, return_confidence=True)
    conf = info["confidence"]
    assert np.all(conf >= 0)
    assert np.isfinite(conf).any()


# ------------------------------------------------------------------------------------------------- model


def test_log_model_prefers_truth_where_paper_energy_does_not() -> None:
    """Steep edges: the paper's Eq. 3/5 prefers the disk pulled down by 9 periods; the log model prefers the truth."""
    truth, disk = _disk_scene()
    wrong = truth - 9 * 256 * disk
    paper_truth = float(unwrap_energy(torch.from_numpy(truth[0]), 8))
    paper_wrong = float(unwrap_energy(torch.from_numpy(wrong[0]), 8))
    assert paper_wrong < paper_truth
    assert natural_energy(truth, 8) < natural_energy(wrong, 8)


def test_natural_energy_hand_computed() -> None:
    # One pair of values 0 and 240 with offset 16: du = log(256 / 16) = log 16; rho = log(1 + (du / 0.1)^2).
    img = np.array([[[0.0, 240.0]]])
    expected = np.log1p((np.log(16.0) / 0.1) ** 2)
    assert natural_energy(img, 8, jacobian=0.0) == pytest.approx(expected)
    assert natural_energy(img, 8) == pytest.approx(expected + np.log(16.0) + np.log(256.0))


# ---------------------------------------------------------------------------------------------- exceptions


@pytest.mark.parametrize(
    ("modulus", "error", "text"),
    [
        (np.full((2, 3), 256.0), ValueError, "256"),
        (np.full((2, 3), -1.0), ValueError, "-1"),
        (np.full((2, 3), 1.5), ValueError, "1.5"),
        (np.zeros((1, 2, 3, 4)), ValueError, "(1, 2, 3, 4)"),
        (np.zeros(5), ValueError, "(5,)"),
        (np.array([["a"]]), TypeError, "<U1"),
    ],
)
def test_bad_modulus(modulus: np.ndarray, error: type, text: str) -> None:
    with pytest.raises(error, match=__import__("re").escape(text)):
        unwrap_natural(modulus, 8)


@pytest.mark.parametrize(
    ("options", "error", "text"),
    [
        ({"bogus": 1}, TypeError, "bogus"),
        ({"potential": "cubic"}, ValueError, "cubic"),
        ({"rho": "cauchy"}, ValueError, "cauchy"),
        ({"sigma": 0.0}, ValueError, "0.0"),
        ({"sigma": "x"}, TypeError, "'x'"),
        ({"offset": -2.0}, ValueError, "-2.0"),
        ({"neighborhood": 6}, ValueError, "6"),
        ({"max_step": 0}, ValueError, "0"),
        ({"rounds": 1.5}, TypeError, "1.5"),
        ({"links": (-1.0,)}, ValueError, "-1.0"),
        ({"max_count": -5}, ValueError, "-5"),
        ({"max_count": float("nan")}, TypeError, "nan"),
    ],
)
def test_bad_options(options: dict, error: type, text: str) -> None:
    with pytest.raises(error, match=__import__("re").escape(text)):
        NaturalOptions.make(**options)
    with pytest.raises(error, match=__import__("re").escape(text)):
        unwrap_natural(np.zeros((1, 3, 3)), 8, **options)


def test_bad_bits_and_init() -> None:
    with pytest.raises(ValueError, match="0"):
        unwrap_natural(np.zeros((1, 3, 3)), 0)
    with pytest.raises(ValueError, match=r"\(1, 2, 2\)"):
        unwrap_natural(np.zeros((1, 3, 3)), 8, init=np.zeros((1, 2, 2)))


# ------------------------------------------------------------------------------------------ torch contract


def test_torch_wrapper_contract(dtype: torch.dtype, device: torch.device) -> None:
    truth = torch.from_numpy(np.stack([_smooth_scene(1, 10, 12, seed=s) for s in range(2)]))  # (2, 1, 10, 12)
    modulus = torch.remainder(truth, 256).to(device, dtype)
    before = modulus.clone()
    out = unwrap_natural_torch(modulus, 8, links=())
    assert torch.equal(modulus, before)
    assert out.dtype == dtype and out.device == modulus.device and out.shape == modulus.shape
    per_image = torch.stack([unwrap_natural_torch(m, 8, links=()) for m in modulus])
    torch.testing.assert_close(out, per_image)
    # Smooth scenes are recovered up to one global number of periods per image (the unidentifiable constant).
    diff = out.double().cpu() - truth
    assert torch.all(diff == diff.flatten(1)[:, :1, None, None])
    assert torch.all(torch.remainder(diff, 256) == 0)
    module = NaturalUnwrap(8, links=())
    torch.testing.assert_close(module(modulus), out)
    empty = unwrap_natural_torch(modulus[:0], 8)
    assert empty.shape == (0, 1, 10, 12)


def test_torch_wrapper_rejects_integer_tensor() -> None:
    with pytest.raises(TypeError, match="int64"):
        unwrap_natural_torch(torch.zeros(3, 3, dtype=torch.int64))


def test_module_rejects_bad_options() -> None:
    with pytest.raises(TypeError, match="bogus"):
        NaturalUnwrap(8, bogus=1)
