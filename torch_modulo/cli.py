"""The ``torch-modulo`` command line.

    torch-modulo demo [--out DIR] [--scene FILE]    simulate, unwrap, tone-map and write files for one scene
    torch-modulo simulate IN OUT [--bits 8] [--exposures 1,256,65536] [--noise ...] [--seed N]
                                                    every HDR file in IN -> a modulo frame stack per scene in OUT
    torch-modulo unwrap IN OUT [--single]           frame stacks (or single modulus images) -> radiance EXRs
    torch-modulo tonemap IN OUT [--op histogram]    radiance files -> PNGs

The folder commands share one engine (:mod:`torch_modulo.batch`): a progress bar, ``--workers N`` processes,
inputs never written, atomic outputs, resume by rerunning, one bad file reported and skipped, a JSON report, a
non-zero exit code when anything failed, and the same commands under ``torchrun`` (each rank takes its shard) or
on a Ray cluster (``--engine ray``). Run ``torch-modulo COMMAND --help`` for every option with an example.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import inspect
import math
import sys
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["build_parser", "main", "simulate_job", "tonemap_job", "unwrap_job"]

#: Radiance files ``simulate`` and ``tonemap`` read.
RADIANCE_EXTENSIONS = (".exr", ".hdr", ".pfm", ".tif", ".tiff")
#: Modulus images ``unwrap --single`` reads.
MODULUS_EXTENSIONS = (".exr", ".png", ".tif", ".tiff", ".pfm")
#: Tone-mapping operators ``tonemap --op`` offers (``torch_modulo.tonemap.tonemap_<op>``).
TONEMAP_OPS = ("histogram", "reinhard", "gamma", "log", "clahe")
_TONEMAP_MODULES = {
    "histogram": "HistogramToneMap",
    "reinhard": "ReinhardToneMap",
    "gamma": "GammaToneMap",
    "log": "LogToneMap",
    "clahe": "ClaheToneMap",
}
#: Modules each command's workers import up front.
_PRELOAD = {
    "simulate": ("torch_modulo.io", "torch_modulo.sensors"),
    "unwrap": ("torch_modulo.io", "torch_modulo.sensors", "torch_modulo.multishot"),
    "tonemap": ("torch_modulo.io", "torch_modulo.tonemap"),
}
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


def _parse(text: str, cast: type[int] | type[float], kind: str) -> Any:
    """``cast(text)``, or the usage error ``expected <kind>; got '<text>'``."""
    try:
        return cast(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {kind}; got {text!r}") from None


def _positive_int(text: str) -> int:
    value = _parse(text, int, "a whole number")
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a number >= 1; got {value}")
    return value


def _ratio(text: str) -> float:
    value = _parse(text, float, "a number")
    if not 1.0 < value:
        raise argparse.ArgumentTypeError(f"expected a ratio > 1; got {value}")
    return value


def _bits(text: str) -> int:
    value = _positive_int(text)
    if value > 24:
        raise argparse.ArgumentTypeError(f"expected a bit depth from 1 to 24; got {value}")
    return value


def _nonnegative_int(text: str) -> int:
    value = _parse(text, int, "a whole number")
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0; got {value}")
    return value


def _positive_float(text: str) -> float:
    value = _parse(text, float, "a number")
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0; got {text!r}")
    return value


def _exposures(text: str) -> list[float]:
    """``"1,256,65536"`` -> [1.0, 256.0, 65536.0]: one or more finite exposures > 0."""
    parts = [p.strip() for p in text.split(",")]
    if not text.strip() or any(not p for p in parts):
        raise argparse.ArgumentTypeError(f"expected comma-separated exposures such as 1,256,65536; got {text!r}")
    values = []
    for part in parts:
        try:
            value = float(part)
        except ValueError:
            raise argparse.ArgumentTypeError(f"exposure {part!r} in {text!r} is not a number") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"exposures must be finite and > 0; got {part!r} in {text!r}")
        values.append(value)
    return values


def _scale(text: str) -> str | float:
    if text == "auto":
        return "auto"
    try:
        return _positive_float(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected 'auto' or a number > 0; got {text!r}") from None


def _flag_value(text: str, where: str) -> bool:
    lowered = text.lower()
    if lowered in ("1", "true", "on", "yes"):
        return True
    if lowered in ("0", "false", "off", "no"):
        return False
    raise argparse.ArgumentTypeError(f"{where} must be on or off; got {text!r}")


def _noise(text: str) -> dict[str, Any] | None:
    """``none``, ``default`` or ``read=2,q=1,dark=0,prnu=0.01,shot=on`` -> NoiseModel fields (validated)."""
    if text == "none":
        return None
    fields: dict[str, Any] = {}
    if text != "default":
        for item in text.split(","):
            key, sep, value = item.partition("=")
            key = key.strip()
            if not sep or key not in _NOISE_KEYS:
                raise argparse.ArgumentTypeError(
                    f"expected none, default or KEY=VALUE pairs with keys q, read, dark, prnu, shot; got {item!r}"
                )
            name = _NOISE_KEYS[key]
            if name == "shot_noise":
                fields[name] = _flag_value(value.strip(), "shot")
            else:
                try:
                    fields[name] = float(value)
                except ValueError:
                    raise argparse.ArgumentTypeError(f"noise {key}={value!r} is not a number") from None
    from torch_modulo.sensors import NoiseModel

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


def _param(text: str) -> tuple[str, Any]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE such as key=0.36; got {text!r}")
    return name.strip(), _param_value(value.strip())


def _tuples(params: Mapping[str, Any]) -> dict[str, Any]:
    """JSON keeps tuples as lists; the tone-mapping functions want tuples (``grid_size=(8, 8)``)."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in params.items()}


