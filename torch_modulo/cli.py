"""The ``torch-modulo`` command line: parse, call the library, report.

    torch-modulo demo [--out DIR] [--scene FILE]    simulate, unwrap, tone-map and write files for one scene
    torch-modulo simulate IN OUT [--bits 8] [--exposures auto] [--noise photon-counting] [--seed N] [--cfa RGGB]
                                 [--max-side N] [--crop H,W] [--linear] [--[no-]spatial] [--longest-frames L]
                                                    every HDR file in IN -> a modulo frame stack per scene in OUT
    torch-modulo unwrap IN OUT [--single] [--noise MODEL] [--[no-]spatial] [--cfa RGGB] [--no-demosaic]
                                                    frame stacks (or single modulus images) -> radiance EXRs
    torch-modulo tonemap IN OUT [--op histogram]    radiance files -> sRGB PNGs (frames, confidence maps skipped)
    torch-modulo design --bits B --noise MODEL --stops S [--frames K] [--no-spatial] [--json] [--plot FILE]
                                                    a modulo sensor's plan and error against a conventional one

The per-file work lives in :mod:`torch_modulo.pipeline`, each folder command's inputs in
:mod:`torch_modulo.folders`, the options' types and the jobs' options in :mod:`torch_modulo._cli_options`, and the
folder commands share one engine (:mod:`torch_modulo.batch`): a progress bar, ``--workers N`` processes, inputs
never written, atomic outputs, resume by rerunning, one bad file reported and skipped, a JSON report, a non-zero
exit code when anything failed, and the same commands under ``torchrun`` (the ranks share the files) or on a Ray
cluster (``--engine ray``). Run ``torch-modulo COMMAND --help`` for every option with an example.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from torch_modulo._argtypes import nonnegative_int as _nonnegative_int
from torch_modulo._argtypes import positive_int as _positive_int
from torch_modulo._cli_design import add_design, run_design
from torch_modulo._cli_options import (
    JOB_OPTIONS,
    bit_depth,
    cfa_pattern,
    crop_size,
    exposures,
    noise,
    param,
    positive_float,
    ratio,
    scale,
)
from torch_modulo.cfa import CFA_PATTERNS
from torch_modulo.pipeline import NONFINITE, TONEMAP_OPS, simulate_job, tonemap_job, unwrap_job

# The jobs live in torch_modulo.pipeline; they stay importable from here.
__all__ = ["build_parser", "main", "simulate_job", "tonemap_job", "unwrap_job"]

# ------------------------------------------------------------------------------------------------ parser


class _Formatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the examples' line breaks (descriptions are wrapped by :func:`_wrap`)."""


def _wrap(text: str) -> str:
    return textwrap.fill(text, width=100)


class _MethodOption(argparse.Action):
    """``--method``, also reachable as ``--solver``, its deprecated former name (using it prints a warning)."""

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string: Any = None
    ) -> None:
        if option_string == "--solver":
            print(f"{parser.prog}: warning: --solver is deprecated; use --method", file=sys.stderr)
        setattr(namespace, self.dest, values)
        namespace.method_option = option_string


_FOLDER_EPILOG = """
Every folder command: inputs are found recursively (hidden files skipped, each file once even through symbolic
links) and sorted; outputs mirror the subfolders; IN is never written; outputs are written atomically; a rerun
skips what is complete (same options, unchanged input) so a crashed or interrupted run resumes where it stopped;
a bad file is reported and skipped; the report lists done/skipped/failed with reasons; the exit code is 0 when
nothing failed, 1 when something failed, 130 after Ctrl-C, 2 for bad options.

Many machines: under torchrun the ranks share the files (balanced by their number of values) and rank 0 merges
the ranks' reports:
  torchrun --nnodes 2 --nproc_per_node 1 --rdzv_backend c10d --rdzv_endpoint HOST:29500 \\
      -m torch_modulo.cli {command} IN OUT
On a Ray cluster (pip install 'torch_modulo[ray]'):
  torch-modulo {command} IN OUT --engine ray --ray-address auto
"""

_NONFINITE_HELP = (
    "what to do with NaN and infinite values: replace (default: NaN and -Inf by 0, +Inf by the image's largest "
    "finite value; the report counts them) or raise (report the file as failed); negative values are clamped to 0"
)


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
    group.add_argument(
        "--merge-timeout",
        type=positive_float,
        default=None,
        metavar="S",
        help="under torchrun: seconds rank 0 waits for the other ranks' reports after its own work, then reports "
        "the missing ones and exits 1 (default: as long as they run)",
    )


