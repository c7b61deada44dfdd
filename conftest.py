"""Shared fixtures: device and dtype (cpu/float32 by default), the shared data folder, and the slow marker.

Choose others with ``pytest --device cuda --dtype float64``; ``--device all`` runs on cpu and cuda when present.
Tests marked ``slow`` run only with ``--runslow`` (CI skips them).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

SHARED_HDR = Path(__file__).resolve().parent.parent / "shared" / "data" / "hdr"

# ``python -m torch_modulo`` runs the command line: keep the doctest collector from importing it.
collect_ignore = ["torch_modulo/__main__.py"]


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--device", default="cpu", help="cpu, cuda or all")
    parser.addoption("--dtype", default="float32", help="float32, float64 or all")
    parser.addoption("--runslow", action="store_true", default=False, help="run tests marked slow")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


def _devices(config: pytest.Config) -> list[str]:
    name = config.getoption("--device")
    if name == "all":
        return ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    return [name]


def _dtypes(config: pytest.Config) -> list[torch.dtype]:
    name = config.getoption("--dtype")
    names = ["float32", "float64"] if name == "all" else [name]
    return [getattr(torch, n) for n in names]


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    if "device" in metafunc.fixturenames:
        metafunc.parametrize("device", [torch.device(d) for d in _devices(metafunc.config)], ids=str)
    if "dtype" in metafunc.fixturenames:
        metafunc.parametrize("dtype", _dtypes(metafunc.config), ids=str)


@pytest.fixture
def shared_hdr() -> Path:
    """The folder of real HDR scenes beside the project; skips the test when it is absent."""
    if not SHARED_HDR.is_dir():
        pytest.skip(f"shared HDR scenes not found at {SHARED_HDR}")
    return SHARED_HDR