# ------------------------------------------------------------------------------------------------ parser


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the examples' line breaks (descriptions are wrapped by :func:`_wrap`)."""


def _wrap(text: str) -> str:
    return textwrap.fill(text, width=100)


_FOLDER_EPILOG = """
Every folder command: inputs are found recursively (hidden files skipped) and sorted; outputs mirror the
subfolders; IN is never written; outputs are written atomically; a rerun skips what is complete (same options,
unchanged input) so a crashed or interrupted run resumes where it stopped; a bad file is reported and skipped; the
report lists done/skipped/failed with reasons; the exit code is 0 when nothing failed, 1 when something failed,
130 after Ctrl-C, 2 for bad options.

Many machines: under torchrun every rank takes files[rank::world_size] and rank 0 merges the reports:
  torchrun --nnodes 2 --nproc_per_node 1 --rdzv_backend c10d --rdzv_endpoint HOST:29500 \\
      -m torch_modulo.cli {command} IN OUT
On a Ray cluster (pip install 'torch_modulo[ray]'):
  torch-modulo {command} IN OUT --engine ray --ray-address auto
"""


def _add_folder_options(sub: argparse.ArgumentParser, what_in: str, what_out: str) -> None:
    sub.add_argument("input", metavar="IN", help=what_in)
    sub.add_argument("output", metavar="OUT", help=what_out)
    group = sub.add_argument_group("batch options (every folder command)")
    group.add_argument(
        "--workers",
        type=_positive_int,
        default=None,
        metavar="N",
        help="worker processes (default: the machine's cores, shared among the torchrun ranks on one machine; "
        "with --engine ray: tasks in flight, default the cluster's CPUs)",
    )
    group.add_argument(
        "--engine",
        choices=("process", "ray"),
        default="process",
        help="process: a local process pool (default); ray: tasks on a Ray cluster (needs torch_modulo[ray])",
    )
    group.add_argument(
        "--ray-address",
        default=None,
        metavar="ADDR",
        help="Ray cluster to join, e.g. auto or ray://host:10001 (default: RAY_ADDRESS or local Ray)",
    )
    group.add_argument("--force", action="store_true", help="redo inputs whose outputs are already complete")
    group.add_argument(
        "--report", default=None, metavar="FILE", help="where the JSON report goes (default: OUT/<command>-report.json)"
    )
    group.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="show a progress bar (default: only when stderr is a terminal)",
    )


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
            "unwrap them from one shot (unwrap_single, see --solver) and from three shots (rollover counting), "
            "tone-map, and write EXRs, PNGs, comparison.png and summary.json."
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
        "--workers", type=_positive_int, default=None, help="processes for the single shot (default: one per core)"
    )
    demo.add_argument(
        "--solver",
        default="guided",
        choices=("guided", "fast", "paper"),
        help="single-shot method of unwrap_single (default: %(default)s; fast and paper: the paper's graph cut)",
    )

    simulate = commands.add_parser(
        "simulate",
        help="HDR files -> simulated modulo frame stacks (training data)",
        formatter_class=_Formatter,
        description=_wrap(
            "Capture every HDR radiance file in IN (.exr .hdr .pfm .tif) with a simulated modulo sensor (paper "
            "Eq. 1, optionally with shot/read noise) at each exposure, and write one frame stack per scene: the "
            "folder OUT/<scene>/ with one frame per exposure (frame_b000_m00.exr, ...; each frame's exposure and "
            "bit depth in its metadata), the manifest frames.json (read back by torch_modulo.sensors.FileSensor "
            "and by `torch-modulo unwrap`) and, unless --no-truth, radiance.exr: the scaled radiance the frames "
            "were captured from (counts per unit exposure), the ground truth for training and scoring."
        ),
        epilog="example:\n  torch-modulo simulate hdr_scenes/ stacks/ --bits 8 --exposures 1,256,65536 "
        "--noise read=2 --seed 1\n" + _FOLDER_EPILOG.format(command="simulate"),
    )
    _add_folder_options(simulate, "folder of HDR radiance files (or one file)", "folder for the frame stacks")
    simulate.add_argument("--bits", type=_bits, default=8, help="sensor bit depth N, 1 to 24 (default: 8)")
    simulate.add_argument(
        "--exposures",
        type=_exposures,
        default=[1.0, 256.0, 65536.0],
        metavar="T1,T2,...",
        help="exposures, comma-separated (default: 1,256,65536); neighbouring ratios up to 2^bits can be unwrapped",
    )
    simulate.add_argument(
        "--noise",
        type=_noise,
        default=None,
        metavar="MODEL",
        help="none (default: Eq. 1 exactly), default (shot noise, 1 e- read noise) or KEY=VALUE pairs: "
        "q=electrons per count, read=read noise (e- rms), dark=dark current (e- per unit exposure), "
        "prnu=fixed-pattern gain spread, shot=on|off; e.g. read=2,prnu=0.01",
    )
    simulate.add_argument(
        "--seed",
        type=_nonnegative_int,
        default=0,
        help="noise seed; each scene draws from a seed derived from it and its file name, so "
        "results do not depend on workers or ranks (default: 0)",
    )
    simulate.add_argument(
        "--scale",
        type=_scale,
        default="auto",
        metavar="auto|S",
        help="radiance multiplier into counts per unit exposure; auto (default) makes the brightest value read "
        "2^bits - 1 at the shortest exposure, so that frame does not roll over",
    )
    simulate.add_argument(
        "--format",
        choices=("exr", "png", "tiff"),
        default="exr",
        help="frame files: exr (default; half floats up to 11 bits), png or tiff (up to 16 bits)",
    )
    simulate.add_argument(
        "--truth",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="also write radiance.exr, the scaled ground truth (default: on)",
    )

    unwrap = commands.add_parser(
        "unwrap",
        help="frame stacks (or single modulus images) -> radiance EXRs",
        formatter_class=_Formatter,
        description=_wrap(
            "Recover radiance. Default (multi shot, paper Eqs. 6-7): every frame stack in IN, i.e. every folder "
            "with a frames.json manifest as `torch-modulo simulate` or torch_modulo.sensors.write_frames write "
            "it, becomes OUT/<stack>.exr by rollover counting (unwrap_multi; stacks of a conventional sensor, "
            "kind 'intensity', are merged with merge_intensity instead). With --single (paper Eqs. 3-5): every "
            "modulus image in IN (.exr .png .tif .pfm) is unwrapped alone (unwrap_single, see --solver) and "
            "becomes OUT/<image>.exr, the restored counts divided by the frame's exposure. Output values are "
            "radiance in counts per unit exposure; the metadata records the source, bit depth and exposures."
        ),
        epilog="examples:\n  torch-modulo unwrap stacks/ radiance/\n"
        "  torch-modulo unwrap camera_frames/ radiance/ --single --bits 8\n" + _FOLDER_EPILOG.format(command="unwrap"),
    )
    _add_folder_options(unwrap, "folder of frame stacks, or of modulus images with --single", "folder for the EXRs")
    unwrap.add_argument(
        "--single", action="store_true", help="IN holds single modulus images: unwrap each one alone (unwrap_single)"
    )
    unwrap.add_argument(
        "--bits",
        type=_bits,
        default=None,
        help="sensor bit depth (default: from each file's metadata, manifest or sidecar)",
    )
    unwrap.add_argument(
        "--exposure",
        type=_positive_float,
        default=None,
        help="with --single: the frames' exposure (default: from the metadata, else 1)",
    )
    unwrap.add_argument(
        "--confidence",
        action="store_true",
        help="with --single: also write OUT/<image>.confidence.exr, unwrap_confidence's map (1: the rollover count "
        "is determined by the image; 0: it was guessed, take a second exposure there)",
    )
    unwrap.add_argument(
        "--solver",
        default=None,
        metavar="METHOD",
        help="with --single: the method of unwrap_single: guided (path following, channels together; the "
        "default), fast (the paper's graph cut on a cheaper schedule) or paper (Eqs. 3-5 from k = 0, slow)",
    )
    unwrap.add_argument(
        "--method",
        choices=("robust", "paper"),
        default="robust",
        help="multi-shot rule: robust (default; exact for every ratio up to 2^bits) or paper (Eq. 6 as printed)",
    )

    tonemap = commands.add_parser(
        "tonemap",
        help="radiance files -> display PNGs",
        formatter_class=_Formatter,
        description=_wrap(
            "Tone-map every radiance file in IN (.exr .hdr .pfm .tif) to OUT/<name>.png with one of the operators "
            "of torch_modulo.tonemap: histogram (Larson et al. 1997, the paper's choice), reinhard, gamma, log, "
            "clahe. Negative values (lossy files) are clamped to 0; of more than three channels (alpha, other views or "
            "layers) the first three are taken as RGB."
        ),
        epilog="examples:\n  torch-modulo tonemap radiance/ png/ --op histogram --srgb\n"
        "  torch-modulo tonemap radiance/ png/ --op reinhard --param key=0.36 --depth 16\n"
        + _FOLDER_EPILOG.format(command="tonemap"),
    )
    _add_folder_options(tonemap, "folder of radiance files (or one file)", "folder for the PNGs")
    tonemap.add_argument(
        "--op", choices=TONEMAP_OPS, default="histogram", help="tone-mapping operator (default: histogram)"
    )
    tonemap.add_argument(
        "--param",
        type=_param,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="an operator parameter, repeatable, e.g. key=0.36 (reinhard), gamma=2.4 exposure=1 (gamma), "
        "clip_limit=3 grid_size=8,8 (clahe), ld_max=200 (histogram); see torch_modulo.tonemap",
    )
    tonemap.add_argument("--srgb", action="store_true", help="apply the sRGB transfer function to the result")
    tonemap.add_argument("--depth", type=int, choices=(8, 16), default=8, help="PNG bits per sample (default: 8)")
    return parser


