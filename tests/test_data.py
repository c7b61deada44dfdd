"""Tests for torch_modulo.data: HDRFolder (Dataset of radiance maps) and RandomModuloCapture (Kornia)."""

from __future__ import annotations

import math
from pathlib import Path

import kornia.augmentation as K
import pytest
import torch
from torch.utils.data import DataLoader

from torch_modulo import capture_modulo
from torch_modulo.data import HDRFolder, RandomModuloCapture
from torch_modulo.io import write_image
from torch_modulo.radiance import load_radiance
from torch_modulo.sensors import NoiseModel


@pytest.fixture
def scenes(tmp_path: Path) -> Path:
    """Four small radiance maps: two EXR at the top, one HDR and one PFM in a subfolder."""
    g = torch.Generator().manual_seed(0)
    write_image(tmp_path / "b.exr", torch.exp(torch.randn(3, 24, 32, generator=g) * 3))
    write_image(tmp_path / "a.exr", torch.exp(torch.randn(3, 24, 32, generator=g) * 3))
    (tmp_path / "sub").mkdir()
    write_image(tmp_path / "sub" / "c.hdr", torch.exp(torch.randn(3, 24, 32, generator=g)))
    write_image(tmp_path / "sub" / "d.pfm", torch.exp(torch.randn(3, 24, 32, generator=g)))
    (tmp_path / "notes.txt").write_text("not a scene")
    (tmp_path / "e.png").write_bytes(b"")  # not an HDR extension: ignored
    return tmp_path


