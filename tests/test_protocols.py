"""Tests for torch_modulo/protocols.py: the measurement protocols of BENCHMARKS.md."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from torch_modulo import io, protocols


class TestDownsampleArea:
    def test_smallest_integer_factor_and_dropped_remainder(self) -> None:
        image = torch.arange(7 * 10, dtype=torch.float64).view(1, 7, 10)
        out = protocols.downsample_area(image, 4)  # factor ceil(10 / 4) = 3 -> (2, 3), last row/column dropped
        assert out.shape == (1, 2, 3)
        assert out[0, 0, 0].item() == pytest.approx(image[0, :3, :3].mean().item())

    def test_no_change_when_small_enough(self) -> None:
        image = torch.rand(3, 4, 5)
        assert protocols.downsample_area(image, 5) is image

    def test_bad_input(self) -> None:
        with pytest.raises(ValueError, match="max_side must be >= 1; got 0"):
            protocols.downsample_area(torch.rand(1, 4, 4), 0)
        with pytest.raises(ValueError, match=r"\(C, H, W\)"):
            protocols.downsample_area(torch.rand(4, 4), 2)


class TestProtocols:
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