# -------------------------------------------------------------------------------------------------- jobs
# Top-level functions run in worker processes: job(task, options) reads task.source and writes task.outputs.


def _scene_seed(seed: int, name: str) -> int:
    """A per-scene seed from the run's seed and the input's name: the same on every worker, rank and rerun."""
    return int.from_bytes(hashlib.sha256(f"{seed}:{name}".encode()).digest()[:8], "little") % (2**63)


def _image_channels(image: Any, source: str) -> Any:
    """(C, H, W) radiance with C = 1 or 3: grey stays grey; with 2 channels (grey + alpha, or two views) the first;
    with 3 or more (RGBA, multi-view or multi-layer files, whose first channels are R, G, B) the first three."""
    c = image.shape[0]
    if c < 1:
        raise ValueError(f"{source} has no channels")
    if c == 1:
        return image
    return image[:1] if c == 2 else image[:3]


def _finite(image: Any, source: str) -> None:
    import torch

    bad = int((~torch.isfinite(image)).sum())
    if bad:
        raise ValueError(f"{source} holds {bad} NaN or infinite values")


def simulate_job(task: Any, options: Mapping[str, Any]) -> dict[str, Any]:
    """Job of ``torch-modulo simulate``: one HDR file -> one frame-stack folder (atomic)."""
    import torch

    from torch_modulo.batch import atomic_output_dir
    from torch_modulo.io import read_image, write_image
    from torch_modulo.sensors import FrameStack, NoiseModel, SimulatedModuloSensor, write_frames

    bits = int(options["bits"])
    taus = [float(t) for t in options["exposures"]]
    image = _image_channels(read_image(task.source, dtype=torch.float64), task.source)
    _finite(image, task.source)
    negatives = int((image < 0).sum())
    image = image.clamp_min(0)
    peak = float(image.max())
    if options["scale"] == "auto":
        if peak <= 0:
            raise ValueError(f"{task.source} is black (maximum {peak}): --scale auto cannot scale it")
        scale = (2**bits - 1) / (peak * min(taus))
    else:
        scale = float(options["scale"])
    # Round to float32 first: radiance.exr (float32) then holds exactly the radiance the frames were captured from.
    radiance = (image * scale).float().double()
    noise = NoiseModel(**options["noise"]) if options["noise"] is not None else None
    seed = _scene_seed(int(options["seed"]), task.name)
    stack = SimulatedModuloSensor(bits, noise, seed=seed)(radiance.unsqueeze(0), taus)
    metadata = {
        **stack.metadata,
        "source": task.name,
        "radiance_scale": scale,
        "unit": "counts per unit exposure",
        "bits": bits,
        "exposures": taus,
    }
    dtype = torch.float32 if bits <= 24 else torch.float64
    stack = FrameStack(stack.moduli.to(dtype), stack.exposures, bits, metadata, kind=stack.kind)
    with atomic_output_dir(task.outputs[0]) as folder:
        write_frames(stack, folder, format=options["format"])
        if options["truth"]:
            write_image(
                folder / "radiance.exr",
                radiance.float(),
                {"source": task.name, "radiance_scale": scale, "unit": "counts per unit exposure"},
            )
    return {"shape": list(image.shape), "radiance_scale": scale, "negatives_clamped": negatives}