def _add_demo(commands: Any) -> None:
    from torch_modulo.singleshot import METHODS  # the registry's names: a new method is a choice at once

    demo = commands.add_parser(
        "demo",
        help="run the whole pipeline on one scene and write the results",
        description=(
            "Simulate 8-bit modulo and intensity captures of an HDR scene (default: the embedded CC0 scene), "
            "unwrap them from one shot (unwrap_single, see --method) and from three shots (rollover counting), "
            "tone-map, and write EXRs, PNGs, comparison.png and summary.json."
        ),
        epilog="example: torch-modulo demo --out demo_out",
    )
    demo.add_argument("--out", default="demo_out", help="output folder (default: %(default)s)")
    demo.add_argument("--scene", default=None, help="an EXR or HDR radiance file (default: the embedded scene)")
    demo.add_argument("--bits", type=bit_depth, default=8, help="sensor bit depth, 1 to 24 (default: %(default)s)")
    demo.add_argument(
        "--ratio",
        type=ratio,
        default=64.0,
        help="multi-shot neighbouring exposure ratio, at most 2**bits (default: %(default)s)",
    )
    demo.add_argument(
        "--workers",
        type=_positive_int,
        default=None,
        help="processes for the single shot with --method guided, fast or paper (default: one per core; learned "
        "and lsq run in this process)",
    )
    demo.add_argument(
        "--method",
        "--solver",
        action=_MethodOption,
        dest="method",
        default="learned",
        choices=METHODS,
        help="single-shot method of unwrap_single (default: %(default)s; fast and paper: the paper's graph cut; "
        "--solver is its deprecated former name)",
    )


_NOISE_PRESETS = (
    "photon-counting (1 e- per count, 1 e- read noise{photon}), q16 (16 e- per count, 16 e- read noise) or dfpa (a "
    "digital-pixel focal plane array like the paper's camera; see torch_modulo.noise.NoiseModel.preset)"
)
_NOISE_HELP = (
    "{default}. Otherwise: none (Eq. 1 exactly); a preset, {presets}; or KEY=VALUE pairs, optionally after a preset "
    "whose fields they change (else the first preset's): q=electrons per count, read=read noise (e- rms), "
    "dark=dark current (e- per unit exposure), prnu=fixed-pattern gain spread, shot=on|off; e.g. read=2,prnu=0.01 or "
    "q16,read=20"
)


def _add_noise(sub: argparse.ArgumentParser, default: str, photon: str = "") -> None:
    """``--noise MODEL`` (:func:`torch_modulo._cli_options.noise`): its help starts with what ``default`` says, and
    ``photon`` ends the photon-counting preset's description (where it is the default)."""
    presets = _NOISE_PRESETS.format(photon=photon)
    text = _NOISE_HELP.format(default=default, presets=presets)
    sub.add_argument("--noise", type=noise, default=None, metavar="MODEL", help=text)


def _add_cfa(sub: argparse.ArgumentParser, text: str) -> None:
    """``--cfa PATTERN``: one of the colour filter arrays, default none, with the help ``text``."""
    sub.add_argument("--cfa", type=cfa_pattern, choices=CFA_PATTERNS, default=None, metavar="PATTERN", help=text)


