"""Shared test configuration: small thread counts, deterministic torch."""

import os

os.environ.setdefault("OMP_NUM_THREADS", "2")

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(min(2, torch.get_num_threads()))


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(1234)
