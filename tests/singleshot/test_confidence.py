"""Tests for unwrap_confidence / UnwrapConfidence: where a single-shot result's level is determined or guessed."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import torch_modulo as tm
from torch_modulo.singleshot import UnwrapConfidence, unwrap_confidence, unwrap_single
from torch_modulo.singleshot.confidence import bottleneck_steps
from torch_modulo.singleshot.grid import pair_offsets, pair_slices


def brute_bottleneck(image: np.ndarray, sources: np.ndarray, neighborhood: int) -> np.ndarray:
    """Minimax path steps from the ``sources`` mask by relaxation until nothing changes (Bellman-Ford style)."""
    h, w = image.shape
    b = np.where(sources, 0.0, np.inf)
    while True:
        old = b.copy()
        for off in pair_offsets(neighborhood):
            first, second = pair_slices(h, w, off)
            step = np.abs(image[first] - image[second])
            b[second] = np.minimum(b[second], np.maximum(b[first], step))
            b[first] = np.minimum(b[first], np.maximum(b[second], step))
        if np.array_equal(b, old):
            return b


def test_ramp_confidence_is_one_minus_step_over_half_period(device, dtype):
    ramp = torch.arange(0.0, 400.0, 40.0, device=device, dtype=dtype).reshape(1, -1)
    conf = unwrap_confidence(ramp, bits=8)
    assert conf.shape == ramp.shape and conf.dtype == dtype and conf.device == ramp.device
    expected = torch.full_like(ramp, 1 - 40 / 128)
    expected[0, 0] = 1.0  # the reference pixel
    torch.testing.assert_close(conf, expected)


def test_region_behind_a_cliff_has_zero_confidence(device, dtype):
    img = torch.zeros(12, 12, device=device, dtype=dtype)
    img[:, 6:] = 1000.0
    img[:, :6] += torch.arange(6.0, device=device, dtype=dtype)
    conf = unwrap_confidence(img, bits=8)
    assert torch.all(conf[:, 6:] == 0)
    assert torch.all(conf[:, :6] > 0.99)


def test_a_smooth_gap_in_the_cliff_joins_the_region():
    img = np.zeros((12, 12))
    img[:, 6:] = 1000.0
    img[5, :] = np.linspace(0.0, 1000.0, 12)  # one row climbs in steps of about 91 counts
    b = bottleneck_steps(img, bits=8, neighborhood=4)
    assert b[:, 6:].max() == pytest.approx(1000.0 / 11, rel=1e-9)
    conf = unwrap_confidence(torch.from_numpy(img), bits=8, neighborhood=4)
    assert float(conf[:, 6:].min()) == pytest.approx(1 - 1000.0 / 11 / 128)


@pytest.mark.parametrize("neighborhood", [4, 8])
@pytest.mark.parametrize("seed", range(4))
def test_bottleneck_equals_minimax_paths(neighborhood, seed):
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 4000, size=(9, 11)).astype(np.float64)
    img[2:6, 3:8] = 500.0  # the reference region: a plateau larger than any chance join of random values
    got = bottleneck_steps(img, bits=8, neighborhood=neighborhood)
    plateau = np.zeros(img.shape, dtype=bool)
    plateau[2:6, 3:8] = True
    np.testing.assert_allclose(got, brute_bottleneck(img, plateau, neighborhood))


def test_batches_are_per_plane_and_module_matches(dtype):
    rng = np.random.default_rng(0)
    batch = torch.from_numpy(np.cumsum(rng.integers(0, 90, size=(2, 3, 10, 14)), axis=-1).astype(np.float64)).to(dtype)
    out = unwrap_confidence(batch, bits=8)
    for b in range(2):
        for c in range(3):
            torch.testing.assert_close(out[b, c], unwrap_confidence(batch[b, c], bits=8))
    torch.testing.assert_close(UnwrapConfidence(bits=8)(batch), out)
    torch.testing.assert_close(tm.unwrap_confidence(batch[0]), out[0])
    assert unwrap_confidence(torch.tensor([[7.0]])).item() == 1.0


def test_flags_the_level_single_shot_had_to_guess():
    # A smooth ramp with a bright square 2176 counts up (8.5 periods): every edge of the square is steeper than
    # half a period, and whichever level unwrap_single picks, its border steps stay near half a period. The
    # confidence says the square's level is a guess, and the ramp's is not.
    y, x = np.mgrid[0:32, 0:32]
    truth = np.floor(10 + 20 * x + 5 * y).astype(np.float64)
    truth[10:20, 10:20] += 2176
    restored = unwrap_single(torch.from_numpy(truth % 256), bits=8)
    conf = unwrap_confidence(restored, bits=8).numpy()
    square = np.zeros(truth.shape, dtype=bool)
    square[10:20, 10:20] = True
    assert conf[square].max() < 0.25
    assert conf[~square].min() > 0.5
    wrong = ~tm.exact_k_map(restored[None, None], torch.from_numpy(truth)[None, None], 8)[0, 0].numpy()
    assert wrong.any() and conf[wrong].max() < 0.25  # the square went to a wrong level, and is flagged


@pytest.mark.parametrize(
    ("value", "error", "match"),
    [
        (torch.zeros(4, 4, dtype=torch.int64), TypeError, "floating"),
        (torch.tensor([[0.0, float("nan")]]), ValueError, "NaN|finite"),
        (torch.zeros(0, 4), ValueError, "empty"),
        (torch.zeros(5), ValueError, "dimension|shape"),
        (torch.zeros(1, 1, 1, 2, 2), ValueError, "dimension|shape"),
        ([[0.0, 1.0]], TypeError, "Tensor"),
    ],
)
def test_bad_input_is_named(value, error, match):
    with pytest.raises(error, match=match):
        unwrap_confidence(value)


def test_bad_settings_are_named():
    with pytest.raises(ValueError, match="6"):
        unwrap_confidence(torch.zeros(3, 3), neighborhood=6)
    with pytest.raises(ValueError, match="bits"):
        unwrap_confidence(torch.zeros(3, 3), bits=0)
    with pytest.raises(ValueError, match="6"):
        UnwrapConfidence(neighborhood=6)


def test_regression_float_bits_and_empty_batch():
    restored = torch.tensor([[[[0.0, 16.0, 32.0]]]])
    assert torch.equal(unwrap_confidence(restored, bits=8.0), unwrap_confidence(restored, bits=8))
    empty = unwrap_confidence(torch.zeros(0, 1, 4, 4), bits=8)
    assert empty.shape == (0, 1, 4, 4)