class TestHDRFolder:
    def test_smoke(self, scenes: Path) -> None:
        ds = HDRFolder(scenes)
        assert len(ds) == 4
        assert [p.name for p in ds.paths] == ["a.exr", "b.exr", "c.hdr", "d.pfm"]
        item = ds[0]
        assert item.shape == (3, 24, 32) and item.dtype == torch.float32
        assert "4 files" in repr(ds)
        assert len(HDRFolder(scenes, recursive=False)) == 2
        assert len(HDRFolder(scenes, extensions=["hdr"])) == 1

    def test_values_cleaned(self, tmp_path: Path) -> None:
        image = torch.tensor([[[1.0, -2.0], [float("nan"), 5.0]], [[float("inf"), 3.0], [0.5, 0.25]]])
        write_image(tmp_path / "x.exr", image)
        item = HDRFolder(tmp_path, channels=None)[0]
        assert item.tolist() == [[[1.0, 0.0], [0.0, 5.0]], [[5.0, 3.0], [0.5, 0.25]]]

    def test_nonfinite_policy_is_the_command_lines(self, tmp_path: Path) -> None:
        image = torch.ones(3, 4, 4)
        image[0, 0, 0], image[1, 1, 1] = float("nan"), float("inf")
        write_image(tmp_path / "x.exr", image)
        assert torch.equal(HDRFolder(tmp_path)[0], load_radiance(tmp_path / "x.exr", channels=3))
        with pytest.raises(ValueError, match=r"x\.exr holds 2 NaN or infinite values \(1 NaN, 1 \+Inf, 0 -Inf\)"):
            HDRFolder(tmp_path, nonfinite="raise")[0]
        with pytest.raises(ValueError, match="nonfinite must be one of 'raise', 'replace'; got 'zero'"):
            HDRFolder(tmp_path, nonfinite="zero")
        write_image(tmp_path / "x.exr", torch.full((3, 4, 4), float("nan")))
        with pytest.raises(ValueError, match=r"x\.exr holds no finite value"):  # nothing to replace them with
            HDRFolder(tmp_path)[0]

    def test_channels(self, tmp_path: Path) -> None:
        grey = torch.rand(1, 4, 4) * 10
        rgba = torch.rand(4, 4, 4) * 10
        write_image(tmp_path / "g.exr", grey)
        write_image(tmp_path / "r.exr", rgba)
        ds = HDRFolder(tmp_path)  # g.exr, r.exr
        assert torch.equal(ds[0], grey.expand(3, -1, -1))
        assert torch.equal(ds[1], rgba[:3])
        lum = HDRFolder(tmp_path, channels=1)[1]
        expected = 0.2126 * rgba[0] + 0.7152 * rgba[1] + 0.0722 * rgba[2]
        assert torch.allclose(lum[0], expected, rtol=1e-6)
        assert HDRFolder(tmp_path, channels=None)[1].shape == (4, 4, 4)

    def test_resize_area_average(self, tmp_path: Path) -> None:
        image = torch.arange(48, dtype=torch.float32).reshape(3, 4, 4)
        write_image(tmp_path / "x.exr", image)
        small = HDRFolder(tmp_path, resize=2)[0]
        expected = image.reshape(3, 2, 2, 2, 2).mean(dim=(2, 4))  # 2x2 block means
        assert torch.allclose(small, expected)
        assert HDRFolder(tmp_path, resize=8)[0].shape == (3, 4, 4)  # never enlarged by an int
        assert HDRFolder(tmp_path, resize=(8, 6))[0].shape == (3, 8, 6)  # exact size on request
        assert HDRFolder(tmp_path, resize=(2, 4))[0].shape == (3, 2, 4)

    def test_resize_keeps_aspect(self, scenes: Path) -> None:
        assert HDRFolder(scenes, resize=16)[0].shape == (3, 12, 16)

    def test_crop(self, tmp_path: Path) -> None:
        image = torch.arange(3 * 6 * 8, dtype=torch.float32).reshape(3, 6, 8)
        write_image(tmp_path / "x.exr", image)
        assert torch.equal(HDRFolder(tmp_path, crop=(2, 4))[0], image[:, 2:4, 2:6])
        torch.manual_seed(0)
        ds = HDRFolder(tmp_path, crop=3, random_crop=True)
        corners = set()
        for _ in range(20):
            item = ds[0]
            top, left = divmod(int(item[0, 0, 0]), 8)
            assert torch.equal(item, image[:, top : top + 3, left : left + 3])
            corners.add((top, left))
        assert len(corners) > 3
        with pytest.raises(ValueError, match=r"x\.exr is 6x8 after resizing, smaller than the crop 7x7"):
            HDRFolder(tmp_path, crop=7)[0]

    def test_normalize(self, scenes: Path) -> None:
        item = HDRFolder(scenes, normalize=1000.0)[1]
        flat = item.flatten()
        assert float(flat.kthvalue(math.ceil(0.999 * flat.numel())).values) == pytest.approx(1000.0, rel=1e-5)

    def test_return_path_transform_dtype(self, scenes: Path) -> None:
        ds = HDRFolder(scenes, return_path=True, transform=lambda x: x * 2, dtype=torch.float64)
        item, path = ds[-1]
        assert path.endswith("d.pfm") and item.dtype == torch.float64
        assert torch.equal(item, HDRFolder(scenes, dtype=torch.float64)[3] * 2)
        with pytest.raises(IndexError, match="index 4 out of range for 4 files"):
            ds[4]

    def test_hidden_folders_are_skipped(self, tmp_path: Path) -> None:
        for name in (".ipynb_checkpoints/scene-checkpoint.exr", ".scene.tmp-1-ab/radiance.exr", "scene.exr"):
            (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
            write_image(tmp_path / name, torch.ones(3, 4, 4))
        assert [p.name for p in HDRFolder(tmp_path).paths] == ["scene.exr"]

    def test_half_precision_refuses_radiance_beyond_its_range(self, tmp_path: Path) -> None:
        write_image(tmp_path / "big.exr", torch.full((3, 4, 4), 70000.0))
        with pytest.raises(ValueError, match=r"big\.exr: radiance reaches 70000, beyond the largest torch.float16"):
            HDRFolder(tmp_path, dtype=torch.float16)[0]
        assert float(HDRFolder(tmp_path, dtype=torch.float16, normalize=1000.0)[0].max()) == 1000.0
        assert float(HDRFolder(tmp_path, dtype=torch.bfloat16)[0].max()) == 70144.0  # within bfloat16's range

    @pytest.mark.parametrize("flag", ["recursive", "random_crop", "return_path"])
    def test_flags_must_be_bools(self, scenes: Path, flag: str) -> None:
        with pytest.raises(TypeError, match=f"{flag} must be a bool; got 'no'"):
            HDRFolder(scenes, **{flag: "no"})

    def test_errors(self, tmp_path: Path, scenes: Path) -> None:
        with pytest.raises(FileNotFoundError, match="missing"):
            HDRFolder(tmp_path / "missing")
        (tmp_path / "empty").mkdir()
        with pytest.raises(ValueError, match=r"no files ending in \.exr, \.hdr, \.pfm, \.tif, \.tiff in .*empty"):
            HDRFolder(tmp_path / "empty")
        with pytest.raises(ValueError, match="crop must hold positive ints; got 0"):
            HDRFolder(scenes, crop=0)
        with pytest.raises(TypeError, match=r"resize must be an int or a pair \(height, width\); got 'big'"):
            HDRFolder(scenes, resize="big")  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="resize must be positive; got -3"):
            HDRFolder(scenes, resize=-3)
        with pytest.raises(ValueError, match="channels must be 1, 3 or None; got 2"):
            HDRFolder(scenes, channels=2)
        with pytest.raises(ValueError, match="normalize must be a positive number or None; got 0"):
            HDRFolder(scenes, normalize=0)
        with pytest.raises(TypeError, match="transform must be callable; got int"):
            HDRFolder(scenes, transform=3)  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="dtype must be a floating torch dtype; got torch.int64"):
            HDRFolder(scenes, dtype=torch.int64)

    def test_unreadable_item_names_file(self, tmp_path: Path) -> None:
        write_image(tmp_path / "good.exr", torch.ones(3, 4, 4))
        (tmp_path / "broken.exr").write_bytes(b"\x76\x2f\x31\x01 truncated")
        ds = HDRFolder(tmp_path)
        with pytest.raises(OSError, match=r"broken\.exr"):
            ds[0]
        assert ds[1].shape == (3, 4, 4)

    def test_dataloader_two_workers(self, scenes: Path) -> None:
        ds = HDRFolder(scenes, resize=(16, 16))
        batches = list(DataLoader(ds, batch_size=2, num_workers=2))
        assert [b.shape for b in batches] == [(2, 3, 16, 16), (2, 3, 16, 16)]
        assert torch.equal(torch.cat(batches), torch.stack([ds[i] for i in range(4)]))

    def test_shared_scenes(self, shared_hdr: Path) -> None:
        ds = HDRFolder(shared_hdr / "light-probes", resize=64)
        assert len(ds) == 5
        for i in range(len(ds)):
            item = ds[i]
            assert item.shape[0] == 3 and max(item.shape[1:]) == 64
            assert bool(torch.isfinite(item).all()) and float(item.min()) >= 0 and float(item.max()) > 0


