"""Device hygiene: every tensor the library makes lands on the device it was asked for.

No GPU runs these tests, so CUDA's commonest failure (a tensor made on the default device, then
mixed with the requested device's tensors) is caught another way: torch's default device is set
to ``meta`` (tensors without data) while the library is asked for ``device="cpu"``. A tensor the
library makes without naming its device then lands on ``meta``, and mixing it with the CPU data,
or reading it, raises, exactly where a CUDA run would mix CPU and CUDA tensors. Host-side helper
tensors say ``device="cpu"`` on purpose. ``scheduler="sync"``: torch's default device is set per
thread, so block work must run on this one to be checked.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.recon.system import SystemAberration
from metasensor.simulation.scenes import load_scene

Z = np.zeros(12, np.float32)
Z[3], Z[5] = 0.3, 0.2  # Noll 4 (defocus) and 6 (astigmatism), waves


@pytest.fixture(scope="module")
def cap():
    return ms.simulate(load_scene("chart", 72), ms.SystemConfig(), zernike=Z, snr_db=30.0,
                       seed=0)


@pytest.fixture
def meta_default():
    before = torch.get_default_device()
    torch.set_default_device("meta")
    assert torch.zeros(1).device.type == "meta"  # the check below is live
    try:
        yield
    finally:
        torch.set_default_device(before)


def test_meta_default_catches_an_unplaced_tensor(meta_default):
    # the mechanism itself: a tensor made without a device cannot meet the requested device's
    with pytest.raises((RuntimeError, NotImplementedError)):
        float((torch.ones(3, device="cpu") * torch.ones(3)).sum())


def test_optics_and_simulator_place_their_tensors(meta_default):
    cfg = ms.SystemConfig()
    assert ms.view_psfs(cfg, zernike=Z, device="cpu").shape[:2] == (15, 15)
    assert ms.widefield_psf(cfg, zernike=Z, device="cpu").ndim == 2
    cap = ms.simulate(load_scene("chart", 48), cfg, snr_db=30.0, seed=0, device="cpu",
                      field_zernike=lambda fy, fx: np.multiply.outer(fy**2 + fx**2, Z),
                      field_blocks=(1, 2))
    assert np.isfinite(cap.views).all()


def test_realign_places_its_tensors(cap, meta_default):
    np.testing.assert_array_equal(ms.realign(cap.frames, cap.config), cap.views)


@pytest.mark.parametrize("kwargs", [
    dict(zernike=Z),                                   # HQS, one block
    dict(zernike=Z, iterations=2),                     # Richardson–Lucy
    dict(zernike=Z, blocks=(2, 2)),                    # padded windows (masked products)
    dict(zernike=Z, register=True, iterations=2),      # view registration
    dict(method="geometric", iterations=2),            # geometric DAO
    dict(method="wave", iterations=2),                 # wave-optics DAO
], ids=["hqs", "rl", "blocks", "register", "geometric", "wave"])
def test_reconstruct_places_its_tensors(cap, meta_default, kwargs):
    rec = ms.reconstruct(cap.views, cap.config, device="cpu", scheduler="sync", **kwargs)
    assert rec.image.shape == cap.truth.shape and np.isfinite(rec.image).all()


def test_depth_places_its_tensors(cap, meta_default):
    n = cap.config.nnum
    grid = np.random.default_rng(0).normal(0, 0.2, (n, n, 2, 2, 2)).astype(np.float32)
    sa = SystemAberration(zernike=np.zeros((1, 1, 45), np.float32), shift_grid=grid,
                          view_shape=cap.views.shape[-2:], config=cap.config)
    for calibration in (None, sa):  # with a system aberration, the views are warped first
        d = ms.estimate_depth(cap.views, cap.config, calibration=calibration, candidates=8,
                              device="cpu")
        assert np.isfinite(d.disparity).all()
