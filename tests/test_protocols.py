"""Tests for torch_modulo/protocols.py: scenes, protocols A, A10 and B, and their scores."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from torch_modulo import exact_k_share, io, protocols


class TestDownsampleArea:
    def test_smallest_integer_factor_and_dropped_remainder(self) -> None:
        image = torch.arange(7 * 10, dtype=torch.float64).view(1, 7, 10)
        out = protocols.downsample_area(image, 4)  # factor ceil(10 / 4) = 3 -> (2, 3), last row/column dropped
        assert out.shape == (1, 2, 3)
        assert out[0, 0, 0].item() == pytest.approx(image[0, :3, :3].mean().item())

    def test_a_side_shorter_than_the_factor_becomes_one_pixel(self) -> None:
        strip = torch.rand(3, 3, 2000, dtype=torch.float64)  # factor 4 > 3 rows: it was cut to (3, 0, 500)
        out = protocols.downsample_area(strip, 512)
        assert out.shape == (3, 1, 500)
        torch.testing.assert_close(out[:, 0, 0], strip[:, :, :4].mean(dim=(1, 2)))
        assert protocols.downsample_area(strip.transpose(1, 2), 512).shape == (3, 500, 1)

    def test_no_change_when_small_enough(self) -> None:
        image = torch.rand(3, 4, 5)
        assert protocols.downsample_area(image, 5) is image

    def test_bad_input(self) -> None:
        with pytest.raises(ValueError, match="max_side must be >= 1; got 0"):
            protocols.downsample_area(torch.rand(1, 4, 4), 0)
        with pytest.raises(ValueError, match=r"\(C, H, W\)"):
            protocols.downsample_area(torch.rand(4, 4), 2)


class TestProtocols:
    @pytest.mark.parametrize("bad", [math.nan, math.inf])
    def test_non_finite_radiance_is_refused(self, bad: float) -> None:
        image = torch.tensor([[[1.0, bad]]])
        for protocol in (protocols.protocol_a, protocols.protocol_b):
            with pytest.raises(ValueError, match="image must be finite"):
                protocol(image)
        with pytest.raises(TypeError, match="share must be a number"):
            protocols.protocol_b(torch.rand(1, 2, 2), share="x")  # type: ignore[arg-type]

    def test_protocol_a_puts_the_percentile_at_the_peak(self) -> None:
        gen = torch.Generator().manual_seed(0)
        image = torch.rand(3, 64, 64, generator=gen, dtype=torch.float64) * 10
        counts = protocols.protocol_a(image)
        assert counts.shape == (1, 64, 64)
        assert float(counts.max()) == 4095.0
        assert float((counts >= 4095).double().mean()) == pytest.approx(0.001, abs=0.002)
        assert torch.equal(counts, torch.floor(counts))

    def test_protocol_b_rolls_over_the_requested_share(self) -> None:
        gen = torch.Generator().manual_seed(1)
        image = torch.rand(3, 32, 32, generator=gen, dtype=torch.float64) ** 4
        counts = protocols.protocol_b(image, share=0.3)
        rolled = float((counts >= 256).any(dim=0).double().mean())
        assert rolled == pytest.approx(0.3, abs=0.01)
        assert float(counts.max()) <= 4095.0

    def test_bad_input(self) -> None:
        with pytest.raises(ValueError, match="1 or 3 channels; got 2"):
            protocols.protocol_a(torch.rand(2, 4, 4))
        with pytest.raises(ValueError, match="share must be in"):
            protocols.protocol_b(torch.rand(3, 4, 4), share=1.5)
        with pytest.raises(TypeError, match="floating-point"):
            protocols.protocol_a(torch.ones(3, 4, 4, dtype=torch.int64))

    def test_load_scene_zeroes_negatives_and_lists_scenes(self, tmp_path: Path) -> None:
        image = torch.tensor([[[-1.0, 2.0], [3.0, float("nan")]]]).expand(3, -1, -1).contiguous()
        io.write_image(tmp_path / "a.exr", image)
        (tmp_path / "notes.txt").write_text("not a scene")
        assert protocols.list_scenes(tmp_path) == [tmp_path / "a.exr"]
        loaded = protocols.load_scene(tmp_path / "a.exr", max_side=None)
        assert loaded.dtype == torch.float64
        assert loaded[0].tolist() == [[0.0, 2.0], [3.0, 0.0]]


class TestProtocolA10:
    def test_percentile_at_1023(self) -> None:
        gen = torch.Generator().manual_seed(2)
        image = torch.rand(3, 64, 64, generator=gen, dtype=torch.float64) * 10
        counts = protocols.protocol_a10(image)
        assert counts.shape == (1, 64, 64)
        assert float(counts.max()) == 1023.0
        assert float((counts >= 1023).double().mean()) == pytest.approx(0.001, abs=0.002)
        assert torch.equal(counts, torch.floor(counts))
        assert int(torch.floor(counts / 256).max()) <= 3  # at most four rollover levels on an 8-bit sensor

    def test_is_protocol_a_at_peak_1023(self) -> None:
        image = torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
        assert torch.equal(protocols.protocol_a10(image), protocols.protocol_a(image, peak=1023.0))

    def test_protocol_counts_by_name(self) -> None:
        image = torch.rand(3, 16, 16, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
        assert torch.equal(protocols.protocol_counts(image, "A"), protocols.protocol_a(image))
        assert torch.equal(protocols.protocol_counts(image, "A10"), protocols.protocol_a10(image))
        assert torch.equal(protocols.protocol_counts(image, "B"), protocols.protocol_b(image))
        assert protocols.PROTOCOL_PEAKS == {"A": 4095.0, "A10": 1023.0, "B": 4095.0}
        with pytest.raises(ValueError, match="protocol must be one of 'A', 'A10', 'B'; got 'C'"):
            protocols.protocol_counts(image, "C")


class TestScores:
    truth = torch.tensor([[[10.0, 300.0, 600.0, 20.0], [5.0, 700.0, 1000.0, 40.0]]])  # (1, 2, 4): k 0 1 2 0 / 0 2 3 0

    def test_perfect_and_global_offset(self) -> None:
        for restored in (self.truth, self.truth + 512):
            score = protocols.score_scene(restored, self.truth)
            assert score == protocols.SceneScore(exact_k=1.0, rolled_over_right=1.0, psnr=math.inf)

    def test_rolled_over_right_counts_only_true_k_above_zero(self) -> None:
        restored = self.truth.clone()
        restored[0, 0, 2] -= 256  # one rolled-over value one level low
        restored[0, 1, 0] += 256  # one dark value one level high
        score = protocols.score_scene(restored, self.truth)
        assert score.exact_k == pytest.approx(6 / 8)
        assert score.rolled_over_right == pytest.approx(3 / 4)
        assert protocols.rolled_over_right(restored, self.truth) == score.rolled_over_right
        assert score.psnr == pytest.approx(10 * math.log10(4095.0**2 / (2 * 256.0**2 / 8)))

    def test_nothing_unwrapped_scores_zero_rolled_over(self) -> None:
        modulus = torch.remainder(self.truth, 256)
        assert protocols.rolled_over_right(modulus, self.truth) == 0.0
        assert protocols.score_scene(modulus, self.truth).exact_k == pytest.approx(4 / 8)

    def test_no_rolled_over_value_gives_nan(self) -> None:
        dark = torch.full((1, 3, 3), 7.0)
        assert math.isnan(protocols.rolled_over_right(dark, dark))

    def test_each_channel_aligned_on_its_own(self) -> None:
        truth = torch.stack([self.truth[0], self.truth[0]])  # (2, 2, 4)
        restored = truth + torch.tensor([0.0, 768.0]).view(2, 1, 1)
        assert protocols.score_scene(restored, truth).exact_k == 1.0
        assert torch.equal(protocols.align_offsets(restored, truth), truth)

    def test_agrees_with_exact_k_share(self) -> None:
        gen = torch.Generator().manual_seed(5)
        truth = torch.floor(torch.rand(3, 20, 20, generator=gen, dtype=torch.float64) * 4096)
        restored = torch.remainder(truth, 256) + 256 * torch.randint(0, 16, (3, 20, 20), generator=gen)
        expected = float(exact_k_share(restored[None], truth[None], 8)[0])
        assert protocols.score_scene(restored, truth).exact_k == pytest.approx(expected)

    def test_peak_sets_psnr(self) -> None:
        restored = self.truth + torch.tensor([[[1.0, 0, 0, 0], [0, 0, 0, 0]]])
        a = protocols.score_scene(restored, self.truth, peak=4095.0).psnr
        a10 = protocols.score_scene(restored, self.truth, peak=1023.0).psnr
        assert a - a10 == pytest.approx(20 * math.log10(4095 / 1023))

    def test_bad_input(self) -> None:
        with pytest.raises(ValueError, match="same shape"):
            protocols.score_scene(torch.zeros(2, 2), torch.zeros(2, 3))
        with pytest.raises(TypeError, match="floating-point"):
            protocols.score_scene(torch.zeros(2, 2, dtype=torch.int64), torch.zeros(2, 2))
        with pytest.raises(ValueError, match="NaN"):
            protocols.rolled_over_right(torch.full((2, 2), math.nan), torch.zeros(2, 2))
        with pytest.raises(ValueError, match="bits must be >= 1; got 0"):
            protocols.align_offsets(torch.zeros(2, 2), torch.zeros(2, 2), bits=0)
        with pytest.raises(ValueError, match="peak must be"):
            protocols.score_scene(torch.zeros(2, 2), torch.zeros(2, 2), peak=0.0)


class TestSplit:
    def _folder(self, root: Path) -> Path:
        for rel in (
            "polyhaven-cc0/a.exr",
            "openexr-images/b.exr",
            "hdr-samples/c.hdr",
            "qt-preview/d.hdr",
            "mine.exr",
            "polyhaven-cc0/._a.exr",  # macOS's resource fork beside a scene: hidden, skipped
        ):
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            (root / rel).write_bytes(b"")
        return root

    def test_sources(self) -> None:
        assert protocols.TRAIN_SOURCES == ("openexr-images", "polyhaven-cc0")
        assert protocols.VALIDATION_SOURCES == ("hdr-samples", "hdr-toolbox", "light-probes", "qt-preview")

    def test_list_scenes_by_split(self, tmp_path: Path) -> None:
        root = self._folder(tmp_path)

        def names(split: str) -> list[str]:
            return [p.relative_to(root).as_posix() for p in protocols.list_scenes(root, split)]

        assert names("all") == [
            "hdr-samples/c.hdr",
            "mine.exr",
            "openexr-images/b.exr",
            "polyhaven-cc0/a.exr",
            "qt-preview/d.hdr",
        ]
        assert names("train") == ["openexr-images/b.exr", "polyhaven-cc0/a.exr"]
        assert names("validation") == ["hdr-samples/c.hdr", "qt-preview/d.hdr"]
        assert protocols.scene_split(root / "mine.exr", root) == "other"
        with pytest.raises(ValueError, match="split must be one of"):
            protocols.list_scenes(root, "test")
        with pytest.raises(ValueError, match="must be below folder"):
            protocols.scene_split(tmp_path.parent / "x.exr", root)

    def test_missing_folder_lists_nothing(self, tmp_path: Path) -> None:
        assert protocols.list_scenes(tmp_path / "absent") == []

    def test_dev_scenes_split(self, shared_hdr: Path) -> None:
        assert protocols.DEV_SCENES == shared_hdr
        every = protocols.list_scenes(shared_hdr)
        train = protocols.list_scenes(shared_hdr, "train")
        validation = protocols.list_scenes(shared_hdr, "validation")
        assert sorted(train + validation) == every
        assert all(p.relative_to(shared_hdr).parts[0] in protocols.VALIDATION_SOURCES for p in validation)


class TestParseMethod:
    def test_values(self) -> None:
        assert protocols.parse_method("guided") == ("guided", {})
        assert protocols.parse_method("fast:init=quality,tile=0,denoise=0.7,joint=False") == (
            "fast",
            {"init": "quality", "tile": 0, "denoise": 0.7, "joint": False},
        )

    def test_bad_spec(self) -> None:
        with pytest.raises(ValueError, match="key=value; got 'tile'"):
            protocols.parse_method("fast:tile")
        with pytest.raises(ValueError, match="method name"):
            protocols.parse_method(":tile=0")


def test_downsampling_uses_the_smallest_factor() -> None:
    # 1025 // 2 = 512: factor 2, not ceil(1025 / 512) = 3 (the validation scene belgium is 1025 x 769)
    assert protocols.downsample_area(torch.zeros(1, 769, 1025), 512).shape == (1, 384, 512)
    assert protocols.downsample_area(torch.zeros(1, 10, 10), 3).shape == (1, 3, 3)


def test_load_scene_max_side_zero_is_refused(tmp_path) -> None:
    path = io.write_image(tmp_path / "s.exr", torch.ones(3, 8, 8))
    with pytest.raises(ValueError, match="max_side"):
        protocols.load_scene(path, max_side=0)
    assert protocols.load_scene(path, max_side=None).shape == (3, 8, 8)


def test_protocol_b_checks_and_warns() -> None:
    for bad, message in (
        (dict(peak=float("nan")), "peak must be finite"),
        (dict(period=0), "period must be"),
        (dict(peak=255.5), r"period must be at most floor\(peak\)"),  # nothing could roll over
    ):
        with pytest.raises(ValueError, match=message):
            protocols.protocol_b(torch.rand(3, 4, 4), **bad)
    scene = torch.zeros(3, 10, 10)
    scene[:, 0, :5] = 1.0  # 5% of the pixels above the minimum: 20% cannot roll over
    with pytest.warns(UserWarning, match=r"at most 0.050 of the pixels can roll over"):
        counts = protocols.protocol_b(scene)
    assert float(counts.max()) == 4095.0


def test_protocol_n_refuses_non_finite_values() -> None:
    with pytest.raises(ValueError, match="must be finite"):
        protocols.protocol_n(torch.tensor([1.0, float("inf")]))


def test_the_command_lines_single_shot_psnr_is_aligned_like_its_exact_k() -> None:
    from torch_modulo._scene_rules import count_accuracy

    truth = torch.arange(300.0, 364.0).view(1, 8, 8)  # every value rolled over once
    modulus = torch.remainder(truth, 256.0)
    shifted = modulus + 512.0  # right up to one global rollover
    accuracy = count_accuracy(shifted, modulus, truth, 1.0, 8)
    assert accuracy["exact_k"] == 1.0 and accuracy["psnr_db"] == math.inf  # it was 3 dB, unaligned
