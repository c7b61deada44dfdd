"""Tests of the ``torch-modulo`` command line (torch_modulo/cli.py): parsing, options, help, messages and exit
codes. What the folder commands write is tested end to end in test_end_to_end.py."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from cli_scenes import ROOT, write_scenes
from cli_scenes import names as _names
from cli_scenes import read_report as _report
from cli_scenes import run_cli as _cli

from torch_modulo.cli import build_parser, main
from torch_modulo.io import read_metadata, write_image


@pytest.fixture
def scenes(tmp_path: Path) -> Path:
    """IN/ with three scenes: a.exr, b.hdr (RGBE) and sub/c.exr."""
    return write_scenes(tmp_path / "in")


def test_the_jobs_stay_importable_from_the_command_line() -> None:
    import torch_modulo.cli as cli
    from torch_modulo import pipeline

    assert (cli.simulate_job, cli.unwrap_job, cli.tonemap_job) == (
        pipeline.simulate_job,
        pipeline.unwrap_job,
        pipeline.tonemap_job,
    )


# ------------------------------------------------------------------------------------------- usage and help


BAD_OPTIONS = [
    (["simulate", "{in}", "{out}", "--exposures", "1,-2"], "exposures must be finite and > 0"),
    (["simulate", "{in}", "{out}", "--exposures", "1,x"], "exposure 'x' in '1,x' is not a number"),
    (["simulate", "{in}", "{out}", "--exposures", ""], "expected comma-separated exposures"),
    (["simulate", "{in}", "{out}", "--bits", "30"], "expected a bit depth from 1 to 24; got 30"),
    (["simulate", "{in}", "{out}", "--bits", "20", "--format", "png"], "--format png holds at most 16 bits"),
    (["simulate", "{in}", "{out}", "--noise", "loud=3"], "keys q, read, dark, prnu, shot; got 'loud=3'"),
    (["simulate", "{in}", "{out}", "--noise", "read=-1"], "read_noise must be finite and >= 0; got -1.0"),
    (["simulate", "{in}", "{out}", "--scale", "zero"], "expected 'auto' or a number > 0; got 'zero'"),
    (["simulate", "{in}", "{out}", "--workers", "0"], "expected a number >= 1; got 0"),
    (["tonemap", "{in}", "{out}", "--workers", "two"], "expected a whole number; got 'two'"),
    (["tonemap", "{missing}", "{out}"], "input not found"),
    (["tonemap", "{in}", "{in}"], "is the input folder"),
    (["tonemap", "{in}", "{in}/sub/out"], "is inside the input folder"),
    (["tonemap", "{in}", "{out}", "--report", "{in}/report.json"], "is the input or inside the input folder"),
    (["tonemap", "{in}/a.exr", "{out}", "--report", "{in}/a.exr"], "is the input or inside the input folder"),
    (["tonemap", "{in}", "{out}", "--report", "{out}/a.png"], "would overwrite the output"),
    (["simulate", "{in}", "{out}", "--report", "{out}/a/frames.json"], "would overwrite the output"),
    (["tonemap", "{in}", "{out}", "--report", "{in}/.."], "is a folder"),
    (["tonemap", "{in}", "{out}", "--report", "{out}"], "is a folder"),
    (["tonemap", "{in}", "{out}", "--report", "{out}/.torch-modulo/r.json"], "inside the folder of done markers"),
    (["tonemap", "{in}", "{out}", "--op", "drago"], "invalid choice: 'drago'"),
    (["tonemap", "{in}", "{out}", "--op", "reinhard", "--param", "gamma=2"], "has no parameter 'gamma'"),
    (["tonemap", "{in}", "{out}", "--op", "reinhard", "--param", "key=-1"], "key"),
    (["tonemap", "{in}", "{out}", "--param", "oops"], "expected NAME=VALUE"),
    (["tonemap", "{in}", "{out}", "--engine", "spark"], "invalid choice: 'spark'"),
    (["unwrap", "{in}", "{out}", "--exposure", "2"], "--exposure applies to --single only"),
    (["unwrap", "{in}", "{out}", "--method", "magic"], "invalid choice: 'magic'"),
    (["unwrap", "{in}", "{out}", "--solver", "fast"], "--solver applies to --single only"),
    (["unwrap", "{in}", "{out}", "--confidence"], "--confidence applies to --single only"),
    (["unwrap", "{in}", "{out}", "--single", "--solver", "magic"], "--solver must be one of"),
    (["unwrap", "{in}"], "the following arguments are required: OUT"),
    (["unwrap", "{in}", "{out}", "--method", "fast"], "--method fast is a single-shot method: use it with --single"),
    (["unwrap", "{in}", "{out}", "--single", "--method", "learned:levels"], "method options must read key=value"),
    (["unwrap", "{in}", "{out}", "--single", "--method", "magic:levels=False"], "--method must be one of"),
    (
        ["unwrap", "{in}", "{out}", "--single", "--method", "learned:levels=maybe"],
        "bad --method 'learned:levels=maybe'",
    ),
    (["unwrap", "{in}", "{out}", "--single", "--method", "guided:speed=2"], "bad --method 'guided:speed=2'"),
    (["unwrap", "{in}", "{out}", "--single", "--method", "learned:cfa=RGGB"], "cfa is not a method option; use --cfa"),
    (["unwrap", "{in}", "{out}", "--single", "--method", "fast:workers=2"], "workers is not a method option"),
    (["unwrap", "{in}", "{out}", "--method", "learned:levels=False"], "is a single-shot method: use it with --single"),
    (["unwrap", "{in}", "{out}", "--single", "--method", "robust"], "--method must be one of"),
    (["tonemap", "{in}", "{out}", "--nonfinite", "zero"], "invalid choice: 'zero'"),
    (["simulate", "{in}", "{out}", "--merge-timeout", "0"], "expected a finite number > 0; got '0'"),
    (["simulate", "{in}", "{out}", "--noise", "loud"], "a preset (photon-counting, q16, dfpa)"),
    (["simulate", "{in}", "{out}", "--noise", "q16,q=0"], "electrons_per_count must be > 0"),
    (["simulate", "{in}", "{out}", "--exposures", "auto,2"], "exposure 'auto' in 'auto,2' is not a number"),
    (["unwrap", "{in}", "{out}", "--method", "paper", "--noise", "q16"], "--method paper decodes Eqs. 6-7 as printed"),
    (["unwrap", "{in}", "{out}", "--single", "--noise", "q16"], "--noise applies to multi shot only"),
    (["tonemap", "{in}", "{out}", "--srgb", "--no-srgb", "--depth", "12"], "invalid choice: 12"),
    (["simulate", "{in}", "{out}", "--cfa", "RGBG"], "argument --cfa: invalid choice: 'RGBG'"),
    (["unwrap", "{in}", "{out}", "--cfa", "rgbg"], "argument --cfa: invalid choice: 'RGBG'"),
    (["simulate", "{in}", "{out}", "--exposures", "-1,16,256"], "got '-1' in '-1,16,256'"),
    (["simulate", "{in}", "{out}", "--exposures", "-1"], "got '-1' in '-1'"),
    (["simulate", "{in}", "{out}", "--exposures", "1,1,16"], "exposure 1 appears twice in '1,1,16'"),
    (["simulate", "{in}", "{out}", "--bits", "0"], "expected a bit depth from 1 to 24; got 0"),
    (
        ["simulate", "{in}", "{out}", "--exposures", "1,1000,1000000"],
        "exposures 1 and 1000 are 1000 times apart, more than 2^8 = 256",
    ),
]


class TestUsage:
    @pytest.mark.parametrize(("argv", "message"), BAD_OPTIONS, ids=[" ".join(a[3:] or a[:2]) for a, _ in BAD_OPTIONS])
    def test_bad_options_are_usage_errors(
        self, argv: list[str], message: str, scenes: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
    ) -> None:
        paths = {"in": str(scenes), "out": str(tmp_path / "out"), "missing": str(tmp_path / "missing")}
        with pytest.raises(SystemExit) as exit_info:
            main([a.format(**paths) for a in argv])
        err = capsys.readouterr().err
        assert exit_info.value.code == 2
        assert f"usage: torch-modulo {argv[0]}" in err and "error:" in err and message in err
        assert "Traceback" not in err
        assert not (tmp_path / "out").exists()  # nothing was started

    def test_missing_ray_is_a_usage_error(
        self, scenes: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
    ) -> None:
        monkeypatch.setitem(sys.modules, "ray", None)
        with pytest.raises(SystemExit) as exit_info:
            main(["tonemap", str(scenes), str(tmp_path / "out"), "--engine", "ray"])
        assert exit_info.value.code == 2
        assert "pip install 'torch_modulo[ray]'" in capsys.readouterr().err

    def test_usage_error_from_the_installed_command(self, tmp_path: Path) -> None:
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "torch_modulo",
                "simulate",
                str(tmp_path),
                str(tmp_path / "o"),
                "--exposures",
                "1,0",
            ],
            capture_output=True,
            text=True,
            cwd=ROOT,
            timeout=120,
        )
        assert result.returncode == 2
        assert "exposures must be finite and > 0" in result.stderr and "Traceback" not in result.stderr

    @pytest.mark.parametrize("command", ["demo", "simulate", "unwrap", "tonemap"])
    def test_help_explains_every_option_with_an_example(self, command: str, capsys: pytest.CaptureFixture[str]) -> None:
        with pytest.raises(SystemExit) as exit_info:
            main([command, "--help"])
        assert exit_info.value.code == 0
        text = capsys.readouterr().out
        assert "example" in text and f"torch-modulo {command}" in text
        sub = build_parser()._subparsers._group_actions[0].choices[command]  # type: ignore[union-attr]
        for action in sub._actions:
            assert action.help, f"{command}: {action.dest} has no help"
            for option in action.option_strings:
                assert option in text

    def test_version(self, capsys: pytest.CaptureFixture[str]) -> None:
        import torch_modulo

        with pytest.raises(SystemExit) as exit_info:
            main(["--version"])
        assert exit_info.value.code == 0
        assert capsys.readouterr().out.strip() == f"torch-modulo {torch_modulo.__version__}"

    def test_demo_options_are_unchanged(self) -> None:
        args = build_parser().parse_args(["demo"])
        assert (args.out, args.scene, args.bits, args.ratio, args.workers) == ("demo_out", None, 8, 64.0, None)
        args = build_parser().parse_args(
            ["demo", "--out", "x", "--scene", "s.exr", "--bits", "10", "--ratio", "16", "--workers", "2"]
        )
        assert (args.out, args.scene, args.bits, args.ratio, args.workers) == ("x", "s.exr", 10, 16.0, 2)


# ------------------------------------------------------------------------------------------ messages and codes


def test_values_that_look_like_options_and_any_case() -> None:
    # Regression: --exposures -1,16,256 failed with argparse's "expected one argument", --cfa rggb was refused.
    parser = build_parser()
    assert parser.parse_args(["simulate", "i", "o", "--cfa", "rggb"]).cfa == "RGGB"
    assert parser.parse_args(["unwrap", "i", "o", "--cfa", "gBrG"]).cfa == "GBRG"
    from torch_modulo.cli import _values_attached

    argv = ["simulate", "i", "o", "--exposures", "-1,16", "--seed", "2", "--scale", "-2"]
    assert _values_attached(argv) == ["simulate", "i", "o", "--exposures=-1,16", "--seed", "2", "--scale=-2"]
    assert _values_attached(["simulate", "i", "o", "--exposures", "--noise"]) == [
        "simulate",
        "i",
        "o",
        "--exposures",
        "--noise",
    ]


class TestMessages:
    def test_no_inputs(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        (tmp_path / "empty").mkdir()
        assert _cli("unwrap", tmp_path / "empty", tmp_path / "out") == 1
        assert "no frame stacks (folders with a frames.json manifest) found in" in capsys.readouterr().err

    def test_an_output_folder_that_cannot_be_made_is_a_clear_error(
        self, scenes: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
    ) -> None:
        (tmp_path / "afile").write_text("x")
        assert _cli("tonemap", scenes, tmp_path / "afile" / "out") == 2
        err = capsys.readouterr().err
        assert "cannot create the output folder" in err and "Traceback" not in err

    def test_solver_is_a_deprecated_alias_of_method(self, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
        (tmp_path / "in").mkdir()
        counts = torch.floor(torch.linspace(0, 900, 24).view(1, 1, 24).expand(1, 10, 24)).contiguous()
        write_image(tmp_path / "in" / "ramp.png", torch.remainder(counts, 256), {"bits": 8})
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out", "--single", "--method", "fast") == 0
        assert "--solver is deprecated" not in capsys.readouterr().err
        assert read_metadata(tmp_path / "out" / "ramp.exr")["solver"] == "fast"
        # the old spelling is the same option: the rerun skips the image, and says to use --method
        assert _cli("unwrap", tmp_path / "in", tmp_path / "out", "--single", "--solver", "fast") == 0
        assert "torch-modulo unwrap: warning: --solver is deprecated; use --method" in capsys.readouterr().err
        assert _names(_report(tmp_path / "out", "unwrap")["skipped"]) == ["ramp.png"]
        args = build_parser().parse_args(["demo", "--solver", "paper"])
        assert args.method == "paper"
        assert "torch-modulo demo: warning: --solver is deprecated; use --method" in capsys.readouterr().err


def _option_help(command: str, dest: str) -> str:
    from torch_modulo.cli import _subparser

    (action,) = [a for a in _subparser(build_parser(), command)._actions if a.dest == dest]
    return str(action.help)


class TestHelpSaysWhatItMeans:
    def test_noise_help_names_each_preset_once(self) -> None:
        # Regression: the --noise help listed photon-counting three times.
        for command in ("simulate", "unwrap"):
            text = _option_help(command, "noise")
            assert text.count("photon-counting") == 1 and "dfpa" in text and "q16 (16 e-" in text, text

    def test_unwrap_noise_help_gives_the_real_default(self) -> None:
        # Regression: unwrap's help said "default (photon-counting)" while its default is each stack's own model.
        text = _option_help("unwrap", "noise")
        assert "default (photon-counting)" not in text and "the model each stack records" in text

    def test_unwrap_method_help_says_what_it_means_in_each_case(self) -> None:
        # Regression: --method is a multi-shot rule or a single-shot method depending on --single; say so per case.
        text = _option_help("unwrap", "method").lower()
        multi, single = text.index("without --single, a multi-shot rule:"), text.index("with --single, a single-shot")
        assert multi < text.index("robust") < single < text.index("learned")


def test_a_repeated_longest_exposure_is_simulated_and_decoded(tmp_path: Path) -> None:
    # Under noise the longest exposure's repeats collect light (plan_exposures(..., longest_frames=2)); the stack
    # keeps both frames and unwrap decodes it.
    source = tmp_path / "in"
    source.mkdir()
    write_image(source / "a.exr", torch.exp2(torch.linspace(0.0, 10.0, 96)).view(1, 8, 12).expand(3, -1, -1))
    stacks, out = tmp_path / "stacks", tmp_path / "out"
    assert _cli("simulate", source, stacks, "--noise", "q16", "--exposures", "0.05,0.5,1,1") == 0
    assert _report(stacks, "simulate")["options"]["exposures"] == [0.05, 0.5, 1.0, 1.0]
    assert len(list((stacks / "a").glob("frame_*"))) == 4
    assert _cli("unwrap", stacks, out) == 0
    (done,) = _report(out, "unwrap")["done"]
    assert done["noise"] == "q16" and done["accuracy"]["gross_share"] == 0.0


def test_auto_plans_take_the_longest_exposure_as_often_as_asked(tmp_path: Path) -> None:
    source = tmp_path / "in"
    source.mkdir()
    write_image(source / "a.exr", torch.exp2(torch.linspace(0.0, 10.0, 96)).view(1, 8, 12).expand(3, -1, -1))
    once, twice = tmp_path / "once", tmp_path / "twice"
    assert _cli("simulate", source, once, "--noise", "q16", "--spatial") == 0
    assert _cli("simulate", source, twice, "--noise", "q16", "--spatial", "--longest-frames", "2") == 0
    plan = json.loads((once / "a" / "frames.json").read_text())["exposures"]
    repeated = json.loads((twice / "a" / "frames.json").read_text())["exposures"]
    assert repeated == plan + [plan[-1]]
