"""The command line's options: the types that parse each option's text, and each folder command's job options.

A type turns an option's text into its value or raises the usage error that names it (exit code 2), never a
traceback or a silent fallback. The job options (JSON-compatible; they decide whether an existing output is
complete) are built from the parsed arguments and checked before anything is written: a bad combination ends with
the subcommand's usage (exit code 2).

Example:
    >>> exposures("1,256,65536"), noise("q16,read=20")["read_noise"]
    ([1.0, 256.0, 65536.0], 20.0)
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from typing import Any

from torch_modulo import pipeline
from torch_modulo._argtypes import parse as _parse
from torch_modulo._scene_rules import undecodable_ratio

__all__ = [
    "JOB_OPTIONS",
    "bit_depth",
    "cfa_pattern",
    "crop_size",
    "exposures",
    "noise",
    "param",
    "positive_float",
    "ratio",
    "scale",
    "simulate_options",
    "tonemap_options",
    "unwrap_options",
]

#: Multi-shot rules of ``unwrap --method`` (without ``--single``).
_MULTI_RULES = ("robust", "paper")
_NOISE_KEYS = {
    "q": "electrons_per_count",
    "electrons_per_count": "electrons_per_count",
    "read": "read_noise",
    "read_noise": "read_noise",
    "dark": "dark_current",
    "dark_current": "dark_current",
    "prnu": "prnu",
    "shot": "shot_noise",
    "shot_noise": "shot_noise",
}


# ------------------------------------------------------------------------------------------ option types


def ratio(text: str) -> float:
    """A ratio of exposures, a number > 1."""
    value = _parse(text, float, "a number")
    if not 1.0 < value:
        raise argparse.ArgumentTypeError(f"expected a ratio > 1; got {value}")
    return value


def bit_depth(text: str) -> int:
    """A sensor bit depth, a whole number from 1 to 24 (one message for every value outside)."""
    value = _parse(text, int, "a bit depth from 1 to 24")
    if not 1 <= value <= 24:
        raise argparse.ArgumentTypeError(f"expected a bit depth from 1 to 24; got {value}")
    return value


def cfa_pattern(text: str) -> str:
    """A colour filter array's name in any case (``rggb`` -> ``"RGGB"``); ``choices`` then checks it."""
    return text.strip().upper()


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = _parse(text, float, "a number")
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0; got {text!r}")
    return value


def exposures(text: str) -> list[float] | str:
    """``"auto"``, or ``"1,256,65536"`` -> [1.0, 256.0, 65536.0]: one or more finite exposures > 0, each once but
    the longest (two frames of one exposure add nothing to rollover counting, so a repeat is most likely a typo and
    is refused; under noise the longest exposure's repeats collect light, as ``plan_exposures(...,
    longest_frames=L)`` plans them)."""
    if text.strip() == "auto":
        return "auto"
    parts = [p.strip() for p in text.split(",")]
    if not text.strip() or any(not p for p in parts):
        raise argparse.ArgumentTypeError(
            f"expected comma-separated exposures such as 1,256,65536, or auto; got {text!r}"
        )
    values = []
    for part in parts:
        try:
            value = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"exposure {part!r} in {text!r} is not a number") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"exposures must be finite and > 0; got {part!r} in {text!r}")
        values.append(value)
    for value in values:
        if values.count(value) > 1 and value != max(values):
            raise argparse.ArgumentTypeError(
                f"exposure {value:g} appears twice in {text!r}: give each exposure once (one frame each), "
                "except the longest, whose repeats collect more light under noise"
            )
    return values


def crop_size(text: str) -> list[int]:
    """``"256"`` -> [256, 256], ``"128,256"`` or ``"128x256"`` -> [128, 256]: a crop's height and width."""
    parts = text.replace("x", ",").split(",")
    try:
        values = [int(p) for p in parts]
    except ValueError:
        values = []
    if len(values) not in (1, 2) or any(v < 1 for v in values):
        raise argparse.ArgumentTypeError(f"expected a crop size H,W or N (pixels, each >= 1); got {text!r}")
    return values * 2 if len(values) == 1 else values


