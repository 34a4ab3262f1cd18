"""Depth-stage test fixtures: one torch thread (these problems are small; on a shared machine
two OpenMP threads per process only add contention), restored afterwards."""

import pytest
import torch


@pytest.fixture(autouse=True)
def _one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
