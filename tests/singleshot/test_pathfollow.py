"""Tests for path following: torch_modulo.singleshot.pathfollow."""

from __future__ import annotations

import numpy as np
import pytest

from torch_modulo.singleshot.pathfollow import (
    quality_guided_colour_k,
    quality_guided_k,
    residue_density,
    smooth_wrapped,
)


def smooth_scene(h: int, w: int, seed: int, peak: float = 3000.0) -> np.ndarray:
    """Integer counts of a smooth scene (two Gaussian bumps on a ramp) with a dark corner at k = 0.

    The bumps are kept gentle enough (steepest step below about 100 counts per pixel) that the true image is
    what the energy prefers.
    """
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    sigma = 0.25 * max(h, w)
    peak = min(peak, 100.0 * sigma)
    img = 20 + 3 * x
    for _ in range(2):
        cy, cx = rng.uniform(0.4, 0.6) * h, rng.uniform(0.4, 0.6) * w
        img += peak * np.exp(-((y - cy) ** 2 + (x - cx) ** 2) / (2 * sigma**2))
    return np.floor(img).astype(np.int64)


class TestQualityGuided:
    @pytest.mark.parametrize("seed", range(3))
    def test_recovers_smooth_scene_up_to_offset(self, seed: int) -> None:
        truth = smooth_scene(30, 25, seed=seed)
        k = quality_guided_k(truth % 256, 8)
        diff = truth // 256 - k
        assert np.all(diff == diff.flat[0])

    def test_single_pixel(self) -> None:
        assert quality_guided_k(np.array([[7]]), 8).tolist() == [[0]]

    def test_residue_density(self) -> None:
        assert residue_density(smooth_scene(20, 20, seed=0) % 256, 8) == 0.0
        # One 2 x 2 loop whose wrapped differences go 0 -> 100 -> 200 -> 44 (= 300) -> 0 does not close.
        loop = np.array([[0, 100], [44, 200]])
        assert residue_density(loop, 8) == 1.0
        assert residue_density(np.zeros((1, 5)), 8) == 0.0


def test_colour_k_of_one_channel_is_quality_guided_k() -> None:
    modulus = smooth_scene(12, 14, seed=4) % 256
    assert np.array_equal(quality_guided_colour_k(modulus[None], 8)[0], quality_guided_k(modulus, 8))


def test_smooth_wrapped_keeps_flat_images_across_the_wrap() -> None:
    # Values on both sides of the wrap (250 and 4 are 10 counts apart): the phasor average lands between them,
    # at 255 or 0, where averaging the values themselves would give 127.
    modulus = np.where(np.arange(10)[None, :] % 2 == 0, 250, 4).repeat(6, axis=0)
    out = smooth_wrapped(modulus, 256, 5.0)
    assert out.min() >= 0 and out.max() < 256
    assert np.all((out > 248) | (out < 6))
    assert np.allclose(smooth_wrapped(np.full((4, 4), 100), 256, 0.7), 100)
