"""Tests for large images in bounded memory: torch_modulo.singleshot.tiles (overlapping tiles, ``"fast"``) and the
block-built spanning tree of ``"guided"`` (torch_modulo.singleshot.pathfollow), both steered by ``tile_pixels``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import torch_modulo.singleshot.pathfollow as pathfollow
import torch_modulo.singleshot.tiles as tiles
from torch_modulo.singleshot import unwrap_single
from torch_modulo.singleshot.graphcut import MoveStats
from torch_modulo.singleshot.grid import integrate_wrapped, pair_indices, spanning_tree
from torch_modulo.singleshot.methods import REGISTRY, make_spec
from torch_modulo.singleshot.tiles import (
    MIN_TILE_PIXELS,
    TILE_OVERLAP,
    TILE_PIXELS,
    check_tile_pixels,
    solve_tiled,
    stitch_offsets,
    tile_grid,
)

SMALL = MIN_TILE_PIXELS  # the smallest tiles: 128 x 128 pixels, overlap included


def smooth_counts(h: int, w: int, channels: int = 1, seed: int = 0) -> torch.Tensor:
    """(C, H, W) float64 counts of a smooth scene (a ramp and Gaussian bumps, steepest pair below half a period)
    that rolls an 8-bit counter over many times; every channel has pixels at k = 0."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    planes = []
    for _ in range(channels):
        img = 5 + rng.uniform(8, 14) * x + rng.uniform(8, 14) * y
        for _ in range(3):
            cy, cx, s = rng.uniform(0, h), rng.uniform(0, w), rng.uniform(0.15, 0.3) * max(h, w)
            img += rng.uniform(-1, 1) * 20 * s * np.exp(-((y - cy) ** 2 + (x - cx) ** 2) / (2 * s * s))
        planes.append(np.floor(img - img.min() + 5))
    return torch.from_numpy(np.stack(planes))


