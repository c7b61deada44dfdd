"""Every Python example of the README runs as written (each in a fresh namespace, in the project folder)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)


def test_readme_has_examples() -> None:
    assert len(BLOCKS) >= 4, "README.md lost its python examples"


@pytest.mark.parametrize(
    "block",
    [
        pytest.param(b, id=f"block{i}", marks=[pytest.mark.slow] if "torch.compile" in b else [])
        for i, b in enumerate(BLOCKS)
    ],
)
def test_readme_example_runs(block: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # examples that write files write them here
    assert os.getcwd() == str(tmp_path)
    exec(compile(block, str(README), "exec"), {"__name__": "readme_example"})  # noqa: S102 - our own README