def scale(text: str) -> str | float:
    """``"auto"``, or a radiance multiplier: a finite number > 0."""
    if text == "auto":
        return "auto"
    try:
        return positive_float(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected 'auto' or a number > 0; got {text!r}") from None


def _flag_value(text: str, where: str) -> bool:
    lowered = text.lower()
    if lowered in ("1", "true", "on", "yes"):
        return True
    if lowered in ("0", "false", "off", "no"):
        return False
    raise argparse.ArgumentTypeError(f"{where} must be on or off; got {text!r}")


def noise(text: str) -> dict[str, Any] | str:
    """A ``--noise`` value -> NoiseModel fields (validated), or ``"none"``.

    ``none``; ``default`` (the photon-counting preset); a preset name; or KEY=VALUE pairs (``read=2,prnu=0.01``),
    optionally after a preset name (``q16,read=20``) whose fields they change (else the photon-counting preset's).
    """
    from torch_modulo.noise import PRESETS, NoiseModel

    text = text.strip()
    if text == "none":
        return "none"
    items = [item.strip() for item in text.split(",")]
    base = pipeline.DEFAULT_NOISE if items[0] == "default" else items[0]
    if items[0] == "default" or base in PRESETS:
        items = items[1:]
    else:
        base = pipeline.DEFAULT_NOISE
    fields: dict[str, Any] = dict(PRESETS[base])
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key not in _NOISE_KEYS:
            raise argparse.ArgumentTypeError(
                f"expected none, default, a preset ({', '.join(PRESETS)}) or KEY=VALUE pairs with keys q, read, "
                f"dark, prnu, shot; got {item!r}"
            )
        name = _NOISE_KEYS[key]
        if name == "shot_noise":
            fields[name] = _flag_value(value.strip(), "shot")
        else:
            try:
                fields[name] = float(value)
            except ValueError:
                raise argparse.ArgumentTypeError(f"noise {key}={value!r} is not a number") from None
    try:
        return NoiseModel(**fields).to_dict()
    except (TypeError, ValueError) as error:
        raise argparse.ArgumentTypeError(f"bad noise {text!r}: {error}") from None


def _param_value(text: str) -> Any:
    lowered = text.lower()
    if lowered == "none":
        return None
    if lowered in ("true", "false"):
        return lowered == "true"
    if "," in text:
        return [_param_value(p) for p in text.split(",")]
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def param(text: str) -> tuple[str, Any]:
    """``NAME=VALUE`` -> ``(name, value)``: a tone-mapping parameter; the value a bool, None, a number, a string or,
    comma-separated, a list of these (``grid_size=8,8``)."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE such as key=0.36; got {text!r}")
    return name.strip(), _param_value(value.strip())


# ------------------------------------------------------------------------------------------ job options


def _noise_option(value: dict[str, Any] | str | None, default: Any) -> Any:
    """A parsed ``--noise``: ``default`` when not given, None for ``none``, else the NoiseModel fields."""
    if value is None:
        return default
    return None if value == "none" else value


def simulate_options(args: argparse.Namespace, sub: argparse.ArgumentParser) -> dict[str, Any]:
    """The options of :func:`torch_modulo.pipeline.simulate_job` from ``simulate``'s arguments; a bad combination
    is a usage error of ``sub``, as are exposures too far apart for ``unwrap`` to decode, unless forced
    (``--force-exposures``: then a warning on stderr)."""
    if args.format != "exr" and args.bits > 16:
        sub.error(f"--format {args.format} holds at most 16 bits; got --bits {args.bits} (use --format exr)")
    if args.exposures != "auto" and (too_far := undecodable_ratio(args.exposures, args.bits)):
        if not args.force_exposures:
            sub.error(
                f"--exposures: {too_far}: `torch-modulo unwrap` cannot count the rollovers between them; choose "
                "exposures at most 2^bits apart or --exposures auto (--force-exposures writes them anyway)"
            )
        print(
            f"torch-modulo simulate: warning: {too_far}: `torch-modulo unwrap` cannot count the rollovers between "
            "them (--force-exposures writes them anyway)",
            file=sys.stderr,
        )
    from torch_modulo.noise import NoiseModel

    options = {
        "bits": args.bits,
        "exposures": args.exposures,
        "noise": _noise_option(args.noise, NoiseModel.preset(pipeline.DEFAULT_NOISE).to_dict()),
        "seed": args.seed,
        "scale": args.scale,
        "format": args.format,
        "truth": args.truth,
    }
    if args.cfa is not None:  # only when given: outputs completed without it stay complete
        options["cfa"] = args.cfa
    if args.linear:
        options["linear"] = True
    if args.force_exposures and args.exposures != "auto":
        options["force_exposures"] = True
    if args.max_side is not None:
        options["max_side"] = args.max_side
    if args.crop is not None:
        options["crop"] = args.crop
    if args.spatial:
        if args.noise == "none":
            sub.error("--spatial plans for the noise-aware decoder: it needs a noise model; got --noise none")
        if args.exposures != "auto" and len(args.exposures) < 2:
            sub.error(f"--spatial plans multi-shot stacks; got one exposure, --exposures {args.exposures[0]:g}")
    multi = args.exposures == "auto" or len(args.exposures) > 1
    if args.spatial is not None or (args.noise != "none" and multi):
        # Noisy plans are for the decoder with spatial evidence by default since it became the default: stacks an
        # earlier version planned for each pixel (no option) are not complete.
        options["spatial"] = True if args.spatial is None else args.spatial
    if args.longest_frames != 1:  # only when given: outputs completed without it stay complete
        if args.exposures != "auto":
            sub.error(
                f"--longest-frames applies to --exposures auto; repeat the longest given exposure instead "
                f"(e.g. 1,16,256,256); got --exposures {','.join(f'{t:g}' for t in args.exposures)}"
            )
        options["longest_frames"] = args.longest_frames
    return _with_nonfinite(options, args.nonfinite)


def _with_nonfinite(options: dict[str, Any], nonfinite: str) -> dict[str, Any]:
    # Only a non-default policy joins the options: outputs an earlier version completed (files without NaN or
    # infinite values, the only ones it accepted) are the same under the default, so they stay complete.
    if nonfinite != "replace":
        options["nonfinite"] = nonfinite
    return options


def unwrap_options(args: argparse.Namespace, sub: argparse.ArgumentParser) -> dict[str, Any]:
    """The options of :func:`torch_modulo.pipeline.unwrap_job` from ``unwrap``'s arguments; a bad combination, or
    a single-shot method or method option that ``unwrap_single`` refuses, is a usage error of ``sub``."""
    if args.exposure is not None and not args.single:
        sub.error("--exposure applies to --single only (frame stacks carry their exposures)")
    option = getattr(args, "method_option", None) or "--method"
    if args.confidence and not args.single:
        sub.error("--confidence applies to --single only")
    if args.noise is not None and args.single:
        sub.error("--noise applies to multi shot only (unwrap_single takes no noise model)")
    if args.spatial is not None and args.single:
        sub.error("--spatial/--no-spatial apply to multi shot only")
    if args.spatial and args.noise == "none":
        sub.error("--spatial is noise-aware decoding: it needs a noise model; got --noise none")
    if args.spatial and args.method == "paper":
        sub.error("--spatial is noise-aware decoding, which --method paper does not do; got --method paper")
    if args.noise not in (None, "none") and args.method == "paper":
        sub.error(
            "--method paper decodes Eqs. 6-7 as printed and takes no noise model: use --method robust, or --noise none"
        )
    rule, method = "robust", None  # the keys stay "method" (multi shot), "solver" (single shot)
    method_options: dict[str, Any] = {}
    if args.single:
        from torch_modulo.protocols import parse_method
        from torch_modulo.singleshot import METHODS, SingleShotUnwrap

        if args.method is not None:
            try:
                method, parsed = parse_method(args.method)
            except ValueError as error:
                sub.error(f"{option}: {error}")
            method_options.update(parsed)
            if method not in METHODS:
                sub.error(f"{option} must be one of {', '.join(sorted(METHODS))}; got {args.method!r}")
            reserved = {"bits": "--bits", "cfa": "--cfa", "workers": "--workers", "method": "--method"}
            for key in sorted(set(method_options) & {*reserved, "return_info"}):
                where = f"; use {reserved[key]}" if key in reserved else ""
                sub.error(f"{option} {args.method!r}: {key} is not a method option{where}")
            try:  # the options are checked now, before any file: an unknown one, a bad value, a missing file
                SingleShotUnwrap(bits=8, method=method, **method_options)
            except (TypeError, ValueError, FileNotFoundError) as error:
                sub.error(f"bad {option} {args.method!r}: {error}")
    elif option == "--solver":
        sub.error("--solver applies to --single only")
    elif args.method is not None:
        if args.method not in _MULTI_RULES:
            from torch_modulo.singleshot import METHODS

            if args.method.partition(":")[0] in METHODS:
                sub.error(f"--method {args.method} is a single-shot method: use it with --single")
            choices = ", ".join(repr(r) for r in _MULTI_RULES)
            sub.error(f"argument --method/--solver: invalid choice: {args.method!r} (choose from {choices})")
        rule = args.method
    options = {
        "single": args.single,
        "bits": args.bits,
        "exposure": args.exposure,
        "method": rule,
        "noise": _noise_option(args.noise, "stack"),
        "solver": method,
        "confidence": args.confidence,
        # Graph cuts inside each job use processes of their own only when the batch itself runs one at a time.
        "_solver_workers": None if args.workers == 1 else 1,
    }
    # Only when not the default: outputs completed before these options existed stay complete.
    if method_options:
        options["solver_options"] = dict(sorted(method_options.items()))
    if args.single and method in (None, "learned"):
        # "learned" moves regions by its level costs since version 2, and refines a mosaic's photosites since 3:
        # its earlier outputs are not complete.
        options["learned_version"] = 3
    if args.cfa is not None:
        options["cfa"] = args.cfa
    if not args.demosaic:
        options["demosaic"] = False
    if not args.single:
        # None: as each stack records, with spatial evidence where it records nothing, since that became the
        # default: radiance an earlier version decoded per pixel from such a stack is not complete.
        options["spatial"] = args.spatial
    return options


def tonemap_options(args: argparse.Namespace, sub: argparse.ArgumentParser) -> dict[str, Any]:
    """The options of :func:`torch_modulo.pipeline.tonemap_job` from ``tonemap``'s arguments, checked by
    :func:`torch_modulo.pipeline.tonemap_options`; a bad parameter is a usage error of ``sub``."""
    srgb = args.op != "gamma" if args.srgb is None else args.srgb  # gamma's own gamma encodes for display
    try:
        options = pipeline.tonemap_options(args.op, dict(args.param), srgb=srgb, depth=args.depth)
    except (TypeError, ValueError) as error:
        sub.error(f"bad --param for --op {args.op}: {error}")
    return _with_nonfinite(options, args.nonfinite)


#: The job options of each folder command, from its parsed arguments and its parser (for usage errors).
JOB_OPTIONS: dict[str, Callable[[argparse.Namespace, argparse.ArgumentParser], dict[str, Any]]] = {
    "simulate": simulate_options,
    "unwrap": unwrap_options,
    "tonemap": tonemap_options,
}
