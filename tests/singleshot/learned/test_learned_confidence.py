"""Tests of the learned single-shot method: the confidence (confidence.py): the weakest pair on the path, the
function and its layer."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from learned_helpers import scene  # tests/singleshot/learned/

from torch_modulo.cfa import interpolate_wrapped, mosaic
from torch_modulo.singleshot import unwrap_single
from torch_modulo.singleshot.learned import (
    LearnedConfidence,
    decode_jumps,
    learned_confidence,
    learned_k,
)

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/singleshot/conftest.py


class TestConfidence:
    def test_weakest_pair_on_the_path(self) -> None:
        m = np.array([[10, 20, 30, 40]])
        jump = np.zeros((2, 1, 4), dtype=np.int16)
        cost = np.zeros((2, 1, 4), dtype=np.float32)
        cost[0, 0] = [0.001, 0.001, 2.0, 0.0]  # the pair (2, 3) is unsure
        k, confidence = decode_jumps(m, jump, cost, 8)
        assert k.tolist() == [[0, 0, 0, 0]]
        assert np.allclose(confidence, np.exp(-np.array([[0.0, 0.001, 0.001, 2.0]])))

    @pytest.mark.parametrize("shape", [(24, 20), (3, 24, 20), (2, 1, 24, 20)])
    def test_learned_confidence_shapes_and_batches(self, shape: tuple, device: torch.device) -> None:
        g = torch.Generator().manual_seed(0)
        modulus = torch.randint(0, 256, shape, generator=g).double().to(device)
        confidence = learned_confidence(modulus)
        assert confidence.shape == modulus.shape and confidence.device == modulus.device
        assert bool(((confidence > 0) & (confidence <= 1)).all())
        if len(shape) == 4:
            single = torch.stack([learned_confidence(m) for m in modulus])
            assert torch.equal(confidence, single)

    def test_info_confidence_is_the_same_runs(self, device: torch.device) -> None:
        g = torch.Generator().manual_seed(1)
        batch = torch.from_numpy(np.stack([scene(40, s) for s in range(3)]) % 256)[None].repeat(2, 1, 1, 1)
        batch[1] = torch.randint(0, 256, batch.shape[1:], generator=g).double()
        batch = batch.float().to(device)
        restored, info = unwrap_single(batch, 8, return_info=True)
        assert info.confidence is not None
        assert info.confidence.shape == batch.shape and info.confidence.dtype == batch.dtype
        assert info.confidence.device == batch.device
        assert torch.equal(info.confidence, learned_confidence(batch))
        assert bool((info.confidence[0] > info.confidence[1].mean()).all())  # smooth scenes beat noise
        # the other methods have no confidence of their own
        assert unwrap_single(batch[0, 0], 8, method="guided", return_info=True)[1].confidence is None
        assert unwrap_single(batch[0, 0], 8, method="lsq", return_info=True)[1].confidence is None
        # a mosaic: the guide's confidence at each photosite, with the mosaic's shape
        guide = interpolate_wrapped(batch[0, :1], "RGGB", 8)
        _, mosaic_info = unwrap_single(batch[0, :1], 8, cfa="RGGB", return_info=True, max_cuts=0)
        expected = mosaic(learned_confidence(guide), "RGGB")
        assert torch.equal(mosaic_info.confidence, expected.reshape(batch[0, :1].shape))

    def test_learned_confidence_of_empty_inputs(self) -> None:
        with pytest.raises(ValueError, match=r"empty image; got shape \(1, 3, 0, 4\)"):
            learned_confidence(torch.zeros(1, 3, 0, 4))
        for shape in ((1, 0, 4, 4), (0, 3, 4, 4)):  # no channels, no images: nothing to be unsure of
            assert learned_confidence(torch.zeros(shape)).shape == shape

    def test_learned_confidence_is_the_decoders(self) -> None:
        truth = np.stack([scene(40, s) for s in range(3)])
        modulus = torch.from_numpy(truth % 256)
        _, expected = learned_k((truth % 256).astype(np.int64), 8)
        assert np.allclose(learned_confidence(modulus).numpy(), expected)
        with pytest.raises(ValueError, match="weights"):
            learned_confidence(modulus, weights="/nonexistent.pt")
        with pytest.raises(ValueError, match="integers"):
            learned_confidence(modulus + 0.5)


class TestLearnedConfidenceModule:
    def test_module_equals_function(self) -> None:
        m = torch.from_numpy(scene(24) % 256).float()
        layer = LearnedConfidence(bits=8, tile=16)
        assert torch.equal(layer(m), learned_confidence(m, 8, tile=16))

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            ({"bits": 0}, ValueError, "bits"),
            ({"tile": 2}, ValueError, "tile must be 0 .* got 2"),
            ({"augment": "yes"}, TypeError, "augment"),
            ({"weights": 3}, TypeError, "weights"),
        ],
    )
    def test_bad_arguments_are_named(self, kwargs: dict, error: type, match: str) -> None:
        with pytest.raises(error, match=match):
            LearnedConfidence(**kwargs)
