"""Tests for FileSensor, RawFormat and write_frames: round trips, camera folders, raw dumps, errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
import torch

from torch_modulo.io import read_image, write_image
from torch_modulo.sensors import (
    MANIFEST,
    FileSensor,
    FrameStack,
    NoiseModel,
    RawFormat,
    SimulatedIntensitySensor,
    SimulatedModuloSensor,
    frame_bits,
    frame_exposure,
    stack_files,
    write_frames,
)


def _moduli(shape: tuple[int, ...], bits: int, seed: int = 0, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randint(0, 2**bits, shape, generator=g).to(dtype)


class TestRoundTrip:
    @pytest.mark.parametrize(
        "fmt, bits", [("exr", 8), ("exr", 11), ("exr", 16), ("exr", 24), ("png", 8), ("png", 12), ("tiff", 16)]
    )
    def test_write_then_read(self, tmp_path: Path, fmt: str, bits: int) -> None:
        stack = FrameStack(_moduli((1, 3, 3, 5, 6), bits), [1.0, 16.0, 250.5], bits, {"scene": "test", "n": [1, 2]})
        manifest = write_frames(stack, tmp_path, format=fmt)
        assert manifest == tmp_path / MANIFEST
        back = FileSensor(tmp_path).read()
        assert back == stack
        assert back.exposures.shape == (3,)

    def test_batched_per_item_exposures(self, tmp_path: Path) -> None:
        taus = torch.tensor([[1.0, 8.0], [0.5, 64.0], [2.0, 3.0]])
        stack = FrameStack(_moduli((3, 2, 1, 4, 4), 10), taus, 10, kind="intensity")
        write_frames(stack, tmp_path, format="png")
        back = FileSensor(tmp_path).read()
        assert back == stack and back.kind == "intensity" and back.exposures.shape == (3, 2)

    def test_batched_shared_exposures(self, tmp_path: Path) -> None:
        stack = FrameStack(_moduli((2, 3, 2, 3, 3), 8), [1.0, 2.0, 4.0], 8)
        write_frames(stack, tmp_path / "new" / "sub", format="tiff")  # folders are created
        assert FileSensor(tmp_path / "new" / "sub").read() == stack

    def test_float64_stack(self, tmp_path: Path) -> None:
        stack = FrameStack(_moduli((1, 2, 1, 3, 3), 20, dtype=torch.float64), [1.0, 3.0], 20)
        write_frames(stack, tmp_path)
        back = FileSensor(tmp_path).read()
        assert back == stack and back.dtype == torch.float64
        assert FileSensor(tmp_path, dtype=torch.float32).read().dtype == torch.float32

    def test_simulated_sensor_round_trip(self, tmp_path: Path) -> None:
        radiance = torch.rand(2, 3, 8, 8, generator=torch.Generator().manual_seed(0)) * 5000
        stack = SimulatedModuloSensor(bits=8, noise=NoiseModel(prnu=0.01), seed=3)(radiance, [1.0, 20.0, 400.0])
        write_frames(stack, tmp_path, format="png")
        assert FileSensor(tmp_path).read() == stack

    def test_each_frame_is_self_describing(self, tmp_path: Path) -> None:
        """Without the manifest, the frames' own metadata still gives exposures and bits."""
        stack = FrameStack(_moduli((1, 3, 1, 4, 4), 12), [1.0, 10.0, 100.0], 12)
        write_frames(stack, tmp_path, format="png")
        (tmp_path / MANIFEST).unlink()
        back = FileSensor(tmp_path).read()
        assert torch.equal(back.moduli, stack.moduli)
        assert back.exposures.tolist() == [1.0, 10.0, 100.0] and back.bits == 12

    def test_downstream_same_result(self, tmp_path: Path) -> None:
        """Unwrapping the frames from disk equals unwrapping the simulated ones."""
        multishot = pytest.importorskip("torch_modulo.multishot")
        radiance = torch.rand(1, 3, 16, 16, generator=torch.Generator().manual_seed(1)) * 60
        sim = SimulatedModuloSensor(bits=8, noise=None)(radiance, [1.0, 32.0, 1024.0])
        write_frames(sim, tmp_path, format="png")
        disk = FileSensor(tmp_path).read()
        a = multishot.unwrap_multi(sim.moduli, sim.exposures, sim.bits)
        b = multishot.unwrap_multi(disk.moduli, disk.exposures, disk.bits)
        assert torch.equal(a, b)
        assert torch.equal(a * 1024, torch.floor(radiance * 1024))

    def test_write_errors(self, tmp_path: Path) -> None:
        stack = FrameStack(_moduli((1, 1, 1, 2, 2), 17, dtype=torch.float64), [1.0], 17)
        with pytest.raises(ValueError, match="at most 16 bits; got bits=17"):
            write_frames(stack, tmp_path, format="png")
        big = FrameStack(_moduli((1, 1, 1, 2, 2), 25, dtype=torch.float64), [1.0], 25)
        with pytest.raises(ValueError, match="at most 24 bits exactly.*got bits=25"):
            write_frames(big, tmp_path)
        with pytest.raises(ValueError, match="format must be one of .*got 'jpg'"):
            write_frames(stack, tmp_path, format="jpg")
        with pytest.raises(TypeError, match="stack must be a FrameStack; got Tensor"):
            write_frames(torch.zeros(1), tmp_path)  # type: ignore[arg-type]
        bad_meta = FrameStack(_moduli((1, 1, 1, 2, 2), 8), [1.0], 8, {"x": object()})
        with pytest.raises(TypeError, match="stack.metadata must be JSON-serialisable"):
            write_frames(bad_meta, tmp_path)
        with pytest.raises(ValueError, match="prefix must be"):
            write_frames(FrameStack(_moduli((1, 1, 1, 2, 2), 8), [1.0], 8), tmp_path, prefix=".hidden")
        assert list(tmp_path.iterdir()) == []

    def test_empty_batch_refused_nothing_written(self, tmp_path: Path) -> None:
        # A batch of 0 wrote a manifest listing no frames, which FileSensor then refused to read back.
        empty = SimulatedModuloSensor(bits=8)(torch.rand(0, 3, 6, 8), [1.0])
        with pytest.raises(ValueError, match=r"stack has no frames \(a batch of 0, shape \(0, 1, 3, 6, 8\)\)"):
            write_frames(empty, tmp_path / "stack")
        assert list(tmp_path.iterdir()) == []


