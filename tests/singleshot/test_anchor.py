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
