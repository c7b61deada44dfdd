"""Tests for the worker pool of torch_modulo.singleshot.workers."""

from __future__ import annotations

import torch
from torch.utils.data import DataLoader, Dataset

from torch_modulo.singleshot import unwrap_single
from torch_modulo.singleshot.workers import check_workers, default_workers


class TestWorkers:
    def test_workers_agree(self) -> None:
        g = torch.Generator().manual_seed(3)
        modulus = torch.randint(0, 256, (1, 3, 16, 16), generator=g).double()
        one = unwrap_single(modulus, workers=1)
        two = unwrap_single(modulus, workers=2)
        assert torch.equal(one, two)

    def test_default_workers(self) -> None:
        assert default_workers(1, 10**8) == 1
        assert default_workers(8, 100) == 1  # too small for a pool
        assert 1 <= default_workers(3, 10**7) <= 3

    def test_check_workers(self) -> None:
        assert check_workers(None) is None and check_workers(3) == 3


class _Unwrapped(Dataset):
    """Two tiny 2-channel images, each unwrapped with method="fast" and a pool of two workers requested."""

    def __len__(self) -> int:
        return 2

    def __getitem__(self, index: int) -> torch.Tensor:
        g = torch.Generator().manual_seed(index)
        modulus = torch.randint(0, 256, (2, 8, 8), generator=g).double()
        return unwrap_single(modulus, method="fast", workers=2)


def test_fast_inside_a_dataloader_worker() -> None:
    # Regression: a DataLoader worker is a daemonic process, which may not start the pool ("daemonic processes are
    # not allowed to have children"); inside one the planes are solved in-process instead.
    loaded = list(DataLoader(_Unwrapped(), batch_size=None, num_workers=1))
    direct = [_Unwrapped()[i] for i in range(2)]
    assert all(torch.equal(a, b) for a, b in zip(loaded, direct, strict=True))
