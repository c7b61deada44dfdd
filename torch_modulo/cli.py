"""The ``torch-modulo`` command line.

    torch-modulo demo [--out DIR] [--scene FILE]    simulate, unwrap, tone-map and write files for one scene

Run ``torch-modulo COMMAND --help`` for every option with an example.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

__all__ = ["build_parser", "main"]


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number; got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a number >= 1; got {value}")
    return value


def _ratio(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number; got {text!r}") from None
    if not 1.0 < value:
        raise argparse.ArgumentTypeError(f"expected a ratio > 1; got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="torch-modulo",
        description="Unbounded HDR photography with a modulo camera (Zhao et al., ICCP 2015).",
    )
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    demo = commands.add_parser(
        "demo",
        help="run the whole pipeline on one scene and write the results",
        description=(
            "Simulate 8-bit modulo and intensity captures of an HDR scene (default: the embedded CC0 scene), "
            "unwrap them from one shot (graph cuts) and from three shots (rollover counting), tone-map, and write "
            "EXRs, PNGs, comparison.png and summary.json."
        ),
        epilog="example: torch-modulo demo --out demo_out",
    )
    demo.add_argument("--out", default="demo_out", help="output folder (default: %(default)s)")
    demo.add_argument("--scene", default=None, help="an EXR or HDR radiance file (default: the embedded scene)")
    demo.add_argument("--bits", type=_positive_int, default=8, help="sensor bit depth (default: %(default)s)")
    demo.add_argument(
        "--ratio", type=_ratio, default=64.0, help="multi-shot neighbouring exposure ratio (default: %(default)s)"
    )
    demo.add_argument(
        "--workers", type=_positive_int, default=None, help="processes for the graph cuts (default: one per core)"
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``torch-modulo``; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "demo":
        from torch_modulo.demo import run_demo

        try:
            run_demo(args.out, args.scene, bits=args.bits, ratio=args.ratio, workers=args.workers)
        except (OSError, ValueError, TypeError) as error:
            print(f"torch-modulo demo: error: {error}", file=sys.stderr)
            return 1
        return 0
    parser.error(f"unknown command {args.command!r}")
    return 2


if __name__ == "__main__":
    sys.exit(main())
