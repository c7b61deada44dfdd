"""Tests for torch_modulo.io: round trips, orientation, metadata and errors for every writable format."""

from __future__ import annotations

import json
import os
import re
import struct
import warnings
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
import torch

from torch_modulo import io as tmio
from torch_modulo.io import read_image, read_metadata, write_image


def _ramp(c: int, h: int, w: int, scale: float = 1.0) -> torch.Tensor:
    """A non-symmetric image: every value different, so flips, transposes and channel swaps show."""
    return torch.arange(c * h * w, dtype=torch.float32).reshape(c, h, w) * scale


def re_shape(shape: tuple[int, ...]) -> str:
    return re.escape(str(tuple(shape)))


def _listing(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# Format, dtype, channel counts, and a generator of exactly storable values.
EXACT_CASES = [
    ("exr", "float", (1, 2, 3, 4, 7, 12)),
    ("exr", "half", (1, 3)),
    ("pfm", "float", (1, 3)),
    ("png", "uint8", (1, 2, 3, 4)),
    ("png", "uint16", (1, 2, 3, 4)),
    ("tif", "uint8", (1, 3, 4, 5)),
    ("tiff", "uint16", (1, 3)),
    ("tif", "float", (1, 3)),
]


def _values(dtype: str, shape: tuple[int, int, int], seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    if dtype == "uint8":
        return torch.randint(0, 256, shape, generator=g).float()
    if dtype == "uint16":
        return torch.randint(0, 65536, shape, generator=g).float()
    if dtype == "half":  # values half holds exactly: integers below 2048 and eighths below 256
        return torch.randint(-2048, 2048, shape, generator=g).float() / 8.0
    return torch.randn(shape, generator=g) * 1000.0


class TestRoundTrip:
    @pytest.mark.parametrize("ext, kind, channels", EXACT_CASES)
    def test_exact(self, tmp_path: Path, ext: str, kind: str, channels: tuple[int, ...]) -> None:
        for c in channels:
            image = _values(kind, (c, 5, 7), seed=c)
            path = write_image(tmp_path / f"img{c}.{ext}", image, dtype=kind)
            back = read_image(path)
            assert back.dtype == torch.float32
            assert back.shape == (c, 5, 7)
            assert torch.equal(back, image), (ext, kind, c)

    @pytest.mark.parametrize(
        "ext, kind",
        [
            ("exr", "float"),
            ("exr", "half"),
            ("hdr", "float"),
            ("pfm", "float"),
            ("png", "uint16"),
            ("tif", "uint16"),
            ("png", "uint8"),
        ],
    )
    def test_orientation(self, tmp_path: Path, ext: str, kind: str) -> None:
        c = 3
        image = _ramp(c, 4, 6)  # values 0..71: fit uint8, half and RGBE (small integers are exact in RGBE too)
        path = write_image(tmp_path / f"ramp.{ext}", image, dtype=kind)
        back = read_image(path)
        if ext == "hdr":
            assert torch.allclose(back, image, rtol=2**-7, atol=0.5)
            # the brightest pixel is the bottom-right one, whatever the rounding
            assert int(back[0].argmax()) == 4 * 6 - 1
        else:
            assert torch.equal(back, image)

    def test_grey_2d_input(self, tmp_path: Path) -> None:
        image = _ramp(1, 3, 4)[0]
        back = read_image(write_image(tmp_path / "g.exr", image))
        assert back.shape == (1, 3, 4)
        assert torch.equal(back[0], image)

    def test_half_rounds(self, tmp_path: Path) -> None:
        image = torch.tensor([[[0.1, 1000.3, 3.0e4]]])
        back = read_image(write_image(tmp_path / "h.exr", image, dtype="half"))
        assert torch.equal(back, image.half().float())
        assert not torch.equal(back, image)  # it really was stored as half

    def test_exr_keeps_nan_inf(self, tmp_path: Path) -> None:
        image = torch.tensor([[[float("nan"), float("inf"), -float("inf"), -2.5]]])
        back = read_image(write_image(tmp_path / "n.exr", image))
        assert torch.isnan(back[0, 0, 0])
        assert torch.equal(back[..., 1:], image[..., 1:])

    def test_hdr_precision(self, tmp_path: Path) -> None:
        g = torch.Generator().manual_seed(1)
        image = torch.exp(torch.randn(3, 8, 9, generator=g) * 4)  # 20+ stops of range
        back = read_image(write_image(tmp_path / "r.hdr", image))
        # RGBE: one shared exponent, 8-bit mantissas: error below 2^-8 of the largest channel of the pixel
        peak = image.amax(dim=0, keepdim=True)
        assert bool(((back - image).abs() <= peak * 2**-7).all())
        top = image.argmax(dim=0, keepdim=True)  # the largest channel keeps 8 significant bits
        assert torch.allclose(back.gather(0, top), peak, rtol=2**-7, atol=0)
        assert bool((back >= 0).all())

    @pytest.mark.parametrize("ext", ["png", "tif"])
    def test_modulus_16bit_raw_integers(self, tmp_path: Path, ext: str) -> None:
        bits = 12
        g = torch.Generator().manual_seed(3)
        modulus = torch.randint(0, 2**bits, (3, 6, 5), generator=g).float()
        path = write_image(tmp_path / f"m.{ext}", modulus, {"bits": bits})  # default: 16-bit for 12-bit data
        spec = oiio.ImageInput.open(str(path)).spec()
        assert spec.format == "uint16"
        assert torch.equal(read_image(path), modulus)
        assert torch.allclose(read_image(path, normalized=True), modulus / 65535)

    def test_narrow_tiff_reads_stored_integers(self, tmp_path: Path) -> None:
        """A 12-bit TIFF (as 12-bit cameras write) reads as its 12-bit integers, not stretched to 16 bits."""
        tifffile = pytest.importorskip("tifffile")
        values = np.array([0, 1, 2, 100, 2049, 4095], np.uint16)
        path = tmp_path / "c12.tif"
        spec = oiio.ImageSpec(6, 1, 1, "uint16")
        spec.attribute("oiio:BitsPerSample", 12)
        out = oiio.ImageOutput.create(str(path))
        out.open(str(path), spec)
        out.write_image(np.ascontiguousarray((values << 4).reshape(1, 6, 1)))  # OpenImageIO takes 16-bit range
        out.close()
        with tifffile.TiffFile(path) as tif:
            assert tif.pages[0].bitspersample == 12
        assert read_image(path).flatten().tolist() == values.tolist()
        assert torch.allclose(read_image(path, normalized=True).flatten(), torch.from_numpy(values / 4095.0).float())

    def test_default_integer_dtype_is_uint8(self, tmp_path: Path) -> None:
        path = write_image(tmp_path / "m.png", torch.full((1, 2, 2), 200.0))
        inp = oiio.ImageInput.open(str(path))
        assert inp.spec().format == "uint8"
        inp.close()
        with pytest.raises(ValueError, match=r"max 300.0.*uint16"):
            write_image(tmp_path / "m2.png", torch.full((1, 2, 2), 300.0))

    def test_normalized_display_png(self, tmp_path: Path) -> None:
        display = torch.linspace(0, 1, 12).reshape(3, 2, 2)
        path = write_image(tmp_path / "d.png", display, normalized=True)
        raw = read_image(path)
        assert torch.equal(raw, torch.round(display * 255))
        back = read_image(path, normalized=True)
        assert float((back - display).abs().max()) <= 0.5 / 255 + 1e-7
        path16 = write_image(tmp_path / "d16.png", display, normalized=True, dtype="uint16")
        assert float((read_image(path16, normalized=True) - display).abs().max()) <= 0.5 / 65535 + 1e-7

    def test_float64_read(self, tmp_path: Path) -> None:
        image = _values("uint16", (1, 3, 3))
        back = read_image(write_image(tmp_path / "m.png", image, dtype="uint16"), dtype=torch.float64)
        assert back.dtype == torch.float64
        assert torch.equal(back, image.double())

    @pytest.mark.parametrize("in_dtype", [torch.uint8, torch.int32, torch.int64, torch.float64, torch.float16])
    def test_input_dtypes(self, tmp_path: Path, in_dtype: torch.dtype) -> None:
        image = torch.arange(12).reshape(1, 3, 4).to(in_dtype)
        back = read_image(write_image(tmp_path / "m.tif", image, dtype="uint16"))
        assert torch.equal(back, image.float())

    def test_input_unmodified(self, tmp_path: Path) -> None:
        image = _ramp(3, 4, 5) / 59
        copy = image.clone()
        write_image(tmp_path / "a.png", image, normalized=True)
        write_image(tmp_path / "a.exr", image, dtype="half")
        assert torch.equal(image, copy)

    def test_independent_readers(self, tmp_path: Path) -> None:
        """Another library reads our PNG and TIFF with the same values and the same row 0."""
        pil = pytest.importorskip("PIL.Image")
        tifffile = pytest.importorskip("tifffile")
        image = _ramp(3, 4, 5) * 100  # up to 5900: 16-bit
        write_image(tmp_path / "a.png", image, dtype="uint16")
        write_image(tmp_path / "a.tif", image, dtype="uint16")
        grey = _ramp(1, 4, 5) * 1000  # up to 19000: 16-bit grey, which Pillow reads without conversion
        write_image(tmp_path / "g.png", grey, dtype="uint16")
        colour8 = _ramp(3, 4, 5)
        write_image(tmp_path / "c.png", colour8, dtype="uint8")
        expected = image.permute(1, 2, 0).numpy().astype(np.uint16)
        assert np.array_equal(tifffile.imread(tmp_path / "a.tif"), expected)
        assert np.array_equal(np.asarray(pil.open(tmp_path / "g.png")), grey[0].numpy().astype(np.uint16))
        assert np.array_equal(np.asarray(pil.open(tmp_path / "c.png")), colour8.permute(1, 2, 0).numpy())


class TestPFM:
    def test_reads_known_file_right_way_up(self, tmp_path: Path) -> None:
        # PFM stores rows bottom to top: the file's first row is the image's bottom row.
        path = tmp_path / "known.pfm"
        rows_bottom_first = [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]  # width 3, height 2
        payload = struct.pack("<6f", *rows_bottom_first[0], *rows_bottom_first[1])
        path.write_bytes(b"Pf\n3 2\n-1.0\n" + payload)
        image = read_image(path)
        assert torch.equal(image, torch.tensor([[[4.0, 5.0, 6.0], [1.0, 2.0, 3.0]]]))

    def test_big_endian_colour(self, tmp_path: Path) -> None:
        path = tmp_path / "be.pfm"
        pixels = [[[1.0, 2.0, 3.0]], [[4.0, 5.0, 6.0]]]  # height 2, width 1, RGB; bottom row first in the file
        payload = struct.pack(">6f", *pixels[0][0], *pixels[1][0])
        path.write_bytes(b"PF\n1 2\n1.0\n" + payload)
        image = read_image(path)
        assert torch.equal(image[:, 0, 0], torch.tensor([4.0, 5.0, 6.0]))  # top row = last in file
        assert torch.equal(image[:, 1, 0], torch.tensor([1.0, 2.0, 3.0]))

    def test_written_file_layout(self, tmp_path: Path) -> None:
        image = torch.tensor([[[1.0, 2.0], [3.0, 4.0], [5.0, 6.0]]])  # 1 channel, height 3, width 2
        path = write_image(tmp_path / "w.pfm", image)
        data = path.read_bytes()
        header_end = data.index(b"\n", data.index(b"\n", 3) + 1) + 1
        assert data[:2] == b"Pf"
        scale = float(data[data.index(b"\n", 3) + 1 : header_end - 1])
        values = np.frombuffer(data[header_end:], dtype="<f4" if scale < 0 else ">f4")
        assert values.tolist() == [5.0, 6.0, 3.0, 4.0, 1.0, 2.0]  # bottom row first, as PFM requires


class TestMetadata:
    META = {
        "bits": 8,
        "exposure": 0.1,
        "exposures": [1.0, 16.0, 256.0],
        "seed": 2**40,
        "flag": True,
        "nothing": None,
        "camera": "DFPA prototype",
        "nested": {"a": [1, 2, {"b": -0.5}]},
        "compression": "mine",  # a name OpenImageIO interprets: must not change how the file is written
    }

    @pytest.mark.parametrize("ext", ["exr", "png", "tif"])
    def test_round_trip(self, tmp_path: Path, ext: str) -> None:
        image = _ramp(3, 2, 3)
        path = write_image(tmp_path / f"m.{ext}", image, self.META)
        meta = read_metadata(path)
        for key, value in self.META.items():
            assert meta[key] == value, key
            assert type(meta[key]) is type(value), key
        back, meta2 = read_image(path, with_metadata=True)
        assert torch.equal(back, image)
        assert meta2 == meta

    def test_exr_native_attributes(self, tmp_path: Path) -> None:
        path = write_image(tmp_path / "m.exr", _ramp(1, 2, 2), self.META)
        inp = oiio.ImageInput.open(str(path))
        spec = inp.spec()
        inp.close()
        assert spec.getattribute("bits") == 8
        assert spec.getattribute("exposure") == pytest.approx(0.1)
        assert spec.getattribute("camera") == "DFPA prototype"
        assert list(spec.getattribute("exposures")) == [1.0, 16.0, 256.0]
        assert spec.getattribute("compression") == "zip"  # the user key did not change the compression

    def test_tensor_and_numpy_values(self, tmp_path: Path) -> None:
        meta = {"taus": torch.tensor([1.0, 4.0]), "k": np.int64(3), "arr": np.arange(3)}
        out = read_metadata(write_image(tmp_path / "m.exr", _ramp(1, 2, 2), meta))
        assert out["taus"] == [1.0, 4.0] and out["k"] == 3 and out["arr"] == [0, 1, 2]

    def test_foreign_file_attributes(self, tmp_path: Path) -> None:
        path = tmp_path / "foreign.exr"
        spec = oiio.ImageSpec(2, 2, 1, "float")
        spec.attribute("exposure", 0.25)
        spec.attribute("bits", 10)
        out = oiio.ImageOutput.create(str(path))
        out.open(str(path), spec)
        out.write_image(np.zeros((2, 2, 1), np.float32))
        out.close()
        meta = read_metadata(path)
        assert meta["exposure"] == 0.25 and meta["bits"] == 10
        assert tmio.METADATA_ATTRIBUTE not in meta

    def test_tiff_foreign_description_kept(self, tmp_path: Path) -> None:
        path = tmp_path / "d.tif"
        spec = oiio.ImageSpec(2, 2, 1, "uint8")
        spec.attribute("ImageDescription", "a plain description")
        out = oiio.ImageOutput.create(str(path))
        out.open(str(path), spec)
        out.write_image(np.zeros((2, 2, 1), np.uint8))
        out.close()
        assert read_metadata(path)["ImageDescription"] == "a plain description"

    @pytest.mark.parametrize("ext", ["hdr", "pfm"])
    def test_formats_without_metadata_warn(self, tmp_path: Path, ext: str) -> None:
        with pytest.warns(UserWarning, match=r"cannot store metadata.*\['bits'\]"):
            path = write_image(tmp_path / f"m.{ext}", _ramp(3, 2, 2), {"bits": 8})
        assert "bits" not in read_metadata(path)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            write_image(tmp_path / f"n.{ext}", _ramp(3, 2, 2))  # no metadata: no warning

    def test_bad_metadata(self, tmp_path: Path) -> None:
        with pytest.raises(TypeError, match=r"metadata\['obj'\] has type object"):
            write_image(tmp_path / "m.exr", _ramp(1, 2, 2), {"obj": object()})
        with pytest.raises(TypeError, match="keys must be strings; got 3"):
            write_image(tmp_path / "m.exr", _ramp(1, 2, 2), {3: 1})
        with pytest.raises(TypeError, match="metadata must be a dict; got list"):
            write_image(tmp_path / "m.exr", _ramp(1, 2, 2), [("a", 1)])  # type: ignore[arg-type]
        for ext in ("exr", "png", "tif"):  # a lone surrogate has no UTF-8 form (EXR raised a RuntimeError)
            with pytest.raises(ValueError, match=r"metadata\['s'\]\[0\] cannot be stored"):
                write_image(tmp_path / f"m.{ext}", _ramp(1, 2, 2), {"s": ["\ud83d"]})
        assert _listing(tmp_path) == []


class TestErrors:
    def test_missing(self, tmp_path: Path) -> None:
        path = tmp_path / "nope.exr"
        with pytest.raises(FileNotFoundError, match="nope.exr"):
            read_image(path)
        with pytest.raises(FileNotFoundError, match="nope.exr"):
            read_metadata(path)

    def test_directory(self, tmp_path: Path) -> None:
        with pytest.raises(IsADirectoryError, match=str(tmp_path.name)):
            read_image(tmp_path)

    def test_not_an_image(self, tmp_path: Path) -> None:
        for name in ("text.png", "text.exr", "text.tif", "empty.hdr", "notes.xyz"):
            path = tmp_path / name
            path.write_text("" if name.startswith("empty") else "this is not an image")
            with pytest.raises(OSError, match=name):
                read_image(path)

    @pytest.mark.parametrize(
        "ext, kind",
        [
            ("exr", "float"),
            ("exr", "half"),
            ("hdr", "float"),
            ("pfm", "float"),
            ("png", "uint8"),
            ("png", "uint16"),
            ("tif", "uint16"),
        ],
    )
    def test_truncated(self, tmp_path: Path, ext: str, kind: str) -> None:
        image = _values("uint8", (3, 32, 32))
        full = write_image(tmp_path / f"full.{ext}", image, dtype=kind)
        data = full.read_bytes()
        for frac in (0.3, 0.8):
            cut = tmp_path / f"cut{int(frac * 10)}.{ext}"
            cut.write_bytes(data[: int(len(data) * frac)])
            with pytest.raises(OSError, match=cut.name):
                read_image(cut)

    def test_wrong_image_type(self, tmp_path: Path) -> None:
        with pytest.raises(TypeError, match="must be a torch.Tensor; got ndarray"):
            write_image(tmp_path / "a.exr", np.zeros((1, 2, 2)))  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="real numbers; got dtype torch.bool"):
            write_image(tmp_path / "a.exr", torch.zeros(1, 2, 2, dtype=torch.bool))
        with pytest.raises(TypeError, match="complex64"):
            write_image(tmp_path / "a.exr", torch.zeros(1, 2, 2, dtype=torch.complex64))

    @pytest.mark.parametrize("shape", [(4,), (2, 1, 2, 2), (1, 1, 1, 2, 2), (0, 2, 2), (1, 0, 3)])
    def test_wrong_shape(self, tmp_path: Path, shape: tuple[int, ...]) -> None:
        with pytest.raises(ValueError, match=r"a\.exr.*got (.*shape )?" + re_shape(shape)):
            write_image(tmp_path / "a.exr", torch.zeros(shape))

    @pytest.mark.parametrize("ext, c", [("hdr", 1), ("hdr", 4), ("pfm", 2), ("png", 5)])
    def test_channels_for_format(self, tmp_path: Path, ext: str, c: int) -> None:
        with pytest.raises(ValueError, match=rf"stores .* channels; got {c}"):
            write_image(tmp_path / f"a.{ext}", torch.zeros(c, 2, 2))

    def test_unsupported_extension_and_dtype(self, tmp_path: Path) -> None:
        with pytest.raises(ValueError, match=r"unsupported extension '\.jpg'"):
            write_image(tmp_path / "a.jpg", torch.zeros(3, 2, 2))
        with pytest.raises(ValueError, match=r"PNG \(\.png\) stores dtype 'uint8' or 'uint16'; got 'float'"):
            write_image(tmp_path / "a.png", torch.zeros(3, 2, 2), dtype="float")
        with pytest.raises(ValueError, match="got 'half'"):
            write_image(tmp_path / "a.hdr", torch.zeros(3, 2, 2), dtype="half")
        with pytest.raises(ValueError, match=r"got \[1\]"):
            write_image(tmp_path / "a.exr", torch.zeros(3, 2, 2), dtype=[1])  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="torch.float32 or torch.float64; got torch.int32"):
            read_image(tmp_path / "whatever.exr", dtype=torch.int32)

    @pytest.mark.parametrize("ext", ["png", "tif"])
    def test_integer_values(self, tmp_path: Path, ext: str) -> None:
        nan = torch.tensor([[[1.0, float("nan")]]])
        with pytest.raises(ValueError, match=r"1 NaN and 0 Inf"):
            write_image(tmp_path / f"a.{ext}", nan)
        with pytest.raises(ValueError, match=r"non-integer value 2.5"):
            write_image(tmp_path / f"a.{ext}", torch.tensor([[[1.0, 2.5]]]))
        with pytest.raises(ValueError, match=r"\[0, 255\]; got min -1.0"):
            write_image(tmp_path / f"a.{ext}", torch.tensor([[[-1.0, 2.0]]]))
        with pytest.raises(ValueError, match=r"\[0, 65535\]; got min 0.0, max 65536.0"):
            write_image(tmp_path / f"a.{ext}", torch.tensor([[[0.0, 65536.0]]]), dtype="uint16")
        with pytest.raises(ValueError, match=r"normalized=True: values must lie in \[0, 1\]; got min 0.0, max 1.5"):
            write_image(tmp_path / f"a.{ext}", torch.tensor([[[0.0, 1.5]]]), normalized=True)
        with pytest.raises(ValueError, match="NaN"):
            write_image(tmp_path / f"a.{ext}", nan, normalized=True)
        assert _listing(tmp_path) == []

    def test_float_format_values(self, tmp_path: Path) -> None:
        with pytest.raises(ValueError, match=r"values >= 0 only; got min -0.5"):
            write_image(tmp_path / "a.hdr", torch.tensor([[[-0.5]], [[1.0]], [[1.0]]]))
        with pytest.raises(ValueError, match=r"finite values only; got 1 NaN"):
            write_image(tmp_path / "a.hdr", torch.tensor([[[float("nan")]], [[1.0]], [[1.0]]]))
        with pytest.raises(ValueError, match=r"half: values beyond \+-65504.*70000"):
            write_image(tmp_path / "a.exr", torch.tensor([[[70000.0]]]), dtype="half")
        assert _listing(tmp_path) == []

    def test_missing_folder(self, tmp_path: Path) -> None:
        with pytest.raises(FileNotFoundError, match="no_such_dir"):
            write_image(tmp_path / "no_such_dir" / "a.exr", torch.zeros(1, 2, 2))

    def test_path_type(self) -> None:
        with pytest.raises(TypeError, match="str or os.PathLike; got int"):
            read_image(3)  # type: ignore[arg-type]