class TestRandomModuloCapture:
    def test_empty_batch(self) -> None:
        # kornia's base class raised "cannot reshape tensor of 0 elements" on a batch of 0
        aug = RandomModuloCapture(exposure=(1.0, 4.0), bits=8)
        out = aug(torch.rand(0, 3, 8, 8))
        assert out.shape == (0, 3, 8, 8) and aug.exposure is not None and aug.exposure.shape == (0,)
        assert K.AugmentationSequential(aug)(torch.rand(0, 3, 8, 8)).shape == (0, 3, 8, 8)
        assert aug(torch.rand(0, 3, 8, 8), params={"exposure": torch.empty(0)}).shape == (0, 3, 8, 8)

    @pytest.mark.parametrize("flag", ["log_uniform", "straight_through"])
    def test_flags_must_be_bools(self, flag: str) -> None:
        with pytest.raises(TypeError, match=f"{flag} must be a bool; got 'no'"):
            RandomModuloCapture(**{flag: "no"})

    def test_smoke_equals_capture(self) -> None:
        torch.manual_seed(0)
        radiance = torch.rand(5, 3, 8, 8) * 1000  # far outside [0, 1]: nothing may clamp it
        aug = RandomModuloCapture(exposure=(0.5, 40.0), bits=8)
        out = aug(radiance)
        tau = aug.exposure
        assert tau is not None and tau.shape == (5,) and bool(((tau >= 0.5) & (tau <= 40.0)).all())
        assert torch.equal(out, capture_modulo(radiance, tau, bits=8))
        assert len(set(tau.tolist())) == 5  # one exposure per sample
        assert torch.equal(aug(radiance, params=aug._params), out)  # Kornia's replay of parameters
        assert "RandomModuloCapture(exposure=(0.5, 40.0), bits=8" in repr(aug)

    def test_exposure_distribution(self) -> None:
        torch.manual_seed(1)
        x = torch.ones(4000, 1, 1, 1)
        log_aug = RandomModuloCapture(exposure=(1.0, 1024.0))
        log_aug(x)
        logs = torch.log2(log_aug.exposure)
        assert abs(float(logs.mean()) - 5.0) < 0.2 and abs(float(logs.std()) - 10 / math.sqrt(12)) < 0.15
        lin_aug = RandomModuloCapture(exposure=(1.0, 1024.0), log_uniform=False)
        lin_aug(x)
        assert abs(float(lin_aug.exposure.mean()) - 512.5) < 20

    def test_same_on_batch_and_fixed(self) -> None:
        aug = RandomModuloCapture(exposure=(1.0, 100.0), same_on_batch=True)
        aug(torch.ones(6, 1, 2, 2))
        assert len(set(aug.exposure.tolist())) == 1
        fixed = RandomModuloCapture(exposure=3.0, bits=4)
        out = fixed(torch.full((2, 1, 1, 2), 7.0))
        assert fixed.exposure.tolist() == [3.0, 3.0] and out.flatten().tolist() == [5.0] * 4  # 21 mod 16

    def test_keepdim_and_dtype(self) -> None:
        x = torch.rand(3, 4, 5, dtype=torch.float64) * 50
        copy = x.clone()
        out = RandomModuloCapture(keepdim=True)(x)
        assert out.shape == (3, 4, 5) and out.dtype == torch.float64
        assert torch.equal(x, copy)
        assert RandomModuloCapture()(x).shape == (1, 3, 4, 5)

    def test_in_augmentation_sequential(self) -> None:
        torch.manual_seed(2)
        radiance = torch.rand(4, 3, 10, 12) * 5000
        capture = RandomModuloCapture(exposure=(1.0, 8.0), bits=8)
        pipeline = K.AugmentationSequential(K.RandomHorizontalFlip(p=1.0), K.CenterCrop(8), capture)
        out = pipeline(radiance)
        flipped = torch.flip(radiance, dims=[-1])[..., 1:9, 2:10]
        assert out.shape == (4, 3, 8, 8)
        assert torch.equal(out, capture_modulo(flipped, capture.exposure, bits=8))

    def test_noise(self) -> None:
        torch.manual_seed(3)
        radiance = torch.full((3, 1, 32, 32), 200.0)
        aug = RandomModuloCapture(exposure=(2.0, 4.0), bits=8, noise=NoiseModel(read_noise=2.0))
        out = aug(radiance)
        clean = capture_modulo(radiance, aug.exposure, bits=8)
        assert not torch.equal(out, clean)
        assert torch.equal(out, torch.floor(out)) and float(out.min()) >= 0 and float(out.max()) <= 255
        # shot noise on ~600 counts: a std of ~25 counts per pixel
        assert 10 < float(out[0].std()) < 60

    def test_straight_through_gradient(self) -> None:
        x = (torch.rand(2, 1, 3, 3, dtype=torch.float64) * 100).requires_grad_()
        aug = RandomModuloCapture(exposure=(2.0, 5.0), straight_through=True)
        aug(x).sum().backward()
        assert torch.allclose(x.grad, aug.exposure.double().view(-1, 1, 1, 1).expand_as(x))

    def test_errors(self) -> None:
        with pytest.raises(ValueError, match=r"0 < low <= high.*got \(4.0, 2.0\)"):
            RandomModuloCapture(exposure=(4.0, 2.0))
        with pytest.raises(ValueError, match=r"got \(0.0, 2.0\)"):
            RandomModuloCapture(exposure=(0.0, 2.0))
        with pytest.raises(TypeError, match=r"number or a pair \(low, high\); got \[1, 2, 3\]"):
            RandomModuloCapture(exposure=[1, 2, 3])  # type: ignore[arg-type]
        with pytest.raises(TypeError, match="noise must be a NoiseModel or None; got str"):
            RandomModuloCapture(noise="poisson")  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="straight_through=True needs noise=None"):
            RandomModuloCapture(noise=NoiseModel(), straight_through=True)
        with pytest.raises(ValueError, match="bits must be >= 1; got 0"):
            RandomModuloCapture(bits=0)
        with pytest.raises(ValueError, match="radiance must be >= 0; got min -1.0"):
            RandomModuloCapture()(-torch.ones(1, 1, 2, 2))

    def test_dataloader_workers(self, scenes: Path) -> None:
        """As a per-item transform inside two DataLoader workers, and on batches in the loop."""
        torch.manual_seed(4)
        ds = HDRFolder(scenes, resize=(8, 8), normalize=200.0, transform=RandomModuloCapture(bits=6, keepdim=True))
        batches = list(DataLoader(ds, batch_size=2, num_workers=2))
        stacked = torch.cat(batches)
        assert stacked.shape == (4, 3, 8, 8)
        assert torch.equal(stacked, torch.floor(stacked)) and float(stacked.max()) < 64
        loop_capture = RandomModuloCapture(exposure=(1.0, 16.0), bits=8)
        for radiance in DataLoader(HDRFolder(scenes, resize=(8, 8)), batch_size=2, num_workers=2):
            moduli = loop_capture(radiance)
            assert torch.equal(moduli, capture_modulo(radiance, loop_capture.exposure, bits=8))


