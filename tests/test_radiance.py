"""Tests of torch_modulo/radiance.py: load_radiance, one policy for values a radiance map cannot hold, shared by
every reader of radiance files."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from torch_modulo import radiance
from torch_modulo.io import read_image, write_image
from torch_modulo.radiance import load_radiance

NAN, INF = float("nan"), float("inf")


def _write(path: Path, image: torch.Tensor) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_image(path, image)
    return path


class TestLoadRadiance:
    def test_smoke(self, tmp_path: Path) -> None:
        image = torch.rand(3, 5, 7) * 100
        loaded = load_radiance(_write(tmp_path / "x.exr", image))
        assert loaded.shape == (3, 5, 7) and loaded.dtype == torch.float32
        assert torch.equal(loaded, read_image(tmp_path / "x.exr"))
        assert load_radiance(tmp_path / "x.exr", dtype=torch.float64).dtype == torch.float64

    def test_nonfinite_values_are_replaced_by_default(self, tmp_path: Path) -> None:
        image = torch.tensor([[[1.0, -2.0], [NAN, 5.0]], [[INF, 3.0], [-INF, 0.25]]])
        loaded, counts = load_radiance(_write(tmp_path / "x.exr", image), channels=None, with_counts=True)
        assert loaded.tolist() == [[[1.0, 0.0], [0.0, 5.0]], [[5.0, 3.0], [0.0, 0.25]]]
        assert counts == {"nan": 1, "posinf": 1, "neginf": 1, "negative": 1}

    def test_nonfinite_raise_names_the_file_and_the_counts(self, tmp_path: Path) -> None:
        path = _write(tmp_path / "x.exr", torch.tensor([[[1.0, NAN], [INF, INF]]]))
        with pytest.raises(ValueError) as info:
            load_radiance(path, nonfinite="raise")
        assert str(info.value).startswith(f"{path} holds 3 NaN or infinite values (1 NaN, 2 +Inf, 0 -Inf); ")
        assert "nonfinite='replace'" in str(info.value)

    @pytest.mark.parametrize("nonfinite", ["replace", "raise"])
    def test_a_file_without_a_finite_value_is_refused(self, tmp_path: Path, nonfinite: str) -> None:
        path = _write(tmp_path / "x.exr", torch.full((3, 2, 2), NAN))
        with pytest.raises(ValueError, match=r"x\.exr holds no finite value \(12 NaN, 0 \+Inf, 0 -Inf\)"):
            load_radiance(path, nonfinite=nonfinite)

    def test_negatives_are_clamped_even_with_raise(self, tmp_path: Path) -> None:
        path = _write(tmp_path / "x.exr", torch.tensor([[[-0.01, 2.0]]]))
        assert load_radiance(path, nonfinite="raise").tolist() == [[[0.0, 2.0]]]

    def test_a_nan_in_a_dropped_channel_does_not_count(self, tmp_path: Path) -> None:
        rgba = torch.ones(4, 2, 2)
        rgba[3, 0, 0] = NAN
        path = _write(tmp_path / "x.exr", rgba)
        assert torch.equal(load_radiance(path, nonfinite="raise"), torch.ones(3, 2, 2))
        with pytest.raises(ValueError, match="1 NaN"):
            load_radiance(path, channels=None, nonfinite="raise")

    @pytest.mark.parametrize(
        ("stored", "channels", "expected"),
        [(1, "auto", 1), (2, "auto", 1), (3, "auto", 3), (4, "auto", 3), (9, "auto", 3)]
        + [(1, 3, 3), (2, 3, 3), (4, 3, 3), (1, 1, 1), (2, 1, 1), (4, 1, 1), (2, None, 2), (4, None, 4)],
    )
    def test_channels(self, tmp_path: Path, stored: int, channels: int | str | None, expected: int) -> None:
        image = torch.rand(stored, 3, 4) * 10
        loaded = load_radiance(_write(tmp_path / "x.exr", image), channels=channels)
        assert loaded.shape == (expected, 3, 4)
        if channels == 3 and stored < 3:
            assert torch.equal(loaded, image[:1].expand(3, -1, -1))
        elif channels == 1 and stored >= 3:
            luminance = 0.2126 * image[0] + 0.7152 * image[1] + 0.0722 * image[2]
            torch.testing.assert_close(loaded[0], luminance)
        else:
            assert torch.equal(loaded, image[:expected])

    def test_errors(self, tmp_path: Path) -> None:
        path = _write(tmp_path / "x.exr", torch.ones(1, 2, 2))
        with pytest.raises(ValueError, match="nonfinite must be one of 'raise', 'replace'; got 'zero'"):
            load_radiance(path, nonfinite="zero")
        with pytest.raises(ValueError, match="channels must be 1, 3, 'auto' or None; got 2"):
            load_radiance(path, channels=2)
        with pytest.raises(TypeError, match="with_counts must be .*; got 'no'"):
            load_radiance(path, with_counts="no")  # type: ignore[arg-type]
        with pytest.raises(FileNotFoundError, match="missing"):
            load_radiance(tmp_path / "missing.exr")
        (tmp_path / "broken.exr").write_bytes(b"not an image")
        with pytest.raises(OSError, match=r"broken\.exr"):
            load_radiance(tmp_path / "broken.exr")

    def test_input_file_is_not_modified(self, tmp_path: Path) -> None:
        path = _write(tmp_path / "x.exr", torch.tensor([[[NAN, -1.0, 2.0]]]))
        before = path.read_bytes()
        load_radiance(path)
        assert path.read_bytes() == before


def test_every_radiance_reader_shares_load_radiance() -> None:
    """The command line, the jobs, the Dataset and the demo read radiance through load_radiance only."""
    root = Path(radiance.__file__).parent
    for name in ("cli.py", "_cli_options.py", "pipeline.py", "data.py", "demo.py"):
        text = (root / name).read_text()
        assert "nan_to_num" not in text and "torch.isfinite" not in text, name
    for name in ("pipeline.py", "data.py", "demo.py"):
        assert "from torch_modulo.radiance import" in (root / name).read_text(), name


class TestDisplayReferredFiles:
    """8/16-bit PNG and TIFF hold display-referred (sRGB-encoded) values, not radiance (regression: simulate took a
    PNG's 0-255 values as linear radiance and reported it done)."""

    @pytest.mark.parametrize("name, kind", [("photo.png", "uint8"), ("photo.tif", "uint16"), ("photo.png", "uint16")])
    def test_integer_files_are_refused_unless_linear(self, tmp_path: Path, name: str, kind: str) -> None:
        path = tmp_path / name
        write_image(path, torch.tensor([[[0.0, 7.0], [100.0, 255.0]]]), dtype=kind)
        bits = kind.removeprefix("uint")
        with pytest.raises(ValueError, match=rf"{name} holds {bits}-bit integers, display-referred.*linear=True"):
            load_radiance(path, linear=False)
        assert load_radiance(path, linear=True).tolist() == [[[0.0, 7.0], [100.0, 255.0]]]
        assert torch.equal(load_radiance(path), load_radiance(path, linear=True))  # no opinion: read as stored
        assert radiance.display_referred(path) == f"{bits}-bit integers"

    def test_float_files_are_radiance(self, tmp_path: Path) -> None:
        path = _write(tmp_path / "x.exr", torch.ones(1, 2, 2))
        assert radiance.display_referred(path) is None
        assert load_radiance(path, linear=False).shape == (1, 2, 2)

    def test_linear_must_be_a_flag(self, tmp_path: Path) -> None:
        with pytest.raises(TypeError, match="linear must be a bool or None"):
            load_radiance(_write(tmp_path / "x.exr", torch.ones(1, 2, 2)), linear="yes")  # type: ignore[arg-type]