class TestCameraFolders:
    def _camera_frames(self, folder: Path, bits: int = 12, sidecar: str = "full") -> torch.Tensor:
        frames = _moduli((3, 1, 5, 4), bits, seed=4)
        for i, (frame, tau) in enumerate(zip(frames, [2.0, 20.0, 200.0], strict=True)):
            path = write_image(folder / f"cap_{i}.png", frame, dtype="uint16")
            side = path.with_name(path.name + ".json") if sidecar == "full" else path.with_suffix(".json")
            side.write_text(json.dumps({"exposure": tau, "bits": bits}))
        return frames

    @pytest.mark.parametrize("sidecar", ["full", "stem"])
    def test_png_with_sidecars(self, tmp_path: Path, sidecar: str) -> None:
        frames = self._camera_frames(tmp_path, sidecar=sidecar)
        (tmp_path / ".cap_9.tmp.png").write_bytes(b"half-written")  # hidden: skipped
        (tmp_path / "notes.txt").write_text("ignored")
        stack = FileSensor(tmp_path).read()
        assert torch.equal(stack.moduli[0], frames)
        assert stack.exposures.tolist() == [2.0, 20.0, 200.0] and stack.bits == 12 and stack.kind == "modulo"
        assert [p.name for p in FileSensor(tmp_path).files] == ["cap_0.png", "cap_1.png", "cap_2.png"]

    def test_list_of_files_keeps_order(self, tmp_path: Path) -> None:
        frames = self._camera_frames(tmp_path)
        files = [tmp_path / "cap_2.png", tmp_path / "cap_0.png"]
        stack = FileSensor(files).read()
        assert torch.equal(stack.moduli[0, 0], frames[2]) and stack.exposures.tolist() == [200.0, 2.0]

    def test_arguments_override(self, tmp_path: Path) -> None:
        self._camera_frames(tmp_path)
        stack = FileSensor(tmp_path, exposures=[1.0, 2.0, 3.0], bits=14, device="cpu").read()
        assert stack.exposures.tolist() == [1.0, 2.0, 3.0] and stack.bits == 14

    def test_hand_written_manifest(self, tmp_path: Path) -> None:
        frames = self._camera_frames(tmp_path)
        (tmp_path / MANIFEST).write_text(
            json.dumps({"bits": 12, "frames": [{"file": "cap_1.png", "exposure": 20.0}, "cap_0.png"]})
        )
        stack = FileSensor(tmp_path).read()  # cap_0's exposure comes from its sidecar
        assert torch.equal(stack.moduli[0], frames[[1, 0]])
        assert stack.exposures.tolist() == [20.0, 2.0] and stack.bits == 12
        # A manifest that contradicts the sidecars is refused (it used to override them silently).
        (tmp_path / MANIFEST).write_text(json.dumps({"bits": 12, "frames": [{"file": "cap_1.png", "exposure": 5.0}]}))
        with pytest.raises(
            ValueError, match=r"exposure 5 for frame cap_1\.png, but .*cap_1\.png\.json records exposure 20"
        ):
            FileSensor(tmp_path).read()
        assert FileSensor(tmp_path, exposures=[5.0]).read().exposures.tolist() == [5.0]  # the argument overrides

    def test_foreign_exr_attributes(self, tmp_path: Path) -> None:
        """EXR frames written by another program with exposure and bits as native attributes."""
        frames = _moduli((2, 3, 4, 5), 10, seed=8)
        for i, tau in enumerate([0.25, 8.0]):
            path = tmp_path / f"f{i}.exr"
            spec = oiio.ImageSpec(5, 4, 3, "half")
            spec.attribute("exposure", tau)
            spec.attribute("bits", 10)
            out = oiio.ImageOutput.create(str(path))
            out.open(str(path), spec)
            assert out.write_image(np.ascontiguousarray(frames[i].permute(1, 2, 0).numpy()))
            out.close()
        stack = FileSensor(tmp_path).read()
        assert torch.equal(stack.moduli[0], frames) and stack.exposures.tolist() == [0.25, 8.0]
        assert stack.bits == 10