_SIMULATE_DESCRIPTION = (
    "Capture every HDR radiance file in IN (.exr .hdr .pfm .tif .tiff) with a simulated modulo sensor (paper "
    "Eq. 1, with shot and read noise by default, as torch_modulo.sensors.SimulatedModuloSensor()) at each "
    "exposure, and write one frame stack per scene: the folder OUT/<scene>/ with one frame per exposure "
    "(frame_b000_m00.exr, ...; each frame's exposure and bit depth in its metadata), the manifest "
    "frames.json (with the noise model, read back by torch_modulo.sensors.FileSensor and by `torch-modulo "
    "unwrap`, which decodes with it) and, unless --no-truth, radiance.exr: the scaled radiance the frames "
    "were captured from (counts per unit exposure), the ground truth for training and scoring. By default "
    "(--exposures auto) each scene gets the exposures that plan_exposures plans for its own dynamic range, "
    "bit depth and noise model; one given exposure makes a single-shot stack whose frame wraps (for "
    "`torch-modulo unwrap --single`). With --cfa the sensor is a colour sensor: RGB scenes are mosaicked "
    "by its colour filter array and the frames are mosaics (one channel, the pattern in the metadata), "
    "while radiance.exr stays RGB."
)
_SIMULATE_EXAMPLES = (
    "examples:\n  torch-modulo simulate hdr_scenes/ stacks/\n"
    "  torch-modulo simulate hdr_scenes/ stacks/ --noise q16 --seed 1\n"
    "  torch-modulo simulate hdr_scenes/ many/ --noise q16 --no-spatial      # each pixel decoded alone: more frames\n"
    "  torch-modulo simulate hdr_scenes/ twice/ --noise q16 --longest-frames 2   # the longest exposure twice\n"
    "  torch-modulo simulate hdr_scenes/ single/ --exposures 1 --noise none   # one wrapped frame per scene\n"
    "  torch-modulo simulate hdr_scenes/ colour/ --cfa RGGB                   # a colour modulo camera\n"
    "  torch-modulo simulate big_scenes/ small/ --max-side 512 --crop 256     # area-averaged, centre crop\n"
)


