"""Shared test configuration: small thread counts, deterministic torch."""

import os
import tempfile

os.environ.setdefault("OMP_NUM_THREADS", "2")
# PSF banks of the tests go to a private cache, never into the user's ~/.cache
os.environ.setdefault("METASENSOR_CACHE", tempfile.mkdtemp(prefix="ms-cache-"))

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(min(2, torch.get_num_threads()))


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(1234)