class TestHDRFolderFormatsAndBadFiles:
    def test_reads_the_formats_the_command_line_reads(self, scenes: Path) -> None:
        # Regression: HDRFolder collected .exr .hdr .pfm only, while `torch-modulo simulate` also reads TIFF.
        from torch_modulo.radiance import RADIANCE_EXTENSIONS

        write_image(scenes / "f.tif", torch.rand(3, 24, 32) * 50, dtype="float")
        dataset = HDRFolder(scenes)
        assert [p.name for p in dataset.paths] == ["a.exr", "b.exr", "f.tif", "c.hdr", "d.pfm"]
        assert set(RADIANCE_EXTENSIONS) <= set(dataset.extensions)

    def test_display_referred_files_are_refused_unless_linear(self, tmp_path: Path) -> None:
        write_image(tmp_path / "photo.tif", torch.full((3, 4, 4), 200.0), dtype="uint8")
        with pytest.raises(ValueError, match=r"photo\.tif holds 8-bit integers, display-referred"):
            HDRFolder(tmp_path)[0]
        assert HDRFolder(tmp_path, linear=True)[0].max() == 200.0

    def test_skip_bad_keeps_a_dataloader_going_and_reports(self, scenes: Path) -> None:
        # Regression: one unreadable file stopped the whole DataLoader.
        (scenes / "broken.exr").write_bytes(b"not an EXR" * 20)
        with pytest.raises(OSError, match=r"broken\.exr"):
            list(DataLoader(HDRFolder(scenes, crop=8), batch_size=1))
        dataset = HDRFolder(scenes, crop=8, skip_bad=True)
        with pytest.warns(UserWarning, match=r"HDRFolder: skipped .*broken\.exr \(OSError: .*\); gave .*c\.hdr"):
            batches = list(DataLoader(dataset, batch_size=2))
        assert sum(b.shape[0] for b in batches) == len(dataset) == 5
        assert list(dataset.skipped) == [str(scenes / "broken.exr")]

    def test_skip_bad_with_nothing_good_raises(self, tmp_path: Path) -> None:
        (tmp_path / "broken.exr").write_bytes(b"not an EXR" * 20)
        with pytest.raises(ValueError, match=r"every file of .* failed to load; the last: .*broken\.exr"):
            HDRFolder(tmp_path, skip_bad=True)[0]

    def test_skip_bad_must_be_a_flag(self, scenes: Path) -> None:
        with pytest.raises(TypeError, match="skip_bad must be a bool"):
            HDRFolder(scenes, skip_bad="yes")  # type: ignore[arg-type]