class TestAtomicWrite:
    def test_no_temporary_left_and_replace(self, tmp_path: Path) -> None:
        path = tmp_path / "a.exr"
        write_image(path, torch.zeros(1, 2, 2))
        write_image(path, torch.ones(1, 2, 2))
        assert _listing(tmp_path) == ["a.exr"]
        assert torch.equal(read_image(path), torch.ones(1, 2, 2))

    def test_failure_keeps_old_file(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        path = write_image(tmp_path / "a.png", torch.zeros(1, 2, 2))
        seen: list[str] = []

        def broken_replace(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
            seen.append(Path(src).name)
            raise OSError("disk full")

        monkeypatch.setattr(tmio.os, "replace", broken_replace)
        with pytest.raises(OSError, match="disk full"):
            write_image(path, torch.full((1, 2, 2), 3.0))
        monkeypatch.undo()
        assert seen and seen[0].startswith(".a.") and seen[0].endswith(".png")  # same extension, hidden
        assert _listing(tmp_path) == ["a.png"]
        assert torch.equal(read_image(path), torch.zeros(1, 2, 2))

    def test_returns_path_and_accepts_str(self, tmp_path: Path) -> None:
        out = write_image(str(tmp_path / "s.tif"), torch.zeros(1, 1, 1))
        assert isinstance(out, Path) and out.exists()
        json.dumps(read_metadata(str(out)))  # metadata of a plain file is JSON-ready too


@pytest.fixture
def tiny_tmpfs(tmp_path: Path) -> Path:
    """A 64 KiB tmpfs (needs root and permission to mount; the test is skipped otherwise)."""
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    import subprocess

    mount = tmp_path / "full"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode(errors='replace').strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=False)


class TestFullDisk:
    """Regression: ``write_image`` to .png on a full disk returned success and left a truncated file."""

    def _noise(self) -> torch.Tensor:
        gen = torch.Generator().manual_seed(7)
        return torch.randint(0, 256, (3, 200, 200), generator=gen).float()  # incompressible: about 120 KB

    @pytest.mark.parametrize("ext", [".png", ".exr", ".tif"])
    def test_full_disk_raises_and_leaves_nothing(self, tiny_tmpfs: Path, ext: str) -> None:
        with pytest.raises(OSError, match=re.escape(str(tiny_tmpfs / f"a{ext}"))):
            write_image(tiny_tmpfs / f"a{ext}", self._noise())
        assert os.listdir(tiny_tmpfs) == []

    def test_full_disk_keeps_the_previous_png(self, tiny_tmpfs: Path) -> None:
        path = write_image(tiny_tmpfs / "a.png", torch.zeros(1, 4, 4))
        with pytest.raises(OSError, match="No space left on device"):
            write_image(path, self._noise())
        assert os.listdir(tiny_tmpfs) == ["a.png"] and torch.equal(read_image(path), torch.zeros(1, 4, 4))

    def test_short_png_write_is_caught(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        # Without a full disk: a writer that reports success but leaves half the file, as libpng does.
        real_create = oiio.ImageOutput.create

        class ShortWriter:
            def __init__(self, name: str) -> None:
                self.name, self.out = name, real_create(name)

            def open(self, name: str, spec: oiio.ImageSpec) -> bool:
                return self.out.open(name, spec)

            def write_image(self, array: np.ndarray) -> bool:
                return self.out.write_image(array)

            def close(self) -> bool:
                ok = self.out.close()
                with open(self.name, "r+b") as f:
                    f.truncate(os.path.getsize(self.name) // 2)
                return ok

            def geterror(self) -> str:
                return self.out.geterror()

        class Factory:
            create = staticmethod(ShortWriter)

        monkeypatch.setattr(tmio.oiio, "ImageOutput", Factory)
        with pytest.raises(OSError, match=re.escape(str(tmp_path / "a.png"))):
            write_image(tmp_path / "a.png", self._noise())
        assert _listing(tmp_path) == []


class TestFlags:
    """Regression: flags were taken by truthiness (``normalized="no"`` switched normalisation on)."""

    @pytest.mark.parametrize("flag", ["no", 0, 1, None])
    def test_flags_must_be_bools(self, tmp_path: Path, flag: object) -> None:
        if flag is not None:  # write_image's normalized=None chooses (TestRawOrNormalized)
            with pytest.raises(TypeError, match=f"normalized must be a bool; got {flag!r}"):
                write_image(tmp_path / "a.png", torch.zeros(1, 2, 2), normalized=flag)  # type: ignore[arg-type]
        path = write_image(tmp_path / "a.png", torch.zeros(1, 2, 2))
        with pytest.raises(TypeError, match="normalized must be a bool"):
            read_image(path, normalized=flag)  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="with_metadata must be a bool"):
            read_image(path, with_metadata=flag)  # type: ignore[arg-type]


def _png_chunks(path: Path) -> list[str]:
    """The chunk types of a PNG file, in order."""
    data = path.read_bytes()
    names, i = [], 8
    while i < len(data):
        (length,) = struct.unpack(">I", data[i : i + 4])
        names.append(data[i + 4 : i + 8].decode("ascii"))
        i += 12 + length
    return names


class TestRawOrNormalized:
    """Regression: a float image in [0, 1] was refused without ``normalized=True``, a batch of one (1, C, H, W) was
    refused, and PNGs of raw counts were tagged sRGB. ``normalized=None`` now decides, and never rescales counts."""

    @pytest.mark.parametrize("ext, kind, top", [("png", "uint8", 255), ("png", "uint16", 65535), ("tif", "uint8", 255)])
    def test_float_image_in_unit_range_is_normalized(self, tmp_path: Path, ext: str, kind: str, top: int) -> None:
        display = torch.linspace(0, 1, 12).reshape(3, 2, 2)
        path = write_image(tmp_path / f"d.{ext}", display, dtype=kind)
        assert torch.equal(read_image(path), torch.round(display.double() * top).float())
        assert torch.equal(
            read_image(path), read_image(write_image(tmp_path / f"n.{ext}", display, dtype=kind, normalized=True))
        )

    def test_counts_stay_raw(self, tmp_path: Path) -> None:
        counts = torch.tensor([[[0.0, 1.0], [2.0, 255.0]]])
        assert torch.equal(read_image(write_image(tmp_path / "c.png", counts)), counts)
        for dtype in (torch.uint8, torch.int64):  # integer tensors are counts, even when they hold only 0 and 1
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                back = read_image(write_image(tmp_path / "i.png", torch.tensor([[[0, 1]]], dtype=dtype)))
            assert torch.equal(back, torch.tensor([[[0.0, 1.0]]]))

    def test_a_dark_frame_is_never_rescaled(self, tmp_path: Path) -> None:
        dark = torch.tensor([[[0.0, 1.0], [1.0, 0.0]]])
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a sensor's frame ("bits" in its metadata) is counts: no warning
            path = write_image(tmp_path / "f.png", dark, {"exposure": 1.0, "bits": 8})
        assert torch.equal(read_image(path), dark)
        with pytest.raises(ValueError, match=r"non-integer value 0.5"):  # a frame is counts even in [0, 1]
            write_image(tmp_path / "g.png", torch.tensor([[[0.25, 0.5]]]), {"bits": 8})
        from torch_modulo.sensors import FileSensor, FrameStack, write_frames

        stack = FrameStack(torch.tensor([[[[0.0, 1.0]]], [[[1.0, 0.0]]]]), [1.0, 4.0], bits=8)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            write_frames(stack, tmp_path / "stack", format="png")
        assert torch.equal(FileSensor(tmp_path / "stack").read().frames, stack.frames)

    def test_zeros_and_ones_warn_and_stay_raw(self, tmp_path: Path) -> None:
        mask = torch.tensor([[[0.0, 1.0]]])
        with pytest.warns(UserWarning, match=r"only 0 and 1 .* raw integers 0 and 1.*normalized=True"):
            path = write_image(tmp_path / "m.png", mask)
        assert torch.equal(read_image(path), mask)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert torch.equal(read_image(write_image(tmp_path / "r.png", mask, normalized=False)), mask)
            assert torch.equal(read_image(write_image(tmp_path / "n.png", mask, normalized=True)), mask * 255)
            write_image(tmp_path / "z.png", torch.zeros(1, 2, 2))  # zeros are the same either way

    def test_out_of_range_non_integers_refused(self, tmp_path: Path) -> None:
        with pytest.raises(ValueError, match=r"non-integer value 2.5.*normalized=True for an image in \[0, 1\]"):
            write_image(tmp_path / "a.png", torch.tensor([[[0.25, 2.5]]]))
        with pytest.raises(ValueError, match=r"\[0, 255\]; got min -0.5"):
            write_image(tmp_path / "a.png", torch.tensor([[[-0.5, 0.5]]]))
        assert _listing(tmp_path) == []

    @pytest.mark.parametrize("ext", ["png", "tif", "exr"])
    def test_batch_of_one(self, tmp_path: Path, ext: str) -> None:
        image = _ramp(3, 2, 4)
        back = read_image(write_image(tmp_path / f"b.{ext}", image.unsqueeze(0)))
        assert torch.equal(back, image)
        with pytest.raises(ValueError, match=r"batch of 2, shape \(2, 3, 2, 4\).*one file per image"):
            write_image(tmp_path / f"c.{ext}", torch.stack([image, image]))

    def test_raw_png_is_tagged_as_data(self, tmp_path: Path) -> None:
        raw = write_image(tmp_path / "raw.png", torch.tensor([[[0.0, 7.0, 200.0]]]), {"exposure": 1.0, "bits": 8})
        assert not {"sRGB", "gAMA", "cHRM", "iCCP"} & set(_png_chunks(raw))
        meta = read_metadata(raw)
        assert meta["oiio:ColorSpace"] == "Raw"
        assert "torch_modulo:colorspace" not in meta and meta["bits"] == 8
        display = write_image(tmp_path / "display.png", torch.tensor([[[0.0, 0.5, 1.0]]]))
        assert "sRGB" in _png_chunks(display)
        assert "srgb" in read_metadata(display)["oiio:ColorSpace"].lower()
        pil = pytest.importorskip("PIL.Image")
        assert "srgb" not in pil.open(raw).info and "gamma" not in pil.open(raw).info
