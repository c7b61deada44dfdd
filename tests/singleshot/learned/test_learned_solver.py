"""Tests of the learned single-shot method: the method through unwrap_single (solver.py): shapes, devices, batches,
consistency with the modulus."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from learned_helpers import scene  # tests/singleshot/learned/

from torch_modulo.singleshot import unwrap_single

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/singleshot/conftest.py


class TestLearnedUnwrap:
    @pytest.mark.parametrize("shape", [(20, 24), (1, 20, 24), (3, 20, 24), (2, 3, 20, 24), (1, 2, 20, 24)])
    def test_cardinality(self, shape: tuple, device: torch.device, dtype: torch.dtype) -> None:
        g = torch.Generator().manual_seed(0)
        modulus = torch.randint(0, 256, shape, generator=g).to(device=device, dtype=dtype)
        out = unwrap_single(modulus, method="learned", workers=1)
        assert out.shape == modulus.shape and out.dtype == dtype and out.device == modulus.device

    def test_consistent_with_modulus(self) -> None:
        truth = np.stack([scene(40, s) for s in range(3)])
        modulus = torch.from_numpy(truth % 256)
        out = unwrap_single(modulus, method="learned", max_cuts=2, workers=1)
        k = (out - modulus) / 256
        assert torch.equal(k, torch.round(k)) and bool((k >= 0).all())
        assert torch.equal(torch.remainder(out, 256), modulus)

    def test_batch_equals_per_image(self) -> None:
        truth = torch.from_numpy(np.stack([np.stack([scene(32, 3 * b + c) for c in range(3)]) for b in range(2)]))
        modulus = truth % 256
        batch = unwrap_single(modulus, method="learned", workers=1)
        single = torch.stack([unwrap_single(m, method="learned", workers=1) for m in modulus])
        assert torch.equal(batch, single)
        assert torch.equal(unwrap_single(modulus[:0], method="learned"), modulus[:0])

    def test_input_untouched(self) -> None:
        modulus = torch.from_numpy(scene(24) % 256)
        before = modulus.clone()
        unwrap_single(modulus, method="learned")
        assert torch.equal(modulus, before)
