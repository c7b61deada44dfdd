"""Tests of torch_modulo/_cli_options.py: the option types of the command line (what each option's text becomes)
and the job options built from parsed arguments. Bad values and combinations, as the command line reports them,
are tested in test_cli.py."""

from __future__ import annotations

import argparse

import pytest

from torch_modulo._cli_options import JOB_OPTIONS, bit_depth, exposures, noise, param, scale
from torch_modulo.cli import build_parser
from torch_modulo.noise import NoiseModel


@pytest.mark.parametrize(
    ("value", "expected"),
    [
        ("photon-counting", NoiseModel.preset("photon-counting")),
        ("q16", NoiseModel.preset("q16")),
        ("dfpa", NoiseModel.preset("dfpa")),
        ("default", NoiseModel()),
        ("read=2,prnu=0.01", NoiseModel(read_noise=2.0, prnu=0.01)),
        ("q16,read=20", NoiseModel(electrons_per_count=16.0, read_noise=20.0)),
        ("shot=off", NoiseModel(shot_noise=False)),
        ("none", None),
    ],
)
def test_noise_values(value: str, expected: NoiseModel | None) -> None:
    assert noise(value) == ("none" if expected is None else expected.to_dict())
    parsed = build_parser().parse_args(["simulate", "i", "o", "--noise", value]).noise
    assert parsed == noise(value)


def test_values_of_the_other_types() -> None:
    assert exposures(" auto ") == "auto" and exposures("1, 16,256") == [1.0, 16.0, 256.0]
    assert scale("auto") == "auto" and scale("2.5") == 2.5
    assert param("grid_size=8,8") == ("grid_size", [8, 8])
    assert (
        param("key=0.36") == ("key", 0.36) and param("srgb=True") == ("srgb", True) and param("x=none") == ("x", None)
    )
    with pytest.raises(argparse.ArgumentTypeError, match="exposures must be finite and > 0; got 'inf'"):
        exposures("1,inf")


def test_job_options_keep_defaults_out_of_the_fingerprint(capsys: pytest.CaptureFixture[str]) -> None:
    """Options at their defaults are left out, so outputs completed before the option existed stay complete."""
    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    args = parser.parse_args(["tonemap", "i", "o"])
    assert JOB_OPTIONS["tonemap"](args, commands["tonemap"]) == {
        "op": "histogram",
        "params": {},
        "srgb": True,
        "depth": 8,
    }
    args = parser.parse_args(["simulate", "i", "o", "--nonfinite", "raise", "--cfa", "RGGB", "--noise", "none"])
    options = JOB_OPTIONS["simulate"](args, commands["simulate"])
    assert options["nonfinite"] == "raise" and options["cfa"] == "RGGB" and options["noise"] is None
    assert capsys.readouterr().err == ""
    args = parser.parse_args(["simulate", "i", "o", "--exposures", "1,1000", "--force-exposures"])
    options = JOB_OPTIONS["simulate"](args, commands["simulate"])
    assert "nonfinite" not in options and options["force_exposures"] is True
    assert capsys.readouterr().err == (
        "torch-modulo simulate: warning: exposures 1 and 1000 are 1000 times apart, more than 2^8 = 256: "
        "`torch-modulo unwrap` cannot count the rollovers between them (--force-exposures writes them anyway)\n"
    )
    args = parser.parse_args(["simulate", "i", "o", "--exposures", "1,256"])
    assert "force_exposures" not in JOB_OPTIONS["simulate"](args, commands["simulate"])
    args = parser.parse_args(["unwrap", "i", "o", "--workers", "1"])
    options = JOB_OPTIONS["unwrap"](args, commands["unwrap"])
    assert options == {
        "single": False,
        "bits": None,
        "exposure": None,
        "method": "robust",
        "noise": "stack",
        "solver": None,
        "confidence": False,
        "_solver_workers": None,
        "spatial": None,  # as each stack records: with spatial evidence where it records nothing, since 2026-12-07
    }


def test_duplicate_exposures_are_refused_by_name() -> None:
    # Regression: 1,1,16 was accepted silently (two frames of one exposure add nothing to rollover counting).
    with pytest.raises(argparse.ArgumentTypeError, match=r"exposure 1 appears twice in '1,1.0,16'"):
        exposures("1,1.0,16")
    with pytest.raises(argparse.ArgumentTypeError, match=r"exposure 16 appears twice in '16,1,16,256'"):
        exposures("16,1,16,256")