class TestRaw:
    @pytest.mark.parametrize("byteorder", ["little", "big"])
    def test_raw_dumps(self, tmp_path: Path, byteorder: str) -> None:
        raw = RawFormat(width=6, height=4, bits=12, byteorder=byteorder, channels=3, offset=16)
        frames = _moduli((2, 3, 4, 6), 12, seed=1)
        dtype = np.dtype(("<" if byteorder == "little" else ">") + "u2")
        for i, frame in enumerate(frames):
            data = frame.permute(1, 2, 0).numpy().astype(dtype).tobytes()
            (tmp_path / f"dump{i}.raw").write_bytes(b"H" * 16 + data)
        stack = FileSensor(tmp_path, raw=raw, exposures=[1.0, 100.0]).read()
        assert torch.equal(stack.moduli[0], frames) and stack.bits == 12
        assert raw.frame_bytes == 16 + 6 * 4 * 3 * 2

    def test_raw_8bit_with_sidecar(self, tmp_path: Path) -> None:
        raw = RawFormat(width=3, height=2, bits=8)
        frame = torch.tensor([[[1.0, 2.0, 3.0], [4.0, 5.0, 255.0]]])
        (tmp_path / "a.bin").write_bytes(bytes([1, 2, 3, 4, 5, 255]))
        (tmp_path / "a.bin.json").write_text(json.dumps({"exposure": 4.0}))
        stack = FileSensor(tmp_path, raw=raw).read()
        assert torch.equal(stack.moduli[0, 0], frame) and stack.exposures.tolist() == [4.0]

    def test_raw_errors(self, tmp_path: Path) -> None:
        raw = RawFormat(width=2, height=2, bits=10)
        (tmp_path / "short.raw").write_bytes(b"\x00" * 7)
        with pytest.raises(ValueError, match=r"short\.raw has 7 bytes; expected 8 for 2x2x1 samples of 2 bytes"):
            FileSensor(tmp_path, raw=raw, exposures=[1.0]).read()
        (tmp_path / "short.raw").write_bytes(np.array([0, 1, 2, 1024], "<u2").tobytes())
        with pytest.raises(ValueError, match=r"frame .*short\.raw must hold integers in \[0, 1024\).*max 1024"):
            FileSensor(tmp_path, raw=raw, exposures=[1.0]).read()
        with pytest.raises(ValueError, match="no frames in .*pass raw=RawFormat"):
            FileSensor(tmp_path)

    @pytest.mark.parametrize(
        "kwargs, message",
        [
            ({"width": 0}, "width must be a positive int; got 0"),
            ({"bits": 33}, "at most 32; got 33"),
            ({"byteorder": "middle"}, "byteorder must be 'little' or 'big'; got 'middle'"),
            ({"sample_bytes": 1}, "hold 12 bits .*got 1"),
            ({"sample_bytes": 3}, "must be 1, 2 or 4"),
            ({"offset": -1}, "offset must be an int >= 0; got -1"),
        ],
    )
    def test_raw_format_errors(self, kwargs: dict, message: str) -> None:
        args = {"width": 4, "height": 4, "bits": 12} | kwargs
        with pytest.raises(ValueError, match=message):
            RawFormat(**args)

    @pytest.mark.parametrize(
        "extensions, expected",
        [
            (".raw", (".raw",)),  # one str is one extension, not its characters
            ("RAW", (".raw",)),
            (("raw", ".Bin"), (".raw", ".bin")),  # no dot never matched anything
            ([".dat"], (".dat",)),
            ({"RAW"}, (".raw",)),
            ((".raw", ".bin"), (".raw", ".bin")),
            ((), ()),
        ],
    )
    def test_raw_extensions_normalised(self, tmp_path: Path, extensions: object, expected: tuple) -> None:
        raw = RawFormat(width=2, height=1, bits=8, extensions=extensions)  # type: ignore[arg-type]
        assert raw.extensions == expected and raw == RawFormat(width=2, height=1, bits=8, extensions=expected)
        for i, ext in enumerate(expected):
            (tmp_path / f"f{i}{ext.upper()}").write_bytes(bytes([i, 7]))
        if expected:
            stack = FileSensor(tmp_path, raw=raw, exposures=[1.0 + i for i in range(len(expected))]).read()
            assert stack.moduli[0, :, 0, 0].tolist() == [[float(i), 7.0] for i in range(len(expected))]

    @pytest.mark.parametrize("bad", ["", ".", "tar.gz", ".raw.", "a/b", " raw", ("raw", "")])
    def test_raw_extensions_that_cannot_match_refused(self, bad: object) -> None:
        with pytest.raises(ValueError, match=r"RawFormat.extensions must be file suffixes such as '.raw'"):
            RawFormat(width=2, height=1, bits=8, extensions=bad)  # type: ignore[arg-type]

    @pytest.mark.parametrize("bad", [None, 3, (".raw", 3), b".raw", [b".raw"]])
    def test_raw_extensions_of_wrong_type_refused(self, bad: object) -> None:
        with pytest.raises(TypeError, match="RawFormat.extensions must"):
            RawFormat(width=2, height=1, bits=8, extensions=bad)  # type: ignore[arg-type]


