"""The simulator computes a field's kernels first, one per torch thread at once
(``sampling.prefetch_kernels``); the capture is the one computed kernel by kernel."""

import threading

import numpy as np
import torch

from conftest import SMALL
from metasensor.simulation import sampling
from metasensor.simulation.capture import simulate


def _capture(scene, grid, cache, monkeypatch):
    monkeypatch.setenv("METASENSOR_CACHE", str(cache))  # each run computes its own kernels
    # on the CPU: there a field's kernels are made one per torch thread (CUDA makes them on one)
    return simulate(scene, SMALL, field_zernike=grid, scale=1.0, seed=3, device="cpu")


def test_kernels_made_on_two_threads_give_the_capture_made_one_by_one(monkeypatch, tmp_path):
    rng = np.random.default_rng(0)
    scene = rng.random((64, 64)).astype(np.float32)
    grid = np.zeros((2, 2, 6))
    grid[..., 3] = [[0.3, -0.2], [0.1, 0.4]]  # a different defocus per field block
    grid[..., 5] = [[0.2, 0.0], [-0.3, 0.1]]
    threads = set()
    views = sampling.KernelBanks.views

    def spy(self, *args, **kwargs):
        threads.add(threading.get_ident())
        return views(self, *args, **kwargs)

    monkeypatch.setattr(sampling.KernelBanks, "views", spy)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        two = _capture(scene, grid, tmp_path / "a", monkeypatch)
    finally:
        torch.set_num_threads(before)
    assert len(threads - {threading.get_ident()}) == 2  # made on two threads besides this one
    assert torch.get_num_threads() == before
    monkeypatch.setattr(sampling, "prefetch_kernels", lambda *args, **kwargs: None)
    one = _capture(scene, grid, tmp_path / "b", monkeypatch)
    np.testing.assert_allclose(two.views_clean, one.views_clean, rtol=0,
                               atol=1e-6 * one.views_clean.max())
    np.testing.assert_allclose(two.sensor2d_clean, one.sensor2d_clean, rtol=0,
                               atol=1e-6 * one.sensor2d_clean.max())