def test_the_longest_exposure_may_repeat() -> None:
    # Under noise its repeats collect light (plan_exposures(..., longest_frames=L)).
    assert exposures("1,16,256,256") == [1.0, 16.0, 256.0, 256.0]


@pytest.mark.parametrize("text", ["0", "25", "-3"])
def test_bit_depths_out_of_range_get_one_message(text: str) -> None:
    # Regression: --bits 0 said "expected a number >= 1", --bits 25 "expected a bit depth from 1 to 24".
    with pytest.raises(argparse.ArgumentTypeError, match=rf"^expected a bit depth from 1 to 24; got {text}$"):
        bit_depth(text)


def test_crop_and_max_side_values() -> None:
    from torch_modulo._cli_options import crop_size

    assert crop_size("256") == [256, 256] and crop_size("128,256") == [128, 256] and crop_size("128x256") == [128, 256]
    for bad in ("0", "1,2,3", "a", "-4"):
        with pytest.raises(argparse.ArgumentTypeError, match=f"expected a crop size H,W or N .*; got {bad!r}"):
            crop_size(bad)


def test_longest_frames_option(capsys: pytest.CaptureFixture[str]) -> None:
    """``--longest-frames`` joins the options only when given, and only with auto exposures."""
    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    args = parser.parse_args(["simulate", "i", "o", "--longest-frames", "2"])
    assert JOB_OPTIONS["simulate"](args, commands["simulate"])["longest_frames"] == 2
    args = parser.parse_args(["simulate", "i", "o", "--longest-frames", "1"])
    assert "longest_frames" not in JOB_OPTIONS["simulate"](args, commands["simulate"])
    args = parser.parse_args(["simulate", "i", "o", "--exposures", "1,16", "--longest-frames", "2"])
    with pytest.raises(SystemExit):
        JOB_OPTIONS["simulate"](args, commands["simulate"])
    assert "--longest-frames applies to --exposures auto" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        parser.parse_args(["simulate", "i", "o", "--longest-frames", "0"])


def test_spatial_options(capsys: pytest.CaptureFixture[str]) -> None:
    """``--spatial`` joins the options only when given; it needs a noise model, and multi shot for unwrap."""
    parser = build_parser()
    commands = parser._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    args = parser.parse_args(["simulate", "i", "o", "--noise", "q16", "--spatial"])
    assert JOB_OPTIONS["simulate"](args, commands["simulate"])["spatial"] is True
    # noisy multi-shot runs always say which plan: stacks planned per pixel before it was the default are redone
    assert JOB_OPTIONS["simulate"](parser.parse_args(["simulate", "i", "o"]), commands["simulate"])["spatial"] is True
    for quiet in (["--noise", "none"], ["--exposures", "1"]):  # no noise, or single shot: nothing changed
        assert "spatial" not in JOB_OPTIONS["simulate"](
            parser.parse_args(["simulate", "i", "o", *quiet]), commands["simulate"]
        )
    assert JOB_OPTIONS["unwrap"](parser.parse_args(["unwrap", "i", "o"]), commands["unwrap"])["spatial"] is None
    assert "spatial" not in JOB_OPTIONS["unwrap"](
        parser.parse_args(["unwrap", "i", "o", "--single"]), commands["unwrap"]
    )
    alone = parser.parse_args(["simulate", "i", "o", "--noise", "none", "--no-spatial"])  # no noise: nothing to refuse
    assert JOB_OPTIONS["simulate"](alone, commands["simulate"])["spatial"] is False
    for flag, value in (("--spatial", True), ("--no-spatial", False)):
        args = parser.parse_args(["unwrap", "i", "o", flag])
        assert JOB_OPTIONS["unwrap"](args, commands["unwrap"])["spatial"] is value
    refused = (
        (["simulate", "i", "o", "--noise", "none", "--spatial"], "it needs a noise model"),
        (["unwrap", "i", "o", "--single", "--no-spatial"], "apply to multi shot only"),
        (["unwrap", "i", "o", "--noise", "none", "--spatial"], "it needs a noise model"),
        (["unwrap", "i", "o", "--method", "paper", "--spatial"], "got --method paper"),
        (["simulate", "i", "o", "--exposures", "4", "--spatial"], "got one exposure, --exposures 4"),
    )
    for argv, message in refused:
        args = parser.parse_args(argv)
        with pytest.raises(SystemExit):
            JOB_OPTIONS[argv[0]](args, commands[argv[0]])
        assert message in capsys.readouterr().err
