"""The package's size rules, checked so they stay true: no module over 700 lines, at most 3 functions over 80
lines of code (after the docstring, blank and comment lines not counted) and none over 120.

The import rules (layers, no cycles between sibling modules) are checked by ``lint-imports`` in CI (.ci/run), from
the contracts in pyproject.toml.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "torch_modulo"


def code_lines(node: ast.FunctionDef | ast.AsyncFunctionDef, lines: list[str]) -> int:
    """Lines of code of a function's body after its docstring, not counting blank and comment lines."""
    body = node.body
    if (
        isinstance(body[0], ast.Expr)
        and isinstance(body[0].value, ast.Constant)
        and isinstance(body[0].value.value, str)
    ):
        body = body[1:]
    if not body:
        return 0
    end = node.end_lineno or body[-1].lineno
    return sum(1 for line in lines[body[0].lineno - 1 : end] if line.strip() and not line.strip().startswith("#"))


def function_sizes() -> dict[str, int]:
    sizes = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        lines = path.read_text().splitlines()
        for node in ast.walk(ast.parse("\n".join(lines))):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                sizes[f"{path.relative_to(PACKAGE)}:{node.lineno} {node.name}"] = code_lines(node, lines)
    return sizes


def test_code_lines_count_what_they_say() -> None:
    source = 'def f():\n    """Doc."""\n    # a comment\n\n    x = 1\n    return x\n'
    (node,) = ast.parse(source).body
    assert isinstance(node, ast.FunctionDef) and code_lines(node, source.splitlines()) == 2


def test_no_module_over_700_lines() -> None:
    long = {
        str(p.relative_to(PACKAGE)): n for p in PACKAGE.rglob("*.py") if (n := len(p.read_text().splitlines())) > 700
    }
    assert not long


def test_functions_are_short() -> None:
    sizes = function_sizes()
    assert len(sizes) > 500  # the whole package was read
    over_80 = {name: n for name, n in sizes.items() if n > 80}
    assert len(over_80) <= 3, over_80
    assert not {name: n for name, n in over_80.items() if n > 120}
