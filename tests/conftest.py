"""Shared test fixtures."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture
def one_torch_thread():
    # Small tensors: with 2 OpenMP threads on a busy shared machine every op waits for a
    # descheduled worker (measured 30x slower); one thread keeps these tests fast and stable.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
