"""Shared test configuration: small thread counts, deterministic torch."""

import os
import shutil
import tempfile

# under pytest-xdist each of the workers gets one thread, so two workers share two cores; a
# worker sets it for the commands its tests start too (it inherits the controller's 2, and a
# child on two threads sums in another order than the worker's in-process run of the same
# command: the widgets' replay tests compare the two bit for bit)
_THREADS = 1 if "PYTEST_XDIST_WORKER" in os.environ else 2
if "PYTEST_XDIST_WORKER" in os.environ:
    os.environ["OMP_NUM_THREADS"] = "1"
else:
    os.environ.setdefault("OMP_NUM_THREADS", str(_THREADS))
# PSF banks of the tests go to a private cache, never into the user's ~/.cache; it is removed
# when the session ends (up to 1.7 GB per run was left in the temporary folder before)
_OWN_CACHE = None
if "METASENSOR_CACHE" not in os.environ:
    _OWN_CACHE = tempfile.mkdtemp(prefix="ms-cache-")
    os.environ["METASENSOR_CACHE"] = _OWN_CACHE

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(min(_THREADS, torch.get_num_threads()))


def pytest_unconfigure(config):
    if _OWN_CACHE is not None:
        shutil.rmtree(_OWN_CACHE, ignore_errors=True)


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(1234)