def unwrap_job(task: Any, options: Mapping[str, Any]) -> dict[str, Any]:
    """Job of ``torch-modulo unwrap``: one frame stack (or, single shot, one modulus image) -> one radiance EXR."""

    from torch_modulo.io import read_image, write_image

    if options["single"]:
        image, meta = read_image(task.source, with_metadata=True)
        bits = options["bits"]
        if bits is None:
            bits = meta.get("bits", meta.get("bit_depth"))
            if bits is None:
                raise ValueError(f"no bit depth in the metadata of {task.source}: pass --bits")
        exposure = options["exposure"] or meta.get("exposure") or 1.0
        from torch_modulo.singleshot import unwrap_confidence, unwrap_single

        solver = {"method": options["solver"]} if options["solver"] is not None else {}
        counts = unwrap_single(image.unsqueeze(0), int(bits), workers=options["_solver_workers"], **solver)[0]
        radiance = counts.double() / float(exposure)
        metadata = {
            "source": task.name,
            "bits": int(bits),
            "exposure": float(exposure),
            "method": "single",
            "solver": options["solver"] or "default",
            "unit": "counts per unit exposure",
        }
        if options.get("confidence"):
            confidence = unwrap_confidence(counts.double(), int(bits))
            write_image(task.outputs[1], confidence.float(), {**metadata, "unit": "confidence in [0, 1]"})
    else:
        from torch_modulo.multishot import merge_intensity, unwrap_multi
        from torch_modulo.sensors import FileSensor

        # The frames' own dtype (float32 for stacks from simulate: exact up to 24 bits; unwrap_multi decides in
        # float64 internally, and the EXR stores float32 anyway).
        stack = FileSensor(task.source, bits=options["bits"]).read()
        if stack.batch_size != 1:
            raise ValueError(f"{task.source} holds {stack.batch_size} scenes; unwrap expects one scene per stack")
        if stack.kind == "intensity":
            radiance = merge_intensity(stack.frames, stack.exposures, stack.bits)[0]
            method = "merge_intensity"
        else:
            radiance = unwrap_multi(stack.moduli, stack.exposures, stack.bits, options["method"])[0]
            method = options["method"]
        metadata = {
            "source": task.name,
            "bits": stack.bits,
            "exposures": stack.exposure_matrix()[0].tolist(),
            "method": method,
            "kind": stack.kind,
            "unit": "counts per unit exposure",
        }
        if "radiance_scale" in stack.metadata:
            metadata["radiance_scale"] = stack.metadata["radiance_scale"]
    write_image(task.outputs[0], radiance.float(), metadata)
    return {"shape": list(radiance.shape), "method": metadata["method"]}