def _add_simulate(commands: Any) -> None:
    simulate = commands.add_parser(
        "simulate",
        help="HDR files -> simulated modulo frame stacks (training data)",
        formatter_class=_Formatter,
        description=_wrap(_SIMULATE_DESCRIPTION),
        epilog=_SIMULATE_EXAMPLES + _FOLDER_EPILOG.format(command="simulate"),
    )
    _add_folder_options(simulate, "folder of HDR radiance files (or one file)", "folder for the frame stacks")
    simulate.add_argument("--bits", type=bit_depth, default=8, help="sensor bit depth N, 1 to 24 (default: 8)")
    simulate.add_argument(
        "--exposures",
        type=exposures,
        default="auto",
        metavar="auto|T1,T2,...",
        help="auto (default): per scene, plan_exposures(stops, bits, noise=..., longest=1) for the scene's own "
        "stops (log2 of its maximum over the 0.1th percentile of its positive values, plus 4, rounded up); or "
        "exposures, comma-separated, each once but the longest (under noise its repeats collect light), e.g. "
        "1,16,256 or 1,16,256,256 (neighbours more than 2^bits apart, which unwrap cannot decode, are refused: "
        "see --force-exposures; under noise, ratios the noise model says are unsafe draw a warning naming a safe "
        "plan; one exposure: a single-shot stack)",
    )
    simulate.add_argument(
        "--force-exposures",
        action="store_true",
        help="write stacks whose exposures have two neighbours more than 2^bits apart, which `torch-modulo unwrap` "
        "cannot decode (default: off, such --exposures are a usage error and nothing is written)",
    )
    _add_noise(simulate, "the sensor's noise model (default: the first preset below)", "; the default, also 'default'")
    simulate.add_argument(
        "--spatial",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="with a noise model: plan for the decoder with spatial evidence (plan_exposures' default: about half "
        "the frames of the per-pixel plan; given --exposures are checked against its safe ratio), or for each pixel "
        "decoded alone (--no-spatial); each stack records which, so that `torch-modulo unwrap` decodes it so "
        "(default: spatial evidence)",
    )
    simulate.add_argument(
        "--longest-frames",
        type=_positive_int,
        default=1,
        metavar="L",
        help="with --exposures auto: take each plan's longest exposure L times (plan_exposures(..., "
        "longest_frames=L)); under noise the repeats collect light, e.g. --longest-frames 2 decodes protocol "
        "N's scenes better than the per-pixel plan with about half its frames at q16 (default: 1)",
    )
    simulate.add_argument(
        "--seed",
        type=_nonnegative_int,
        default=0,
        help="noise seed; each scene draws from a seed derived from it and its path relative to IN, so "
        "results do not depend on workers or ranks (default: 0)",
    )
    simulate.add_argument(
        "--scale",
        type=scale,
        default="auto",
        metavar="auto|S",
        help="radiance multiplier into counts per unit exposure; auto (default): with --exposures auto, the 0.1th "
        "percentile of the positive values reads 16 counts at the longest exposure; with several given exposures, "
        "the brightest value reads 2^bits - 1 at the shortest (under noise, three standard deviations below the "
        "rollover), so that frame does not roll over; with one given exposure, the 99.9th percentile of the "
        "luminance (grey: of all values) reads 16 periods, 16 * 2^bits - 1 counts (4095 at 8 bits), so it wraps",
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
    simulate.add_argument("--nonfinite", choices=NONFINITE, default="replace", help=_NONFINITE_HELP)
    simulate.add_argument(
        "--max-side",
        type=_positive_int,
        default=None,
        metavar="N",
        help="shrink each scene first by area averaging, by the smallest integer factor that brings its longer side "
        "to at most N pixels (torch_modulo.protocols.downsample_area, as the benchmarks do; rows and columns that do "
        "not fill a block are dropped); e.g. --max-side 512 (default: full size)",
    )
    simulate.add_argument(
        "--crop",
        type=crop_size,
        default=None,
        metavar="H,W",
        help="keep the centre H x W pixels of each scene (after --max-side; N for N x N), e.g. --crop 256,384; "
        "a scene smaller than that fails, named in the report (default: no crop)",
    )
    simulate.add_argument(
        "--linear",
        action="store_true",
        help="take 8/16-bit integer files (PNG, TIFF) as linear radiance; without it they fail, named in the "
        "report: their values are display-referred (a photo encoded for a screen), not light (default: off)",
    )
    _add_cfa(
        simulate,
        f"capture with a colour sensor whose colour filter array is PATTERN ({', '.join(CFA_PATTERNS)}: the "
        "top-left 2 x 2 cell read row by row): the frames are mosaics of the RGB radiance, noise per photosite, "
        "with the pattern in the metadata; scenes that are not RGB fail (each named in the report), an odd height "
        "or width loses its last row or column; radiance.exr stays RGB (default: none, one frame channel per "
        "scene channel)",
    )


_UNWRAP_DESCRIPTION = (
    "Recover radiance. Default (multi shot): every frame stack in IN, i.e. every folder with a frames.json "
    "manifest as `torch-modulo simulate` or torch_modulo.sensors.write_frames write it, becomes "
    "OUT/<stack>.exr by rollover counting (unwrap_multi), noise-aware with the noise model recorded in the "
    "stack's metadata (see --noise; where none is recorded, noise-free: paper Eqs. 6-7); stacks of a "
    "conventional sensor, kind 'intensity', are merged with merge_intensity instead. With --single (paper "
    "Eqs. 3-5): every stack of one exposure (`torch-modulo simulate --exposures 1`) and every modulus "
    "image in IN outside the stacks (.exr .png .tif .tiff .pfm) is unwrapped alone (unwrap_single, see "
    "--method) "
    "and becomes OUT/<name>.exr, the restored counts divided by the frame's exposure. Output values are "
    "radiance in counts per unit exposure; the metadata records the source, bit depth, exposures and noise "
    "model. Where a stack holds its ground truth (radiance.exr, as simulate writes it) the report scores "
    "each result against it (multi shot: median relative error and the share of values more than 50% "
    "off; single shot: exact rollover counts and PSNR) and the summary line gives the means; the "
    "decoder's warnings (exposure ratios too large for the noise) are printed and kept in the report. "
    "Mosaics of a colour sensor (the pattern recorded in the stack, or --cfa) are unwrapped first (multi "
    "shot with unwrap_multi(..., cfa=...), each colour plane apart, single shot with unwrap_single(..., cfa=...)) "
    "and then demosaiced to RGB radiance "
    "(torch_modulo.cfa.demosaic), which is scored against the RGB truth."
)
_UNWRAP_EXAMPLES = (
    "examples:\n  torch-modulo unwrap stacks/ radiance/\n"
    "  torch-modulo unwrap stacks/ radiance/ --noise none      # noise-free decoding (the robust rule)\n"
    "  torch-modulo unwrap stacks/ radiance/ --no-spatial      # each pixel alone, whatever the stacks record\n"
    "  torch-modulo unwrap single/ radiance/ --single          # stacks of one exposure, scored if truth is there\n"
    "  torch-modulo unwrap camera_frames/ radiance/ --single --bits 8 --method fast\n"
    "  torch-modulo unwrap big_frames/ radiance/ --single --bits 8 --method learned:levels=False   # faster\n"
    "  torch-modulo unwrap colour/ radiance/                   # mosaics (simulate --cfa): demosaiced RGB\n"
    "  torch-modulo unwrap camera/ radiance/ --single --bits 8 --cfa RGGB   # mosaicked modulus images\n"
)


def _add_unwrap(commands: Any) -> None:
    unwrap = commands.add_parser(
        "unwrap",
        help="frame stacks (or single modulus images) -> radiance EXRs",
        formatter_class=_Formatter,
        description=_wrap(_UNWRAP_DESCRIPTION),
        epilog=_UNWRAP_EXAMPLES + _FOLDER_EPILOG.format(command="unwrap"),
    )
    _add_folder_options(
        unwrap,
        "folder of frame stacks, or with --single of single-exposure stacks or modulus images",
        "folder for the EXRs",
    )
    unwrap.add_argument(
        "--single",
        action="store_true",
        help="unwrap one frame alone (unwrap_single): stacks of one exposure and modulus images",
    )
    unwrap.add_argument(
        "--bits",
        type=bit_depth,
        default=None,
        help="sensor bit depth (default: from each file's metadata, manifest or sidecar)",
    )
    unwrap.add_argument(
        "--exposure",
        type=positive_float,
        default=None,
        help="with --single: the exposure of modulus images (default: from the metadata, else 1; stacks carry "
        "their own)",
    )
    _add_noise(
        unwrap,
        "multi shot only: the sensor's noise model for noise-aware decoding (default: the model each stack records "
        "in its manifest, as simulate writes it; noise-free where a stack records none)",
    )
    unwrap.add_argument(
        "--spatial",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="multi shot with a noise model: decode with spatial evidence (unwrap_multi's default; a mosaic's "
        "colour planes apart), or each pixel alone (--no-spatial) (default: as each stack records, as simulate "
        "planned it; spatial evidence where it records nothing)",
    )
    unwrap.add_argument(
        "--confidence",
        action="store_true",
        help="with --single: also write OUT/<image>.confidence.exr, unwrap_confidence's map (1: the rollover count "
        "is determined by the image; 0: it was guessed, take a second exposure there; of a mosaic, per colour "
        "plane, one value per photosite); with the learned method (the default; not a mosaic), "
        "learned_confidence's map, from the network's probabilities of the same run (that of its tree, before "
        "any level moves)",
    )
    unwrap.add_argument(
        "--method",
        "--solver",
        action=_MethodOption,
        dest="method",
        default=None,
        metavar="RULE|METHOD",
        help="its meaning depends on --single. Without --single, a multi-shot rule: robust (the default; exact "
        "without noise for ratios up to 2^bits - 1 and integer ratios up to 2^bits, and the one that decodes with a "
        "noise model) or paper (Eq. 6 as printed, noise-free). With --single, a single-shot method of unwrap_single: "
        "learned (the default: the shipped network's rollover jumps, decoded exactly, then its level moves; not on "
        "mosaics), guided (path following, channels together), fast (the paper's graph cut on a cheaper schedule), "
        "paper (Eqs. 3-5 from k = 0, slow) or lsq (DCT least squares), optionally with unwrap_single's options for "
        "it as NAME:KEY=VALUE,... (e.g. learned:levels=False, no level moves, faster; guided:denoise=0.7); "
        "--solver is its deprecated former name (--single only)",
    )
    _add_cfa(
        unwrap,
        f"the colour filter array of mosaicked frames ({', '.join(CFA_PATTERNS)}) where the files do not "
        "record one, e.g. a colour camera's modulus images; a stack or image that records another pattern fails "
        "(default: the pattern each stack or image records; none: not mosaics)",
    )
    unwrap.add_argument(
        "--demosaic",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="demosaic restored mosaics to RGB radiance, (3, H, W) (default: on); --no-demosaic writes the restored "
        "mosaic, (1, H, W), with the pattern in its metadata (scored against the mosaicked truth)",
    )


def _add_tonemap(commands: Any) -> None:
    tonemap = commands.add_parser(
        "tonemap",
        help="radiance files -> display PNGs",
        formatter_class=_Formatter,
        description=_wrap(
            "Tone-map every radiance file in IN (.exr .hdr .pfm .tif .tiff) to OUT/<name>.png with one of the "
            "operators "
            "of torch_modulo.tonemap: histogram (Larson et al. 1997, the paper's choice), reinhard, gamma, log, "
            "clahe. The PNGs are sRGB-encoded for display (see --srgb). Negative values (lossy files) are clamped "
            "to 0; of more than three channels (alpha, other views or layers) the first three are taken as RGB."
        ),
        epilog="examples:\n  torch-modulo tonemap radiance/ png/ --op histogram\n"
        "  torch-modulo tonemap radiance/ png/ --op reinhard --param key=0.36 --depth 16\n"
        + _FOLDER_EPILOG.format(command="tonemap"),
    )
    _add_folder_options(tonemap, "folder of radiance files (or one file)", "folder for the PNGs")
    tonemap.add_argument(
        "--op", choices=TONEMAP_OPS, default="histogram", help="tone-mapping operator (default: histogram)"
    )
    tonemap.add_argument(
        "--param",
        type=param,
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="an operator parameter, repeatable, e.g. key=0.36 (reinhard), gamma=2.4 exposure=1 (gamma), "
        "clip_limit=3 grid_size=8,8 (clahe), ld_max=200 (histogram); see torch_modulo.tonemap",
    )
    tonemap.add_argument(
        "--srgb",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="encode the PNGs for display with the sRGB transfer function (default: on, as the demo's, for every "
        "operator but gamma, whose gamma already encodes them; --no-srgb writes linear display values)",
    )
    tonemap.add_argument("--depth", type=int, choices=(8, 16), default=8, help="PNG bits per sample (default: 8)")
    tonemap.add_argument("--nonfinite", choices=NONFINITE, default="replace", help=_NONFINITE_HELP)


def build_parser() -> argparse.ArgumentParser:
    """The ``torch-modulo`` parser: one subcommand per builder (demo, simulate, unwrap, tonemap, design)."""
    from torch_modulo import __version__

    parser = argparse.ArgumentParser(
        prog="torch-modulo",
        description="Unbounded HDR photography with a modulo camera (Zhao et al., ICCP 2015).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for add in (_add_demo, _add_simulate, _add_unwrap, _add_tonemap, add_design):
        add(commands)
    return parser


# ------------------------------------------------------------------------------------------------ running


def _subparser(parser: argparse.ArgumentParser, command: str) -> argparse.ArgumentParser:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices[command]
    return parser


def _report_clash(report: Path, source: Path, out: Path, tasks: Sequence[Any]) -> str | None:
    """Why ``--report`` may not be written where it points (a folder or OUT itself, the done markers' folder, an
    input, inside the input folder, an output or inside one), or None."""
    from torch_modulo.batch import MARKER_FOLDER
    from torch_modulo.batch.tasks import inside

    path = report.expanduser().resolve()
    if path.is_dir() or path == out:
        return f"--report {report} is a folder; give a file name"
    if inside(path, out / MARKER_FOLDER):
        return f"--report {report} is inside the folder of done markers {out / MARKER_FOLDER}; choose another file"
    if inside(path, source):
        return f"--report {report} is the input or inside the input folder {source}; inputs are never written"
    for task in tasks:
        if path == Path(task.source).resolve():
            return f"--report {report} is the input {task.source}; inputs are never written"
        for output in task.outputs:
            if inside(path, Path(output).resolve()):
                return f"--report {report} would overwrite the output {output}; choose another file"
    return None


def _run_folder_command(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    from torch_modulo import folders, pipeline
    from torch_modulo.batch import BatchError, check_folders, distributed_env, require_ray, run_batch

    sub = _subparser(parser, args.command)
    prog = f"torch-modulo {args.command}"
    try:
        source, out = check_folders(args.input, args.output)
        env = distributed_env()
        if args.engine == "ray":
            require_ray()
    except BatchError as error:
        sub.error(str(error))
    options = JOB_OPTIONS[args.command](args, sub)
    single = getattr(args, "single", False)
    try:
        tasks, wanted = folders.folder_tasks(
            args.command, source, out, single=single, confidence=getattr(args, "confidence", False)
        )
    except OSError as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 1
    if args.report is not None and (clash := _report_clash(Path(args.report), source, out, tasks)):
        sub.error(clash)
    not_radiance: list[dict[str, Any]] = []
    if args.command == "tonemap":  # frames and confidence maps are skipped, and reported
        tasks, not_radiance = folders.radiance_tasks(tasks, out)
    if not tasks:
        also = f" ({len(not_radiance)} files skipped: frames or confidence maps)" if not_radiance else ""
        print(f"{prog}: error: no {wanted} found in {source}{also}", file=sys.stderr)
        return 1
    try:
        report = run_batch(
            args.command,
            tasks,
            pipeline.JOBS[args.command],
            options,
            out,
            input_path=source,
            workers=args.workers,
            engine=args.engine,
            force=args.force,
            progress=args.progress,
            report_path=args.report,
            ray_address=args.ray_address,
            preload=pipeline.PRELOAD[args.command] + (("torch_modulo.singleshot",) if single else ()),
            weigh=folders.count_values,
            merge_timeout=args.merge_timeout,
            skipped=not_radiance,
        )
    except BatchError as error:
        print(f"{prog}: error: {error}", file=sys.stderr)
        return 2
    report_file = Path(args.report) if args.report else out / f"{args.command}-report.json"
    where = ""
    if env.world_size > 1:
        where = f"rank {env.rank}: "
        if report.parts is None:  # this rank's own part (rank 0 holds the merged report under torchrun)
            report_file = report_file.with_name(f"{report_file.stem}.rank{env.rank}{report_file.suffix}")
    if env.rank == 0:
        for entry in not_radiance:
            print(f"{prog}: skipped {entry['input']}: {entry['reason']}", file=sys.stderr)
    print(f"{where}{report.summary()} (report: {report_file})", file=sys.stderr)
    scores = _accuracy_summary(report.done)
    if scores:
        print(f"{where}{prog}: {scores}", file=sys.stderr)
    return report.exit_code


def _accuracy_summary(done: Sequence[dict[str, Any]]) -> str:
    """One line of the mean scores against the stored truth (``unwrap``), or "" when nothing was scored."""
    scored = [entry["accuracy"] for entry in done if entry.get("accuracy")]
    if not scored:
        return ""

    def mean(key: str) -> float:
        return sum(s[key] for s in scored) / len(scored)

    what = f"against the stored truth, mean over {len(scored)} result{'s' * (len(scored) > 1)}:"
    if "exact_k" in scored[0]:
        line = f"{what} exact rollover counts {100 * mean('exact_k'):.2f}%, PSNR {mean('psnr_db'):.1f} dB"
        if all("colour_psnr_db" in s for s in scored):
            line += f", demosaiced colour PSNR {mean('colour_psnr_db'):.1f} dB"
        return line
    return (
        f"{what} median relative error {100 * mean('median_relative_error'):.2f}%, values more than 50% off "
        f"{100 * mean('gross_share'):.3f}%"
    )


def _run_demo(args: argparse.Namespace) -> int:
    from torch_modulo.demo import run_demo

    try:
        run_demo(args.out, args.scene, bits=args.bits, ratio=args.ratio, workers=args.workers, method=args.method)
    except (OSError, ValueError, TypeError) as error:
        print(f"torch-modulo demo: error: {error}", file=sys.stderr)
        return 1
    return 0


#: Options whose value may start with a minus sign (``--exposures -1,16``: refused by name, not by argparse).
_NUMERIC_OPTIONS = (
    "--exposures",
    "--exposure",
    "--scale",
    "--ratio",
    "--bits",
    "--seed",
    "--workers",
    "--stops",
    "--frames",
)


def _values_attached(argv: Sequence[str]) -> list[str]:
    """``argv`` with ``--exposures -1,16`` written ``--exposures=-1,16``: argparse takes a value that starts with
    ``-`` (other than a plain negative number) for an option and fails with "expected one argument"; attached,
    the option's type refuses the value, naming it."""
    out: list[str] = []
    items = list(argv)
    i = 0
    while i < len(items):
        item = items[i]
        following = items[i + 1] if i + 1 < len(items) else ""
        if item in _NUMERIC_OPTIONS and following[:1] == "-" and following[1:2] in set("0123456789."):
            out.append(f"{item}={following}")
            i += 2
            continue
        out.append(item)
        i += 1
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``torch-modulo``; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(_values_attached(sys.argv[1:] if argv is None else argv))
    if args.command == "demo":
        return _run_demo(args)
    if args.command == "design":
        return run_design(args)
    return _run_folder_command(parser, args)


if __name__ == "__main__":
    sys.exit(main())
