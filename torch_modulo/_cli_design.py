"""``torch-modulo design``: how many frames a modulo sensor needs for a scene, the error they give, and the
conventional sensor's plan for the same error (:func:`torch_modulo.design.design`)."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from torch_modulo._argtypes import positive_int
from torch_modulo._cli_options import bit_depth, noise, positive_float

__all__ = ["add_design", "run_design"]

_DESCRIPTION = (
    "Plan the exposures of a modulo sensor for a scene of --stops stops (plan_exposures under the noise model), "
    "predict the median relative error of its noise-aware decoding, and find the conventional (clipping) sensor with "
    "the same bits and noise that reaches the same predicted median error: its exposures and frames. A scene of S "
    "stops spans E_min to 2**S E_min, where E_min reads one count at the longest exposure (1.0). The predictions are "
    "models of the library's decoders on a log-uniform ramp of radiances (benchmarks/bench_design.py checks them "
    "against simulation): by default the modulo decoder with spatial evidence on a smooth scene; --no-spatial plans "
    "and predicts for each pixel decoded alone (2 to 3 times the frames; what a finely textured scene needs)."
)


def add_design(commands: Any) -> None:
    """The ``design`` subcommand's parser."""
    design = commands.add_parser(
        "design",
        help="frames and predicted error of a modulo sensor against a conventional one",
        description=_DESCRIPTION,
        epilog="example: torch-modulo design --bits 10 --noise q16 --stops 20 --plot design.png",
    )
    design.add_argument("--bits", type=bit_depth, required=True, help="both sensors' bit depth, 1 to 24")
    design.add_argument(
        "--noise",
        type=noise,
        required=True,
        metavar="MODEL",
        help="both sensors' noise: a preset (photon-counting, q16, dfpa) or KEY=VALUE pairs as in simulate --noise",
    )
    design.add_argument("--stops", type=positive_float, required=True, help="the scene's dynamic range in stops")
    design.add_argument(
        "--frames", type=positive_int, default=None, help="a budget: the best modulo plan of at most this many frames"
    )
    design.add_argument(
        "--longest-frames",
        type=positive_int,
        default=1,
        metavar="L",
        help="take the modulo plan's longest exposure L times (under noise the repeats collect light; --frames "
        "counts them; default: 1)",
    )
    design.add_argument(
        "--spatial",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="plan and predict for the modulo decoder with spatial evidence (the default), or for each pixel "
        "decoded alone (--no-spatial)",
    )
    design.add_argument("--json", action="store_true", help="print one JSON object instead of the text report")
    design.add_argument(
        "--plot",
        default=None,
        metavar="FILE",
        help="write predicted relative error against radiance (needs matplotlib)",
    )


def run_design(args: argparse.Namespace) -> int:
    """Run ``design``: print the answer (text or JSON) and write the plot; 1 with a message on a bad value."""
    from torch_modulo.design import design, plot
    from torch_modulo.noise import NoiseModel

    if args.noise == "none":
        print("torch-modulo design: error: --noise none has no noise to design for; give a model", file=sys.stderr)
        return 2
    try:
        answer = design(
            args.bits,
            NoiseModel(**args.noise),
            args.stops,
            frames=args.frames,
            longest_frames=args.longest_frames,
            spatial=args.spatial,
        )
        if args.plot:
            plot(answer, args.plot)
    except (ValueError, TypeError, ImportError, OSError) as error:
        print(f"torch-modulo design: error: {error}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(answer.to_dict()))
        return 0
    print(_report(answer.to_dict()))
    if args.plot:
        print(f"plot: {args.plot}")
    return 0


def _report(d: dict[str, Any]) -> str:
    def plan(taus: list[float]) -> str:
        shown = ", ".join(f"{t:.4g}" for t in taus[:12])
        return shown + (f", ... ({len(taus) - 12} more)" if len(taus) > 12 else "")

    reach = "the same" if d["conventional_reaches"] else "no such (256 frames shown)"
    return "\n".join(
        [
            f"{d['bits']}-bit sensors, {d['noise']}, {d['stops']:g} stops",
            f"modulo:       {d['frames']} frames ({'spatial evidence' if d['spatial'] else 'each pixel alone'}), "
            f"predicted median relative error {d['modulo_median_error']:.3g}, "
            f"more than 50% off {100 * d['modulo_gross_share']:.3g}%",
            f"  exposures   {plan(d['exposures'])}",
            f"conventional: {d['conventional_frames']} frames for {reach} median error: "
            f"{d['conventional_median_error']:.3g}, more than 50% off {100 * d['conventional_gross_share']:.3g}%",
            f"  exposures   {plan(d['conventional_exposures'])}",
        ]
    )