def tonemap_job(task: Any, options: Mapping[str, Any]) -> dict[str, Any]:
    """Job of ``torch-modulo tonemap``: one radiance file -> one PNG."""
    from torch_modulo import tonemap
    from torch_modulo.io import read_image, write_image

    hdr = _image_channels(read_image(task.source), task.source)
    _finite(hdr, task.source)
    operator = getattr(tonemap, f"tonemap_{options['op']}")
    display = operator(hdr.clamp_min(0).unsqueeze(0), **_tuples(options["params"]), srgb=options["srgb"])[0]
    metadata = {"source": task.name, "op": options["op"], "params": options["params"], "srgb": options["srgb"]}
    write_image(task.outputs[0], display, metadata, dtype=f"uint{options['depth']}", normalized=True)
    return {"shape": list(hdr.shape)}


# ------------------------------------------------------------------------------------------------ running


def _subparser(parser: argparse.ArgumentParser, command: str) -> argparse.ArgumentParser:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices[command]
    return parser


def _is_stack(path: Path) -> bool:
    return path.is_dir() and (path / "frames.json").is_file()


def _plan(args: argparse.Namespace, source: Path, out: Path) -> tuple[list[Any], str]:
    """The tasks of a folder command (sorted) and a description of what it looks for."""
    from torch_modulo.batch import Task, discover

    def suffix_match(extensions: Sequence[str]) -> Any:
        return lambda p: p.is_file() and p.suffix.lower() in extensions

    if args.command in ("simulate", "tonemap"):
        found = discover(source, suffix_match(RADIANCE_EXTENSIONS))
        wanted = f"radiance files ({' '.join(RADIANCE_EXTENSIONS)})"
    elif args.single:
        found = discover(source, suffix_match(MODULUS_EXTENSIONS))
        wanted = f"modulus images ({' '.join(MODULUS_EXTENSIONS)})"
    else:
        found = discover(source, _is_stack)
        wanted = "frame stacks (folders with a frames.json manifest)"
    tasks = []
    for name, path in found:
        rel = Path(name)
        if args.command == "simulate":
            target = out / rel.with_suffix("")
        elif args.command == "unwrap":
            target = out / (rel.with_suffix(".exr") if args.single else rel.with_name(rel.name + ".exr"))
        else:
            target = out / rel.with_suffix(".png")
        targets = [target]
        if args.command == "unwrap" and args.single and args.confidence:
            targets.append(target.with_name(f"{target.stem}.confidence.exr"))
        tasks.append(Task(name, str(path), tuple(str(t) for t in targets)))
    return tasks, wanted


