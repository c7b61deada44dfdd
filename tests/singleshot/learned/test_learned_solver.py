"""Tests of the learned single-shot method: the method through unwrap_single (solver.py): shapes, devices, batches,
consistency with the modulus."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from learned_helpers import scene  # tests/singleshot/learned/

from torch_modulo.singleshot import unwrap_single
from torch_modulo.singleshot.learned import MIN_LEVEL_SIDE, learned_k, solver

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


class TestThinImages:
    """Regression: a one-row ramp came back with whole stretches a period low (the level moves, whose head reads 2-D
    context, moved them); planes thinner than MIN_LEVEL_SIDE get no level moves."""

    @pytest.mark.parametrize(("width", "step", "offset"), [(64, 10, 0), (300, 10, 0), (1000, 10, 0), (200, 10, 1000)])
    @pytest.mark.parametrize("shape", ["1xN", "Nx1", "2xN", "4xN"])
    def test_thin_ramps_are_exact(self, shape: str, width: int, step: int, offset: int) -> None:
        rows = {"1xN": 1, "Nx1": 1, "2xN": 2, "4xN": 4}[shape]
        ramp = (torch.arange(float(width)) * step + offset).expand(rows, width).clone()
        if shape == "Nx1":
            ramp = ramp.T.contiguous()
        out = unwrap_single(ramp % 256, 8)
        assert torch.equal(out - out.min(), ramp - ramp.min())

    def test_the_issues_ramp(self) -> None:
        ramp = (torch.arange(64.0) * 10).reshape(1, -1)
        assert torch.equal(unwrap_single(ramp % 256, 8), ramp)

    def test_the_side_decides(self, monkeypatch: pytest.MonkeyPatch) -> None:
        calls = []
        real = solver.region_moves
        monkeypatch.setattr(solver, "region_moves", lambda *a, **kw: calls.append(a[0].shape) or real(*a, **kw))
        moduli = (scene(16)[None] % 256).astype(np.int64)
        for side in (MIN_LEVEL_SIDE - 1, MIN_LEVEL_SIDE):
            learned_k(moduli[:, :side], 8, levels=True)
            learned_k(moduli[:, :, :side], 8, levels=True)
        assert calls == [(MIN_LEVEL_SIDE, 16), (16, MIN_LEVEL_SIDE)]


class TestNetworkThreads:
    """The networks run on ``threads`` torch threads on the CPU (option ``threads``); the result does not depend on
    it, and torch's own thread count comes back after the call."""

    def test_threads_change_no_result_and_are_given_back(self, monkeypatch: pytest.MonkeyPatch) -> None:
        truth = np.stack([scene(40, s) for s in range(3)])
        modulus = torch.from_numpy(truth % 256)
        torch.set_num_threads(2)  # the one_thread fixture gives the original back
        seen = []
        real = solver.predict_jumps
        monkeypatch.setattr(
            solver, "predict_jumps", lambda *a, **kw: seen.append(torch.get_num_threads()) or real(*a, **kw)
        )
        one = unwrap_single(modulus, method="learned", threads=1)
        assert torch.get_num_threads() == 2
        every = unwrap_single(modulus, method="learned", threads=0)
        assert torch.equal(one, every) and seen == [1, 2]
        assert solver.LEARNED_OPTIONS["threads"][0] == solver.NETWORK_THREADS == 0  # all threads unless asked

    def test_threads_restored_when_the_network_raises(self) -> None:
        torch.set_num_threads(2)
        with pytest.raises(RuntimeError, match="boom"), solver.network_threads(1):
            assert torch.get_num_threads() == 1
            raise RuntimeError("boom")
        assert torch.get_num_threads() == 2
        with solver.network_threads(0):
            assert torch.get_num_threads() == 2

    def test_threads_refused(self) -> None:
        with pytest.raises(ValueError, match="threads"):
            unwrap_single(torch.zeros(8, 8), method="learned", threads=-1)
