"""Every Python example of the README runs as written (each in a fresh namespace, in the project folder)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
TEXT = README.read_text()
BLOCKS = re.findall(r"```python\n(.*?)```", TEXT, flags=re.S)


def _sections_with_examples() -> list[str]:
    """The ``## `` heading each python example stands under, in order ("" for the first screen, above them all)."""
    heading, found = "", []
    for line in TEXT.splitlines():
        if line.startswith("## "):
            heading = line[3:]
        elif line.startswith("```python"):
            found.append(heading)
    return found


def test_every_python_block_is_run() -> None:
    # Each fence the README opens is one block the test below runs: none is skipped by an odd fence.
    assert len(BLOCKS) == TEXT.count("```python") == len(_sections_with_examples())
    assert all(block.strip() for block in BLOCKS)


def test_readme_shows_each_subject_with_an_example() -> None:
    sections = _sections_with_examples()
    assert sections[0] == "", "the first screen lost its example"
    subjects = ("Multi-shot", "Single shot", "Colour modulo cameras", "In PyTorch pipelines", "Sensors")
    for subject in subjects:
        assert any(s.startswith(subject) for s in sections), f"no python example under the {subject!r} section"


def test_the_first_screen_example_checks_its_results() -> None:
    first = BLOCKS[0]
    assert "import torch_modulo as tm" in first
    checks = [line for line in first.splitlines() if line.startswith("assert ")]
    assert len(checks) >= 2, "the quick-start example should assert that multi and single shot are exact"


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