def _options(args: argparse.Namespace, sub: argparse.ArgumentParser, workers: int | None) -> dict[str, Any]:
    """The job options (JSON-compatible; they decide whether an existing output is complete)."""
    if args.command == "simulate":
        if args.format != "exr" and args.bits > 16:
            sub.error(f"--format {args.format} holds at most 16 bits; got --bits {args.bits} (use --format exr)")
        taus = sorted(args.exposures)
        too_far = [(a, b) for a, b in zip(taus, taus[1:], strict=False) if b / a > 2**args.bits]
        if too_far:
            a, b = too_far[0]
            print(
                f"torch-modulo simulate: warning: exposures {a:g} and {b:g} are more than 2^{args.bits} apart; "
                "`torch-modulo unwrap` cannot count the rollovers between them",
                file=sys.stderr,
            )
        return {
            "bits": args.bits,
            "exposures": args.exposures,
            "noise": args.noise,
            "seed": args.seed,
            "scale": args.scale,
            "format": args.format,
            "truth": args.truth,
        }
    if args.command == "unwrap":
        if args.exposure is not None and not args.single:
            sub.error("--exposure applies to --single only (frame stacks carry their exposures)")
        # Graph cuts inside each job use processes of their own only when the batch itself runs one at a time.
        if args.solver is not None and not args.single:
            sub.error("--solver applies to --single only")
        if args.confidence and not args.single:
            sub.error("--confidence applies to --single only")
        if args.single and args.solver is not None:
            from torch_modulo.singleshot import METHODS

            if args.solver not in METHODS:
                sub.error(f"--solver must be one of {', '.join(sorted(METHODS))}; got {args.solver!r}")
        return {
            "single": args.single,
            "bits": args.bits,
            "exposure": args.exposure,
            "method": args.method,
            "solver": args.solver,
            "confidence": args.confidence,
            "_solver_workers": None if workers == 1 else 1,
        }
    params = dict(args.param)
    from torch_modulo import tonemap

    function = getattr(tonemap, f"tonemap_{args.op}")
    allowed = [p for p in inspect.signature(function).parameters if p not in ("hdr", "srgb")]
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        sub.error(f"--op {args.op} has no parameter {unknown[0]!r}; its parameters are {', '.join(allowed)}")
    try:  # the module twin validates its arguments on construction
        getattr(tonemap, _TONEMAP_MODULES[args.op])(**_tuples(params), srgb=args.srgb)
    except (TypeError, ValueError) as error:
        sub.error(f"bad --param for --op {args.op}: {error}")
    return {"op": args.op, "params": params, "srgb": args.srgb, "depth": args.depth}


