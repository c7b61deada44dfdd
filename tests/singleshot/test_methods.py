"""Tests for the method registry of torch_modulo.singleshot.methods."""

from __future__ import annotations

import numpy as np
import pytest

from torch_modulo.singleshot import METHODS
from torch_modulo.singleshot.methods import REGISTRY, SolverSpec, fast_start, make_spec, solve_plane


class TestRegistry:
    def test_methods_registry(self) -> None:
        assert {"paper", "fast", "guided"} <= set(METHODS)

    def test_methods_is_derived_from_the_registry(self) -> None:
        assert METHODS == tuple(REGISTRY) and METHODS[0] == "learned"
        # The channels of an image are solved together where the method shares information across them.
        assert [name for name in METHODS if REGISTRY[name].joint_channels] == ["learned", "guided"]

    @pytest.mark.parametrize("method", METHODS)
    def test_option_defaults_pass_their_own_checks(self, method: str) -> None:
        for name, option in REGISTRY[method].options.items():
            assert option.check(option.default, name) == option.default

    def test_spec_reads_defaults_from_the_registry(self) -> None:
        spec = make_spec(8, "fast", 4, 0.1, 1e-5, None, 2, 10, {"tile": np.int64(16)})
        assert isinstance(spec, SolverSpec) and spec.neighborhood == 4 and spec.max_iter == 10
        assert spec.option("tile") == 16 and type(spec.option("tile")) is int
        assert spec.option("init") == REGISTRY["fast"].options["init"].default

    @pytest.mark.parametrize(
        ("method", "options", "error", "text"),
        [
            ("paper", {"tile": 8}, TypeError, "it takes: none"),
            ("fast", {"tile": True}, TypeError, "True"),
            ("fast", {"init": ["auto"]}, ValueError, r"\['auto'\]"),
            ("guided", {"colour": "no"}, TypeError, "'no'"),
            ("guided", {"denoise": float("inf")}, ValueError, "inf"),
        ],
    )
    def test_option_errors_name_the_value(self, method: str, options: dict, error: type, text: str) -> None:
        with pytest.raises(error, match=text):
            make_spec(8, method, 8, 0.1, 1e-5, None, 2, 10, options)


def test_fast_start() -> None:
    ramp = np.arange(0, 1200, 40).reshape(1, -1).repeat(3, axis=0)
    assert np.array_equal(fast_start(ramp % 256, 8), ramp)  # no residues: path following
    assert np.array_equal(fast_start(ramp % 256, 8, "zeros"), ramp % 256)


def test_solve_plane_anchors_and_reports() -> None:
    ramp = np.arange(0, 1200, 40).reshape(1, -1).repeat(3, axis=0) + 512
    restored, info = solve_plane(ramp % 256, make_spec(8, "paper", 8, 0.1, 1e-5, None, 2, 1000, {}))
    assert np.array_equal(restored, ramp - 512)
    assert set(info) == {"energies", "steps", "cuts", "energy", "seconds"}
