"""Option types for argparse, shared by the command line, the benchmarks and the research scripts: a bad value is
a usage error that names it (exit code 2), never a traceback or a silent fallback.

Example:
    >>> import argparse
    >>> parser = argparse.ArgumentParser()
    >>> _ = parser.add_argument("--repeat", type=positive_int, default=1)
    >>> parser.parse_args(["--repeat", "3"]).repeat
    3
"""

from __future__ import annotations

import argparse
from typing import Any

import torch

__all__ = ["device", "nonnegative_int", "parse", "positive_int"]


def parse(text: str, cast: type[int] | type[float], kind: str) -> Any:
    """``cast(text)``, or the usage error ``expected <kind>; got '<text>'``."""
    try:
        return cast(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {kind}; got {text!r}") from None


def positive_int(text: str) -> int:
    """A whole number >= 1."""
    value = parse(text, int, "a whole number")
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a number >= 1; got {value}")
    return value


def nonnegative_int(text: str) -> int:
    """A whole number >= 0."""
    value = parse(text, int, "a whole number")
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0; got {value}")
    return value


def device(text: str) -> torch.device:
    """A torch device this process can use (``cpu``, ``cuda``, ``cuda:1``, ...)."""
    try:
        value = torch.device(text)
    except (RuntimeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected a device such as cpu or cuda; got {text!r}") from None
    if value.type == "cuda" and not torch.cuda.is_available():
        raise argparse.ArgumentTypeError(f"{text!r} asked for, but torch.cuda.is_available() is False")
    return value