def _run_folder_command(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    from torch_modulo.batch import BatchError, check_folders, distributed_env, run_batch

    sub = _subparser(parser, args.command)
    prog = f"torch-modulo {args.command}"
    try:
        source, out = check_folders(args.input, args.output)
        env = distributed_env()
    except BatchError as error:
        sub.error(str(error))
    if args.report is not None and source.is_dir() and source in Path(args.report).resolve().parents:
        sub.error(f"--report {args.report} is inside the input folder {source}; inputs are never written")
    if args.engine == "ray":
        from torch_modulo.batch import require_ray

        try:
            require_ray()
        except BatchError as error:
            sub.error(str(error))
    options = _options(args, sub, args.workers)
    try:
        tasks, wanted = _plan(args, source, out)
    except OSError as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 1
    if not tasks:
        print(f"{prog}: error: no {wanted} found in {source}", file=sys.stderr)
        return 1
    # Look the job up in the importable module, not in __main__ (python -m torch_modulo.cli, torchrun -m ...), so
    # that worker processes can unpickle it.
    job = getattr(importlib.import_module("torch_modulo.cli"), f"{args.command}_job")
    try:
        report = run_batch(
            args.command,
            tasks,
            job,
            options,
            out,
            input_path=source,
            workers=args.workers,
            engine=args.engine,
            force=args.force,
            progress=args.progress,
            report_path=args.report,
            ray_address=args.ray_address,
            preload=_PRELOAD[args.command] + (("torch_modulo.singleshot",) if getattr(args, "single", False) else ()),
        )
    except BatchError as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
    report_file = Path(args.report) if args.report else out / f"{args.command}-report.json"
    where = ""
    if env.world_size > 1:
        where = f"rank {env.rank}: "
        if report.parts is None:  # this rank's own part (rank 0 holds the merged report when it could merge)
            report_file = report_file.with_name(f"{report_file.stem}.rank{env.rank}{report_file.suffix}")
    print(f"{where}{report.summary()} (report: {report_file})", file=sys.stderr)
    return report.exit_code


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``torch-modulo``; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command == "demo":
        from torch_modulo.demo import run_demo

        try:
            run_demo(args.out, args.scene, bits=args.bits, ratio=args.ratio, workers=args.workers, method=args.solver)
        except (OSError, ValueError, TypeError) as error:
            print(f"torch-modulo demo: error: {error}", file=sys.stderr)
            return 1
        return 0
    if args.command in ("simulate", "unwrap", "tonemap"):
        return _run_folder_command(parser, args)
    parser.error(f"unknown command {args.command!r}")
    return 2


if __name__ == "__main__":
    sys.exit(main())