class TestErrors:
    def test_missing(self, tmp_path: Path) -> None:
        with pytest.raises(FileNotFoundError, match="nowhere"):
            FileSensor(tmp_path / "nowhere")
        with pytest.raises(FileNotFoundError, match="gone.png"):
            FileSensor([tmp_path / "gone.png"], exposures=[1.0], bits=8).read()

    def test_empty(self, tmp_path: Path) -> None:
        with pytest.raises(ValueError, match="no frames in"):
            FileSensor(tmp_path)
        with pytest.raises(ValueError, match="list of files is empty"):
            FileSensor([])
        with pytest.raises(TypeError, match="source must be a folder, a file or a list of files; got int"):
            FileSensor(3)  # type: ignore[arg-type]

    def test_missing_metadata(self, tmp_path: Path) -> None:
        write_image(tmp_path / "a.png", torch.zeros(1, 2, 2))
        with pytest.raises(ValueError, match=r"no exposure for frame .*a\.png.*a\.png\.json"):
            FileSensor(tmp_path, bits=8).read()
        with pytest.raises(ValueError, match=r"no bit depth for frame .*a\.png"):
            FileSensor(tmp_path, exposures=[1.0]).read()

    def test_bad_sidecar(self, tmp_path: Path) -> None:
        write_image(tmp_path / "a.png", torch.zeros(1, 2, 2))
        side = tmp_path / "a.png.json"
        side.write_text("{not json")
        with pytest.raises(ValueError, match=r"a\.png\.json is not valid JSON"):
            FileSensor(tmp_path).read()
        side.write_text(json.dumps({"exposure": -2.0, "bits": 8}))
        with pytest.raises(
            ValueError, match=r"exposure from .*a\.png\.json must be a positive finite number; got -2.0"
        ):
            FileSensor(tmp_path).read()
        side.write_text(json.dumps({"exposure": 1.0, "bits": "eight"}))
        with pytest.raises(ValueError, match=r"bits from .*a\.png\.json must be an integer; got 'eight'"):
            FileSensor(tmp_path).read()
        side.write_text(json.dumps([1, 2]))
        with pytest.raises(ValueError, match=r"a\.png\.json must hold a JSON object; got list"):
            FileSensor(tmp_path).read()

    def test_sizes_differ(self, tmp_path: Path) -> None:
        write_image(tmp_path / "a.png", torch.zeros(1, 2, 2), {"exposure": 1.0, "bits": 8})
        write_image(tmp_path / "b.png", torch.zeros(1, 2, 3), {"exposure": 2.0, "bits": 8})
        with pytest.raises(ValueError, match=r"b\.png has shape \(1, 2, 3\).*a\.png has \(1, 2, 2\)"):
            FileSensor(tmp_path).read()

    def test_bits_differ(self, tmp_path: Path) -> None:
        write_image(tmp_path / "a.png", torch.zeros(1, 2, 2), {"exposure": 1.0, "bits": 8})
        write_image(tmp_path / "b.png", torch.zeros(1, 2, 2), {"exposure": 2.0, "bits": 9})
        with pytest.raises(ValueError, match=r"b\.png has bits=9 but .*a\.png has bits=8"):
            FileSensor(tmp_path).read()

    def test_values_beyond_bits(self, tmp_path: Path) -> None:
        write_image(tmp_path / "a.png", torch.tensor([[[0.0, 300.0]]]), {"exposure": 1.0, "bits": 8}, dtype="uint16")
        with pytest.raises(ValueError, match=r"frame .*a\.png must hold integers in \[0, 256\) for bits=8.*300"):
            FileSensor(tmp_path).read()
        write_image(tmp_path / "a.png", torch.tensor([[[0.0, 1.5]]]) * 2 / 3, normalized=True)
        write_image(tmp_path / "f.exr", torch.tensor([[[0.0, 1.5]]]), {"exposure": 1.0, "bits": 8})
        with pytest.raises(ValueError, match=r"frame .*f\.exr must hold integers for bits=8; got non-integer"):
            FileSensor([tmp_path / "f.exr"]).read()

    def test_unreadable(self, tmp_path: Path) -> None:
        path = write_image(tmp_path / "a.png", _moduli((1, 16, 16), 8), {"exposure": 1.0, "bits": 8})
        path.write_bytes(path.read_bytes()[:60])
        with pytest.raises(OSError, match=r"a\.png"):
            FileSensor(tmp_path).read()

    def test_bad_arguments(self, tmp_path: Path) -> None:
        write_image(tmp_path / "a.png", torch.zeros(1, 2, 2), {"exposure": 1.0, "bits": 8})
        with pytest.raises(ValueError, match="exposures has 2 values for 1 frames"):
            FileSensor(tmp_path, exposures=[1.0, 2.0])
        with pytest.raises(ValueError, match="exposure from the exposures argument must be a positive finite"):
            FileSensor(tmp_path, exposures=[0.0])
        with pytest.raises(ValueError, match="kind must be one of"):
            FileSensor(tmp_path, kind="raw")
        with pytest.raises(TypeError, match="raw must be a RawFormat or None; got dict"):
            FileSensor(tmp_path, raw={"width": 2})  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="dtype must be a floating torch dtype; got torch.int32"):
            FileSensor(tmp_path, dtype=torch.int32)
        with pytest.raises(ValueError, match="bits from the bits argument: bits must be >= 1; got 0"):
            FileSensor(tmp_path, bits=0)

    def test_bad_manifest(self, tmp_path: Path) -> None:
        stack = FrameStack(_moduli((2, 2, 1, 2, 2), 8), [1.0, 2.0], 8)
        write_frames(stack, tmp_path)
        manifest = json.loads((tmp_path / MANIFEST).read_text())
        broken = dict(manifest, frames=[])
        (tmp_path / MANIFEST).write_text(json.dumps(broken))
        with pytest.raises(ValueError, match=r"frames\.json must list the frames"):
            FileSensor(tmp_path)
        missing = dict(manifest, frames=manifest["frames"][:-1])
        (tmp_path / MANIFEST).write_text(json.dumps(missing))
        with pytest.raises(ValueError, match=r"no frame for exposure 2 of scene 1 .* of a 2 x 2 stack"):
            FileSensor(tmp_path).read()
        disagree = dict(manifest, exposures=[1.0, 3.0])
        (tmp_path / MANIFEST).write_text(json.dumps(disagree))
        with pytest.raises(ValueError, match=r"exposures \[1.0, 3.0\] disagree with the frames' exposures"):
            FileSensor(tmp_path).read()
        (tmp_path / MANIFEST).write_text(json.dumps(dict(manifest, kind="hdr")))
        with pytest.raises(ValueError, match="kind must be one of .*got 'hdr'"):
            FileSensor(tmp_path)
        (tmp_path / MANIFEST).write_text("[]")
        with pytest.raises(ValueError, match="must hold a JSON object"):
            FileSensor(tmp_path)

    @pytest.mark.parametrize("key", ["index", "batch"])
    @pytest.mark.parametrize("value", [10**9, 10**15, 2, -1])
    def test_impossible_places_refused_before_any_allocation(self, tmp_path: Path, key: str, value: int) -> None:
        # A huge index or batch laid out a grid as large as it (index 5e6 took 794 MB before failing): refused on
        # construction, naming the manifest, the frame and the value, since 2 frames fill at most places 0 and 1.
        write_image(tmp_path / "a.png", torch.zeros(1, 2, 2))
        write_image(tmp_path / "b.png", torch.ones(1, 2, 2), normalized=False)
        frames = [{"file": "a.png", "exposure": 1.0}, {"file": "b.png", "exposure": 2.0, key: value}]
        (tmp_path / MANIFEST).write_text(json.dumps({"bits": 8, "frames": frames}))
        message = rf"frames\.json \(frame b\.png\): '{key}' must be an int in \[0, 1\] .*2 frames\); got {value}$"
        with pytest.raises(ValueError, match=message):
            FileSensor(tmp_path)

    @pytest.mark.parametrize("value", [True, 1.0, "1", None])
    def test_non_integer_places_refused(self, tmp_path: Path, value: object) -> None:
        write_image(tmp_path / "a.png", torch.zeros(1, 2, 2))
        frames = [{"file": "a.png", "exposure": 1.0, "index": value}, {"file": "a.png", "exposure": 2.0, "index": 0}]
        (tmp_path / MANIFEST).write_text(json.dumps({"bits": 8, "frames": frames}))
        with pytest.raises(ValueError, match=rf"\(frame a\.png\): 'index' must be an integer; got {value!r}"):
            FileSensor(tmp_path)

    def test_places_within_the_listed_frames_still_read(self, tmp_path: Path) -> None:
        write_image(tmp_path / "a.png", torch.zeros(1, 2, 2))
        write_image(tmp_path / "b.png", torch.ones(1, 2, 2), normalized=False)
        frames = [{"file": "a.png", "exposure": 1.0, "batch": 1}, {"file": "b.png", "exposure": 2.0, "batch": 0}]
        (tmp_path / MANIFEST).write_text(json.dumps({"bits": 8, "frames": frames}))
        stack = FileSensor(tmp_path).read()
        assert stack.shape == (2, 1, 1, 2, 2) and stack.moduli[:, 0, 0, 0, 0].tolist() == [1.0, 0.0]

    def test_intensity_frames_via_simulated_sensor(self, tmp_path: Path) -> None:
        stack = SimulatedIntensitySensor(bits=8, seed=0)(torch.rand(1, 1, 4, 4) * 500, [1.0, 2.0])
        write_frames(stack, tmp_path, format="tiff")
        back = FileSensor(tmp_path).read()
        assert back == stack and back.kind == "intensity"
        assert torch.equal(read_image(tmp_path / "frame_b000_m01.tif"), stack.frames[0, 1])


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


