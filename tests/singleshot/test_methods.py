"""Tests for the method registry of torch_modulo.singleshot.methods."""

from __future__ import annotations

import numpy as np
import pytest

from torch_modulo.singleshot import METHODS
from torch_modulo.singleshot.energy import EnergyParams
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
        spec = make_spec(8, "fast", 4, 0.1, 1e-5, None, 2, 10, {"window": np.int64(16)})
        assert isinstance(spec, SolverSpec) and spec.neighborhood == 4 and spec.max_iter == 10
        assert spec.option("window") == 16 and type(spec.option("window")) is int
        assert spec.option("init") == REGISTRY["fast"].options["init"].default

    @pytest.mark.parametrize(
        ("method", "options", "error", "text"),
        [
            ("paper", {"tile": 8}, TypeError, "it takes: none"),
            ("fast", {"window": True}, TypeError, "True"),
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


class TestRenamedOptions:
    """Options that were renamed keep working under their old name, with a warning."""

    def test_fast_tile_is_window(self) -> None:
        with pytest.warns(DeprecationWarning, match="option 'tile' of method 'fast' is deprecated; use 'window'"):
            spec = make_spec(8, "fast", 8, 0.1, 1e-5, None, 2, 10, {"tile": 16})
        assert spec.options == (("window", 16),)

    def test_both_names_refused(self) -> None:
        with pytest.warns(DeprecationWarning), pytest.raises(TypeError, match="both 'tile' and its new name 'window'"):
            make_spec(8, "fast", 8, 0.1, 1e-5, None, 2, 10, {"tile": 16, "window": 8})

    def test_old_solver_name(self) -> None:
        from torch_modulo.singleshot import graphcut

        start = np.add.outer(np.arange(12), np.arange(12)) * 30
        with pytest.warns(DeprecationWarning, match="solve_tiles is deprecated"):
            old = graphcut.solve_tiles
        p = EnergyParams.make(8)
        offsets = ((0, 1), (1, 0))
        assert np.array_equal(old(start, p, offsets, tile=4), graphcut.solve_windows(start, p, offsets, window=4))


class TestEnergyReportedOnce:
    """The registry's solve step records the energy of a solver that makes no moves, once."""

    @pytest.mark.parametrize("method", ["guided", "learned", "lsq"])
    def test_one_energy_of_the_result(self, method: str) -> None:
        from torch_modulo.singleshot.graphcut import plane_energy
        from torch_modulo.singleshot.grid import pair_offsets
        from torch_modulo.singleshot.methods import solve_group

        ramp = np.add.outer(np.arange(16), np.arange(20)) * 25
        spec = make_spec(8, method, 8, 0.1, 1e-5, None, 2, 10, {})
        ((restored, info),) = solve_group(ramp[None] % 256, spec)
        assert np.array_equal(restored, ramp)
        assert info["energies"] == [plane_energy(restored, spec.params, pair_offsets(8))] == [info["energy"]]
