"""Protocol D: do the sensor-design predictions agree with simulation?

For each case (bits, noise preset, stops), the modulo plan ``plan_exposures(stops, bits, noise=noise, longest=1.0)``
(for the decoder with spatial evidence, the default; ``--no-spatial``: for each pixel decoded alone) and the
conventional plan ``plan_conventional(stops, bits, noise)`` (the fewest frames whose predicted median error meets the
modulo plan's) are each predicted (:func:`torch_modulo.design.predict_modulo`,
:func:`~torch_modulo.design.predict_conventional`) and simulated: a log-uniform ramp of 200,000 radiances over the
stops (the darkest reads one count at the longest exposure, 1.0), captured by the library's own sensors
(``SimulatedModuloSensor``, ``SimulatedIntensitySensor``; for the spatial decoder as 64 rows whose columns each hold
one radiance) and decoded by its own decoders (``unwrap_multi(..., noise=)``, ``merge_intensity(..., noise=)``). A
prediction agrees when its median relative error is within 25% of the simulated one, or within 0.002 absolute.
Prints a table and a JSON summary; exits 1 if any prediction disagrees.

    python benchmarks/bench_design.py                    # the three cases of issue #34
    python benchmarks/bench_design.py --case 12 q16 20   # another case (repeatable)
    python benchmarks/bench_design.py --longest-frames 2 # the modulo plans with their longest exposure twice
    python benchmarks/bench_design.py --no-spatial       # the plans and decoder for each pixel alone
"""

from __future__ import annotations

import argparse
import json
import sys

from torch_modulo import design

CASES = ((10, "q16", 20.0), (8, "photon-counting", 16.0), (8, "dfpa", 24.0))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--case", nargs=3, action="append", metavar=("BITS", "NOISE", "STOPS"), help="bits noise stops")
    parser.add_argument("--values", type=int, default=200_000, help="radiances in the simulated ramp")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--longest-frames", type=int, default=1, help="frames at the modulo plan's longest exposure")
    parser.add_argument(
        "--spatial",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the modulo plan and decoder with spatial evidence (the default), or for each pixel alone",
    )
    args = parser.parse_args(argv)
    cases = [(int(b), n, float(s)) for b, n, s in args.case] if args.case else list(CASES)
    rows = []
    print(f"{'case':<28} {'sensor':<13} {'frames':>6} {'predicted':>10} {'simulated':>10} {'agrees':>7}")
    for bits, noise, stops in cases:
        answer = design.design(bits, noise, stops, longest_frames=args.longest_frames, spatial=args.spatial)
        for prediction in (answer.modulo, answer.conventional):
            simulated = design.simulate_median(prediction, bits, noise, values=args.values, seed=args.seed)
            agrees = design.agrees(prediction.median_error, simulated)
            label = f"{bits} bits, {noise}, {stops:g} stops"
            print(
                f"{label:<28} {prediction.sensor:<13} {prediction.frames:>6} {prediction.median_error:>10.5f} "
                f"{simulated:>10.5f} {'yes' if agrees else 'NO':>7}"
            )
            rows.append(
                {
                    "bits": bits,
                    "noise": noise,
                    "stops": stops,
                    "sensor": prediction.sensor,
                    "spatial": prediction.spatial,
                    "frames": prediction.frames,
                    "predicted_median": prediction.median_error,
                    "simulated_median": simulated,
                    "agrees": agrees,
                }
            )
    print(json.dumps({"protocol": "D", "rows": rows}))
    return 0 if all(r["agrees"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