class TestWriteFramesIsAtomic:
    """Regression: a failure half-way through ``write_frames`` left a mixed stack (new frame 0, old frame 1, old
    manifest) in an existing folder, or a one-frame stack without a manifest in a new one."""

    def _failing_write_image(self, monkeypatch: pytest.MonkeyPatch, after: int) -> None:
        import torch_modulo.sensors.files as files

        real = files.write_image
        calls = {"n": 0}

        def write_image(path: Path, *args: object, **kwargs: object) -> Path:
            calls["n"] += 1
            if calls["n"] > after:
                raise OSError(28, "No space left on device", str(path))
            return real(path, *args, **kwargs)  # type: ignore[arg-type]

        monkeypatch.setattr(files, "write_image", write_image)

    def test_failure_into_an_existing_stack_keeps_the_old_stack(
        self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
    ) -> None:
        folder = tmp_path / "stack"
        old = FrameStack(_moduli((1, 2, 1, 4, 4), 8, seed=1), [1.0, 8.0], 8)
        write_frames(old, folder)
        self._failing_write_image(monkeypatch, after=1)
        new = FrameStack(_moduli((1, 2, 1, 4, 4), 8, seed=2), [1.0, 8.0], 8)
        with pytest.raises(OSError, match="No space left on device") as error:
            write_frames(new, folder)
        assert error.value.filename == str(folder.resolve() / "frame_b000_m01.exr")
        monkeypatch.undo()
        assert FileSensor(folder).read() == old
        assert _hidden(tmp_path) == [] and _hidden(folder) == []

    def test_failure_into_a_new_folder_leaves_nothing(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        self._failing_write_image(monkeypatch, after=1)
        with pytest.raises(OSError):
            write_frames(FrameStack(_moduli((1, 2, 1, 4, 4), 8), [1.0, 8.0], 8), tmp_path / "stack")
        assert list(tmp_path.iterdir()) == []

    def test_other_files_are_kept_and_old_frames_dropped(self, tmp_path: Path) -> None:
        folder = tmp_path / "stack"
        write_frames(FrameStack(_moduli((1, 3, 1, 4, 4), 8, seed=1), [1.0, 4.0, 16.0], 8), folder)
        (folder / "notes.txt").write_text("scene lit from the left")
        (folder / "raw").mkdir()
        (folder / "raw" / "dump.bin").write_bytes(b"\0\1")
        new = FrameStack(_moduli((1, 2, 1, 4, 4), 8, seed=2), [2.0, 8.0], 8)
        write_frames(new, folder)
        names = sorted(p.name for p in folder.iterdir())
        assert names == ["frame_b000_m00.exr", "frame_b000_m01.exr", "frames.json", "notes.txt", "raw"]
        assert (folder / "notes.txt").read_text() == "scene lit from the left"
        assert (folder / "raw" / "dump.bin").read_bytes() == b"\0\1"
        assert FileSensor(folder).read() == new and _hidden(tmp_path) == []

    def test_symlinked_folder_stays_a_link(self, tmp_path: Path) -> None:
        (tmp_path / "real").mkdir()
        (tmp_path / "link").symlink_to(tmp_path / "real", target_is_directory=True)
        stack = FrameStack(_moduli((1, 2, 1, 4, 4), 8), [1.0, 8.0], 8)
        write_frames(stack, tmp_path / "link")
        assert (tmp_path / "link").is_symlink() and FileSensor(tmp_path / "real").read() == stack

    def test_writing_into_the_working_folder(self, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
        folder = tmp_path / "stack"
        folder.mkdir()
        monkeypatch.chdir(folder)
        stack = FrameStack(_moduli((1, 2, 1, 4, 4), 8), [1.0, 8.0], 8)
        write_frames(stack, ".")
        write_frames(stack, ".")
        assert FileSensor(".").read() == stack  # "." is the new folder, not the deleted old one


class TestManifestPathsStayInside:
    """Regression: FileSensor followed frame paths in frames.json that point outside the stack folder."""

    @pytest.mark.parametrize("name", ["../outside.png", "sub/../../outside.png", "/etc/outside.png"])
    def test_paths_leading_out_are_refused_naming_them(self, tmp_path: Path, name: str) -> None:
        folder = tmp_path / "stack"
        folder.mkdir()
        write_image(tmp_path / "outside.png", torch.zeros(1, 2, 2), {"exposure": 1.0, "bits": 8})
        (folder / MANIFEST).write_text(json.dumps({"bits": 8, "frames": [{"file": name, "exposure": 1.0}]}))
        with pytest.raises(ValueError, match=f"frame file '{name}' points outside the stack folder"):
            FileSensor(folder)

    def test_paths_inside_subfolders_are_fine(self, tmp_path: Path) -> None:
        (tmp_path / "sub").mkdir()
        write_image(tmp_path / "sub" / "a.png", torch.full((1, 2, 2), 3.0), {"exposure": 2.0, "bits": 8})
        (tmp_path / MANIFEST).write_text(json.dumps({"bits": 8, "frames": ["sub/./a.png"]}))
        stack = FileSensor(tmp_path).read()
        assert stack.exposures.tolist() == [2.0] and float(stack.moduli.max()) == 3.0


def test_raw_format_sizes_must_be_integers() -> None:
    with pytest.raises(TypeError, match="RawFormat.width must be an integer; got '4'"):
        RawFormat(width="4", height=4, bits=12)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="RawFormat.sample_bytes must be 1, 2 or 4"):
        RawFormat(width=4, height=4, bits=8, sample_bytes=True)  # type: ignore[arg-type]


class TestFrameMetadata:
    def test_lookups_find_the_first_key_present(self) -> None:
        assert frame_exposure({"exposure": 2, "ExposureTime": 4}, "x") == 2.0
        assert frame_exposure({"exposure": None, "exposure_time": 0.5}, "x") == 0.5
        assert frame_bits({"bits": 12.0}, "x") == 12 and frame_bits({"bit_depth": 10}, "x") == 10
        assert frame_exposure({}, "x") is None and frame_bits({"bits": None}, "x") is None

    @pytest.mark.parametrize("value", [0, -2, float("nan"), float("inf"), "fast", True])
    def test_a_bad_exposure_names_its_source(self, value: object) -> None:
        with pytest.raises(ValueError, match="exposure from the metadata of a.png"):
            frame_exposure({"exposure": value}, "the metadata of a.png")

    @pytest.mark.parametrize("value", [8.7, True, 0, 54, "8"])
    def test_a_bad_bit_depth_names_its_source(self, value: object) -> None:
        with pytest.raises(ValueError, match="bits from a.json"):
            frame_bits({"bits": value}, "a.json")

    def test_file_sensor_reads_what_the_lookups_find(self, tmp_path: Path) -> None:
        write_image(tmp_path / "f.png", torch.tensor([[[3.0, 200.0]]]), {"bit_depth": 8, "ExposureTime": 4})
        stack = FileSensor(tmp_path).read()
        assert (stack.bits, stack.exposures.tolist()) == (8, [4.0])

    def test_stack_files_are_the_manifest_and_its_frames(self, tmp_path: Path) -> None:
        stack = FrameStack(torch.zeros(2, 1, 2, 2), [1.0, 4.0], bits=8)
        write_frames(stack, tmp_path / "s")
        (tmp_path / "s" / "notes.txt").write_text("mine")
        assert stack_files(tmp_path / "s") == {"frames.json", "frame_b000_m00.exr", "frame_b000_m01.exr"}
        assert stack_files(tmp_path / "missing") == {"frames.json"}


class TestManifestAgreesWithTheFrames:
    """The manifest never silently overrides what the frames record: a disagreement or an unknown value is refused,
    naming both sides (regression: frames.json with "bits": 9 over 8-bit frames decoded up to 95% wrong)."""

    @staticmethod
    def _stack(folder: Path, cfa: str | None = None) -> dict:
        shape = (1, 3, 1, 4, 4)
        stack = FrameStack(_moduli(shape, 8), [1.0, 16.0, 256.0], 8, cfa=cfa)
        write_frames(stack, folder, format="png")
        return json.loads((folder / MANIFEST).read_text())

    def test_manifest_bits_that_disagree_with_the_frames_are_refused(self, tmp_path: Path) -> None:
        manifest = self._stack(tmp_path)
        (tmp_path / MANIFEST).write_text(json.dumps(dict(manifest, bits=9)))
        with pytest.raises(ValueError, match=r"frames\.json.*bits 9.*frame_b000_m00\.png.*bits 8"):
            FileSensor(tmp_path).read()
        assert FileSensor(tmp_path, bits=8).read().bits == 8  # the argument is the caller's own override

    def test_manifest_cfa_that_disagrees_with_the_frames_is_refused(self, tmp_path: Path) -> None:
        manifest = self._stack(tmp_path, cfa="RGGB")
        metadata = {**manifest["metadata"], "cfa": "GBRG"} if "cfa" in manifest["metadata"] else manifest["metadata"]
        (tmp_path / MANIFEST).write_text(json.dumps(dict(manifest, cfa="GBRG", metadata=metadata)))
        with pytest.raises(ValueError, match=r"frames\.json.*cfa 'GBRG'.*frame_b000_m00\.png.*cfa 'RGGB'"):
            FileSensor(tmp_path).read()

    def test_a_frame_exposure_that_disagrees_with_the_frame_is_refused(self, tmp_path: Path) -> None:
        manifest = self._stack(tmp_path)
        manifest["frames"][1]["exposure"] = 8.0
        manifest["exposures"] = [1.0, 8.0, 256.0]
        (tmp_path / MANIFEST).write_text(json.dumps(manifest))
        with pytest.raises(ValueError, match=r"frames\.json.*exposure 8.*frame_b000_m01\.png.*exposure 16"):
            FileSensor(tmp_path).read()

    @pytest.mark.parametrize("name", ["int37", "float128", 32])
    def test_an_unknown_dtype_is_refused(self, tmp_path: Path, name: object) -> None:
        manifest = self._stack(tmp_path)
        (tmp_path / MANIFEST).write_text(json.dumps(dict(manifest, dtype=name)))
        with pytest.raises(ValueError, match=rf"frames\.json: dtype must be one of .*; got {name!r}"):
            FileSensor(tmp_path).read()

    def test_a_shape_that_disagrees_with_the_frames_is_refused(self, tmp_path: Path) -> None:
        manifest = self._stack(tmp_path)
        (tmp_path / MANIFEST).write_text(json.dumps(dict(manifest, shape=[1, 3, 1, 8, 8])))
        with pytest.raises(ValueError, match=r"frames\.json: shape \[1, 3, 1, 8, 8\] disagrees with the frames'"):
            FileSensor(tmp_path).read()

    @pytest.mark.parametrize("removed, exposure", [(1, "16"), (2, "256"), (0, "1")])
    def test_a_missing_frame_names_its_exposure(self, tmp_path: Path, removed: int, exposure: str) -> None:
        manifest = self._stack(tmp_path)
        del manifest["frames"][removed]
        (tmp_path / MANIFEST).write_text(json.dumps(manifest))
        with pytest.raises(ValueError, match=rf"frames\.json: no frame for exposure {exposure}\b"):
            FileSensor(tmp_path).read()

    def test_a_missing_frame_of_a_hand_written_manifest_names_its_exposure(self, tmp_path: Path) -> None:
        manifest = self._stack(tmp_path)
        frames = [{"file": f["file"]} for i, f in enumerate(manifest["frames"]) if i != 1]
        (tmp_path / MANIFEST).write_text(json.dumps({"bits": 8, "exposures": [1, 16, 256], "frames": frames}))
        with pytest.raises(ValueError, match=r"frames\.json: no frame for exposure 16\b"):
            FileSensor(tmp_path).read()

    def test_agreeing_manifests_still_read(self, tmp_path: Path) -> None:
        self._stack(tmp_path, cfa="BGGR")
        stack = FileSensor(tmp_path).read()
        assert stack.bits == 8 and stack.cfa == "BGGR" and stack.exposures.tolist() == [1.0, 16.0, 256.0]
