"""Tests for the pixel-grid helpers: torch_modulo.singleshot.grid."""

from __future__ import annotations

import numpy as np
import pytest

from torch_modulo.singleshot.grid import (
    components,
    dilate,
    grid_components,
    integrate_wrapped,
    pair_indices,
    pair_offsets,
    pair_slices,
    path_to_root,
    spanning_tree,
    wrapped_difference,
)


def test_pair_offsets() -> None:
    assert pair_offsets(4) == ((0, 1), (1, 0))
    assert set(pair_offsets(8)) == {(0, 1), (1, 0), (1, 1), (1, -1)}
    with pytest.raises(ValueError, match="True"):
        pair_offsets(True)  # type: ignore[arg-type]


@pytest.mark.parametrize("offset", [(0, 1), (1, 0), (1, 1), (1, -1)])
def test_pair_indices_follow_pair_slices(offset: tuple[int, int]) -> None:
    image = np.arange(5 * 7).reshape(5, 7) * 10
    first, second = pair_slices(5, 7, offset)
    i, j = pair_indices(5, 7, offset)
    assert np.array_equal(image.ravel()[i], image[first].ravel())
    assert np.array_equal(image.ravel()[j], image[second].ravel())


@pytest.mark.parametrize("value", [6, [8], "8", None, 8.5])
def test_pair_offsets_names_a_bad_neighborhood(value: object) -> None:
    # Regression: a list used to raise "unhashable type: 'list'" instead of naming the value.
    with pytest.raises(ValueError, match="neighborhood must be one of 4, 8; got"):
        pair_offsets(value)  # type: ignore[arg-type]


def test_wrapped_difference() -> None:
    d = np.array([-300, -128, -1, 0, 127, 128, 255])
    assert wrapped_difference(d, 256).tolist() == [-44, -128, -1, 0, 127, -128, -1]


def test_dilate_grows_by_one_neighbourhood_step() -> None:
    mask = np.zeros((5, 5), dtype=bool)
    mask[2, 2] = True
    assert dilate(mask, pair_offsets(4)).sum() == 5
    assert dilate(mask, pair_offsets(8)).sum() == 9
    assert mask.sum() == 1  # the input is not modified


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (6, 1), (9, 13)])
@pytest.mark.parametrize("share", [0.0, 0.5, 0.8, 1.0])
def test_grid_components_are_the_components_of_the_pairs(shape: tuple[int, int], share: float) -> None:
    rng = np.random.default_rng(sum(shape) + int(10 * share))
    h, w = shape
    right, down = rng.random((h, w - 1)) < share, rng.random((h - 1, w)) < share
    ids = np.arange(h * w).reshape(h, w)
    first = np.concatenate([ids[:, :-1][right], ids[:-1, :][down]])
    second = np.concatenate([ids[:, 1:][right], ids[1:, :][down]])
    count, labels = grid_components(right, down)
    assert (count, labels.tolist()) == tuple(
        x if i == 0 else x.tolist() for i, x in enumerate(components(h * w, first, second))
    )


def test_grid_components_of_empty_and_bad_grids() -> None:
    count, labels = grid_components(np.zeros((0, 4), bool), np.zeros((0, 5), bool))  # 0 x 5
    assert count == 0 and labels.shape == (0,)
    count, labels = grid_components(np.zeros((3, 0), bool), np.zeros((2, 0), bool))  # 3 x 0
    assert count == 0 and labels.shape == (0,)
    with pytest.raises(ValueError, match=r"right \(3, 1\) and down \(2, 5\)"):
        grid_components(np.ones((3, 1), bool), np.ones((2, 5), bool))
    with pytest.raises(ValueError, match=r"right \(3,\) and down \(3,\)"):  # not a grid's pairs at all
        grid_components(np.ones(3, bool), np.ones(3, bool))


def test_components_of_two_chains() -> None:
    count, labels = components(5, np.array([0, 1, 3]), np.array([1, 2, 4]))
    assert count == 2 and labels[0] == labels[1] == labels[2] != labels[3] == labels[4]


def test_spanning_tree_path_sums_and_integration() -> None:
    # A 1 x 4 chain: the tree is the chain, and the path sums integrate the wrapped steps into k.
    i, j = pair_indices(1, 4, (0, 1))
    parent = spanning_tree(4, i, j, np.ones(3))
    assert parent.tolist() == [0, 0, 1, 2]
    assert path_to_root(parent, np.array([0, 1, 1, 1])).tolist() == [0, 1, 2, 3]
    assert path_to_root(parent, np.array([0, 5, 1, 3]), np.maximum).tolist() == [0, 5, 5, 5]
    truth = np.array([[100, 200, 300, 400]])  # steps below half a period: integration recovers k = I // 256
    assert integrate_wrapped(truth % 256, parent, 256).tolist() == (truth // 256).tolist()