def tile_tree_weight(parent: np.ndarray, right: np.ndarray, down: np.ndarray) -> float:
    """The total weight of the tree ``parent`` on the grid whose pair weights are ``right`` and ``down``."""
    h, w = down.shape[0] + 1, right.shape[1] + 1
    child = np.flatnonzero(parent != np.arange(h * w))
    a, b = np.minimum(child, parent[child]), np.maximum(child, parent[child])
    horizontal = (b - a == 1) & (w > 1)  # with one column, pairs one apart are vertical
    total = right.ravel()[(a[horizontal] // w) * (w - 1) + a[horizontal] % w].sum()
    return float(total + down.ravel()[a[~horizontal]].sum())


class TestTileGrid:
    @pytest.mark.parametrize(
        ("h", "w", "pixels"), [(300, 500, SMALL), (1000, 1000, 1 << 18), (6000, 6000, TILE_PIXELS), (1, 10**5, SMALL)]
    )
    def test_cores_partition_and_tiles_fit(self, h: int, w: int, pixels: int) -> None:
        grid = tile_grid(h, w, pixels)
        cover = np.zeros((h, w), dtype=np.int64)
        for tile in (t for row in grid for t in row):
            cover[tile.core] += 1
            ey, ex = tile.ext
            assert (ey.stop - ey.start) * (ex.stop - ex.start) <= pixels
            for c, e, n in zip(tile.core, tile.ext, (h, w), strict=True):
                assert (e.start, e.stop) == (max(0, c.start - TILE_OVERLAP), min(n, c.stop + TILE_OVERLAP))
        assert np.all(cover == 1)
        assert len(grid) * len(grid[0]) > 1

    @pytest.mark.parametrize("pixels", [0, 300 * 500, 10**9])
    def test_one_tile_when_the_image_fits(self, pixels: int) -> None:
        assert tile_grid(300, 500, pixels) == [
            [tiles.Tile((slice(0, 300), slice(0, 500)), (slice(0, 300), slice(0, 500)))]
        ]


class TestCheckTilePixels:
    @pytest.mark.parametrize("value", [0, MIN_TILE_PIXELS, TILE_PIXELS, np.int64(1 << 20)])
    def test_accepts(self, value: object) -> None:
        assert check_tile_pixels(value, "tile_pixels") == int(value)

    @pytest.mark.parametrize(
        ("value", "error", "text"),
        [
            (True, TypeError, "True"),
            (1.5e6, TypeError, "1500000.0"),
            ("4M", TypeError, "'4M'"),
            (None, TypeError, "None"),
            (-1, ValueError, "-1"),
            (1, ValueError, "got 1"),
            (MIN_TILE_PIXELS - 1, ValueError, str(MIN_TILE_PIXELS - 1)),
        ],
    )
    @pytest.mark.parametrize("method", ["guided", "fast"])
    def test_refuses_naming_the_value(self, value: object, error: type, text: str, method: str) -> None:
        with pytest.raises(error, match=text):
            unwrap_single(torch.zeros(4, 4), method=method, tile_pixels=value)

    def test_defaults_and_methods_without_tiles(self) -> None:
        for method in ("guided", "fast"):
            assert REGISTRY[method].options["tile_pixels"].default == TILE_PIXELS
        with pytest.raises(TypeError, match="tile_pixels"):
            unwrap_single(torch.zeros(4, 4), method="paper", tile_pixels=SMALL)


class TestStitchOffsets:
    def test_follows_the_best_agreement(self) -> None:
        # (0, 2) claims +5 but agrees on few pixels: the tree goes 0 -> 1 -> 2.
        assert stitch_offsets(3, [(0, 1, 2, 90), (1, 2, -1, 80), (0, 2, 5, 10)]).tolist() == [0, 2, 1]

    def test_unreached_tiles_stay_at_zero(self) -> None:
        assert stitch_offsets(4, [(2, 3, -4, 7)]).tolist() == [0, 0, 0, -4]


class TestFastInTiles:
    def test_tiled_equals_untiled_on_a_smooth_image(self) -> None:
        truth = smooth_counts(300, 260, seed=1)[0]
        untiled = unwrap_single(truth % 256, method="fast", tile_pixels=0)
        tiled = unwrap_single(truth % 256, method="fast", tile_pixels=SMALL)
        assert torch.equal(untiled, truth) and torch.equal(tiled, truth)

    def test_stitches_a_ramp_that_rolls_over_many_times(self) -> None:
        # 44 rollovers across the image, several inside every tile: each tile is right only up to its constant.
        # A dark corner (4% of the pixels) anchors k = 0.
        y, x = torch.meshgrid(torch.arange(400.0), torch.arange(330.0), indexing="ij")
        truth = torch.floor((20 * x + 16 * y - 1500).clamp_min(0) + 3)
        assert truth.max() // 256 >= 44
        assert torch.equal(unwrap_single(truth % 256, method="fast", tile_pixels=SMALL), truth)

    def test_hook_runs_and_reports(self, monkeypatch: pytest.MonkeyPatch) -> None:
        solved: list[tuple[int, ...]] = []
        inner = tiles.solve_tiled

        def spy(solve, moduli, spec, stats, tile_pixels):  # noqa: ANN001, ANN202
            def count(part, spec, stats):  # noqa: ANN001, ANN202
                solved.append(part.shape)
                return solve(part, spec, stats)

            return inner(count, moduli, spec, stats, tile_pixels)

        monkeypatch.setattr(tiles, "solve_tiled", spy)
        truth = smooth_counts(200, 180, channels=2, seed=2)
        out, info = unwrap_single(truth % 256, method="fast", tile_pixels=SMALL, return_info=True)
        assert torch.equal(out, truth)
        grid = tile_grid(200, 180, SMALL)
        assert len(solved) == 2 * len(grid) * len(grid[0]) and all(s[1] * s[2] <= SMALL for s in solved)
        assert all(len(e) == 1 for row in info.energies for e in row)
        assert bool((info.cuts >= len(solved) // 2).all())
        solved.clear()
        unwrap_single(truth[:, :100, :100] % 256, method="fast", tile_pixels=SMALL)  # fits: one solve per plane
        assert solved == [(1, 100, 100), (1, 100, 100)]

    def test_solve_tiled_without_tiles_is_the_solver(self) -> None:
        truth = smooth_counts(40, 50, seed=3).numpy().astype(np.int64)
        spec = make_spec(8, "guided", 8, 0.1, 1e-5, None, 2, 10, {})
        direct = REGISTRY["guided"].solve(truth % 256, spec, [MoveStats()])
        assert np.array_equal(solve_tiled(REGISTRY["guided"].solve, truth % 256, spec, [MoveStats()], 0), direct)


class TestGuidedInBlocks:
    @pytest.mark.parametrize("channels", [1, 3])
    @pytest.mark.parametrize("options", [{}, {"colour": False}, {"denoise": 0.7}])
    def test_blocks_equal_the_whole_image_on_smooth_images(self, channels: int, options: dict) -> None:
        truth = smooth_counts(260, 240, channels=channels, seed=channels)
        whole = unwrap_single(truth % 256, method="guided", tile_pixels=0, **options)
        blocks = unwrap_single(truth % 256, method="guided", tile_pixels=SMALL, **options)
        assert torch.equal(blocks, whole)
        if not options:
            assert torch.equal(blocks, truth)

    def test_blocks_equal_the_whole_image_on_a_textured_image(self) -> None:
        # Noise with steps beyond half a period: many residues, so the tree decides the result.
        rng = np.random.default_rng(7)
        truth = torch.from_numpy(
            np.floor(smooth_counts(200, 190, channels=3).numpy() + rng.normal(0, 60, (3, 200, 190)))
        )
        truth = truth - truth.min()
        modulus = truth % 256
        guided = {"method": "guided"}
        assert torch.equal(
            unwrap_single(modulus, tile_pixels=SMALL, **guided), unwrap_single(modulus, tile_pixels=0, **guided)
        )

    def test_hook_runs_for_a_small_threshold(self, monkeypatch: pytest.MonkeyPatch) -> None:
        calls: list[int] = []
        inner = pathfollow._forest_graph

        def spy(pair_weights, h: int, w: int, tile_pixels: int):  # noqa: ANN001, ANN202
            calls.append(tile_pixels)
            return inner(pair_weights, h, w, tile_pixels)

        monkeypatch.setattr(pathfollow, "_forest_graph", spy)
        truth = smooth_counts(150, 140, seed=4)[0]
        assert torch.equal(unwrap_single(truth % 256, method="guided", tile_pixels=SMALL), truth)
        assert calls == [SMALL]
        unwrap_single(truth % 256, method="guided")  # below the default threshold: the whole image at once
        assert calls == [SMALL]

    @pytest.mark.parametrize(("h", "w"), [(90, 400), (400, 60), (1, 3000), (3000, 1), (200, 200)])
    def test_forest_graph_holds_a_minimum_spanning_tree(self, h: int, w: int) -> None:
        # Integer difficulties: many pairs of equal weight, so the block trees differ from the whole tree where
        # they tie; the total weight must not.
        difficulty = np.random.default_rng(h * w).integers(0, 4, (h, w)).astype(np.float64)
        right, down = pathfollow._pair_weights(difficulty)
        whole = pathfollow._tree_parents(pathfollow._pair_graph(right, down))
        weights = lambda r0, r1: pathfollow._pair_weights(difficulty[r0:r1])  # noqa: E731
        blocks = pathfollow._tree_parents(pathfollow._forest_graph(weights, h, w, 4096))
        assert blocks.dtype == np.int32
        assert np.count_nonzero(blocks != np.arange(h * w)) == h * w - 1  # one tree, rooted at pixel 0
        assert tile_tree_weight(blocks, right, down) == pytest.approx(tile_tree_weight(whole, right, down), rel=1e-12)


class TestPathFollowingMemory:
    """The memory-lean pieces of path following give the same values as the general grid helpers."""

    @pytest.mark.parametrize(("h", "w"), [(1, 7), (7, 1), (2, 2), (37, 53)])
    def test_pair_graph_is_scipys_graph_of_the_pair_lists(self, h: int, w: int) -> None:
        from scipy.sparse import coo_matrix

        difficulty = np.random.default_rng(h + w).uniform(0, 50, (h, w))
        right, down = pathfollow._pair_weights(difficulty)
        ours = pathfollow._pair_graph(right, down)
        (i0, j0), (i1, j1) = pair_indices(h, w, (0, 1)), pair_indices(h, w, (1, 0))
        rows, cols = np.concatenate([i0, i1]), np.concatenate([j0, j1])
        theirs = coo_matrix((np.concatenate([right.ravel(), down.ravel()]), (rows, cols)), shape=(h * w,) * 2).tocsr()
        for name in ("indptr", "indices", "data"):
            assert np.array_equal(getattr(ours, name), getattr(theirs, name))
        parent = pathfollow._tree_parents(ours)
        assert np.array_equal(parent, spanning_tree(h * w, rows, cols, np.concatenate([right.ravel(), down.ravel()])))

    def test_integrate_and_difficulty_match_the_plain_versions(self, monkeypatch: pytest.MonkeyPatch) -> None:
        monkeypatch.setattr(pathfollow, "_CHUNK", 64)  # many chunks
        rng = np.random.default_rng(5)
        planes = [rng.integers(0, 256, (23, 31)) for _ in range(3)]
        expected = sum(pathfollow._second_difference_quality(m, 256) for m in planes)
        assert np.array_equal(pathfollow._difficulty(planes, 256), expected)
        parent = pathfollow._reliability_tree(expected)
        for m in planes + [pathfollow.smooth_wrapped(planes[0], 256, 0.7)]:
            assert np.array_equal(pathfollow._integrate(m, parent, 256), integrate_wrapped(m, parent, 256))
