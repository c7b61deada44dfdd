"""Tests for anchoring the free constant of k: torch_modulo.singleshot.anchor."""

from __future__ import annotations

import numpy as np
import pytest

from torch_modulo.singleshot.anchor import anchor_k


class TestAnchor:
    def test_darkest_large_region_is_zero(self) -> None:
        k = np.full((40, 40), 3)
        k[:20] = 5
        k[0, 0] = 1  # a lone noisy pixel two levels below: it must not anchor the image
        out = anchor_k(k, min_fraction=0.01)
        assert out[30, 30] == 0 and out[10, 10] == 2 and out[0, 0] == 0
        assert out.min() == 0

    def test_small_images_anchor_on_minimum(self) -> None:
        assert anchor_k(np.array([[2, 3], [4, 2]])).tolist() == [[0, 1], [2, 0]]

    def test_empty(self) -> None:
        assert anchor_k(np.zeros((0, 3), dtype=np.int64)).shape == (0, 3)

    @staticmethod
    def _scene(patch_counts: float) -> tuple[np.ndarray, np.ndarray]:
        """A 50 x 50 ramp at 780-829 counts (k = 3) with a 6 x 6 patch (1.4% of the pixels) at ``patch_counts``."""
        _, x = np.mgrid[0:50, 0:50]
        counts = (780 + x).astype(np.int64)
        counts[5:11, 5:11] = patch_counts + x[5:11, 5:11]
        return counts // 256, counts % 256

    def test_small_region_with_steep_border_does_not_anchor(self) -> None:
        # A 1.4% patch 3 levels below the rest, with steep borders all round: what a solver that put a bright
        # region too low leaves behind. With the modulus the border test rejects it; the 0.1% rule alone takes it.
        k, modulus = self._scene(200)
        assert k[7, 7] == 0 and k[30, 30] == 3
        out = anchor_k(k, modulus=modulus, bits=8)
        assert out[30, 30] == 0 and out[7, 7] == 0  # the bulk at k = 0, the patch clipped to 0
        assert anchor_k(k)[30, 30] == 3

    def test_small_region_with_smooth_border_anchors(self) -> None:
        # The same patch, but its border steps stay under half a period: a true dark region, it anchors.
        k, modulus = self._scene(700)
        assert k[7, 7] == 2 and k[30, 30] == 3
        assert anchor_k(k, modulus=modulus, bits=8)[30, 30] == 1
        assert anchor_k(k, modulus=modulus, bits=8, large_fraction=0.01)[30, 30] == 1

    def test_large_region_anchors_whatever_its_border(self) -> None:
        k, modulus = self._scene(200)
        assert anchor_k(k, modulus=modulus, bits=8, large_fraction=0.01)[30, 30] == 3

    def test_falls_back_to_the_lowest_level_with_a_region(self) -> None:
        # Every region is small and steep-bordered (4 x 4 blocks on 5 levels, a 32-pixel region on the top level):
        # no level passes the tests, and the lowest level with a 0.1% region anchors, as without the modulus,
        # rather than the level of the largest region (which would clip most of the image to k = 0).
        y, x = np.mgrid[0:64, 0:64]
        k = ((y // 4) + (x // 4)) % 5
        k[0:4, 0:8] = 4
        modulus = np.full(k.shape, 100)
        out = anchor_k(k, modulus=modulus, bits=8)
        assert np.array_equal(out, anchor_k(k)) and np.array_equal(out, k - k.min())

    def test_modulus_needs_bits(self) -> None:
        with pytest.raises(ValueError, match="bits"):
            anchor_k(np.zeros((3, 3), dtype=np.int64), modulus=np.zeros((3, 3)))

    def test_long_ramp_keeps_its_levels(self) -> None:
        # A 1 x 20000 ramp of 91 counts a pixel crosses ~7100 levels of 2 or 3 pixels each; none holds 0.1% of the
        # image, so the level of the largest region anchors: level 0 (counts 0, 91, 182) is the first with 3 pixels.
        counts = np.arange(20000, dtype=np.int64) * 91
        k = (counts // 256).reshape(1, -1)
        modulus = (counts % 256).reshape(1, -1)
        assert np.array_equal(anchor_k(k + 5), k)
        assert np.array_equal(anchor_k(k - 7, modulus=modulus, bits=8), k)
        assert np.array_equal(anchor_k(k.T + 2), k.T)


def _reference_anchor(
    k: np.ndarray, min_fraction: float, modulus: np.ndarray | None, bits: int | None, large_fraction: float
) -> np.ndarray:
    """The rule of ``anchor_k``'s docstring, one level and one pixel at a time (small maps only)."""
    from scipy import ndimage

    height, width = k.shape
    need = max(1, int(np.ceil(min_fraction * k.size)))
    large = max(need, int(np.ceil(large_fraction * k.size)))
    levels = sorted({int(v) for v in k.ravel()})
    largest_size, largest_level, lowest_with_need = 0, None, None
    for level in levels:
        labels, _ = ndimage.label(k == level)  # 4-connected by default
        sizes = {int(lab): int((labels == lab).sum()) for lab in np.unique(labels[labels > 0])}
        size = max(sizes.values())
        # the largest region; on a tie, the one reached first in raster order
        region = next(int(lab) for lab in labels.ravel() if lab and sizes[int(lab)] == size)
        if size > largest_size:
            largest_size, largest_level = size, level
        if size < need:
            continue
        if lowest_with_need is None:
            lowest_with_need = level
        if modulus is None or size >= large:
            return np.maximum(k - level, 0)
        restored = modulus.astype(np.int64) + k * 2**bits
        smooth = steep = 0
        for y in range(height):
            for x in range(width):
                for ny, nx in ((y, x + 1), (y + 1, x)):
                    if ny < height and nx < width and (labels[y, x] == region) != (labels[ny, nx] == region):
                        if abs(restored[y, x] - restored[ny, nx]) < 2 ** (bits - 1):
                            smooth += 1
                        else:
                            steep += 1
        if smooth > 0.8 * (smooth + steep):
            return np.maximum(k - level, 0)
    return np.maximum(k - (lowest_with_need if lowest_with_need is not None else largest_level), 0)


def test_matches_reference_on_random_maps() -> None:
    rng = np.random.default_rng(0)
    for trial in range(300):
        height, width = int(rng.integers(1, 13)), int(rng.integers(1, 13))
        y, x = np.mgrid[0:height, 0:width]
        bits = int(rng.choice([2, 4, 8]))
        # a smooth scene (so some borders are smooth), its k shifted on random blocks, plus noise or a coarse pattern
        counts = (rng.uniform(0, 2) * x + rng.uniform(0, 2) * y) * 2**bits / 4 + rng.uniform(0, 3) * 2**bits
        counts = counts.astype(np.int64)
        k = counts >> bits
        for _ in range(int(rng.integers(0, 4))):
            y0, x0 = rng.integers(0, height), rng.integers(0, width)
            k[y0 : y0 + rng.integers(1, 6), x0 : x0 + rng.integers(1, 6)] += rng.integers(-3, 4)
        if trial % 3 == 1:
            k += rng.integers(-1, 2, size=k.shape) * (rng.random(k.shape) < 0.2)
        elif trial % 3 == 2:
            k = ((y // 2 + x // 2) % int(rng.integers(2, 4))) - 1  # many equal-sized regions: ties
        modulus = counts % 2**bits if trial % 2 else rng.integers(0, 2**bits, size=k.shape)
        min_fraction = float(rng.choice([1e-3, 0.02, 0.05, 0.2]))
        large_fraction = float(rng.choice([0.03, 0.1, 0.3, 2.0]))
        expected = _reference_anchor(k, min_fraction, None, None, large_fraction)
        assert np.array_equal(anchor_k(k, min_fraction), expected), trial
        expected = _reference_anchor(k, min_fraction, modulus, bits, large_fraction)
        out = anchor_k(k, min_fraction, modulus=modulus, bits=bits, large_fraction=large_fraction)
        assert out.dtype == np.int64 and np.array_equal(out, expected), trial
