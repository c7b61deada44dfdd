"""Fixtures shared by the single-shot tests."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture
def one_thread():
    """Small convolutions run fastest on one thread (and do not fight the other processes of a shared machine)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
