"""Device and dtype hygiene: every tensor the library makes lands on the device it was asked for,
in float32, whatever torch's defaults are.

No GPU runs these tests, so CUDA's commonest failure (a tensor made on the default device, then
mixed with the requested device's tensors) is caught another way: torch's default device is set
to ``meta`` (tensors without data) while the library is asked for ``device="cpu"``. A tensor the
library makes without naming its device then lands on ``meta``, and mixing it with the CPU data,
or reading it, raises, exactly where a CUDA run would mix CPU and CUDA tensors. Host-side helper
tensors say ``device="cpu"`` on purpose. ``scheduler="sync"``: torch's default device is set per
thread, so block work must run on this one to be checked.

The same runs with torch's default dtype set to float64 (a user's setting) must return float32
and not fail on a float32/float64 mix (``index_add_`` and matrix products refuse one).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.dao.system_aberration import SystemAberration
from metasensor.simulation.scenes import load_scene
from metasensor.solvers.hyper_laplacian import _unit_table

Z = np.zeros(12, np.float32)
Z[3], Z[5] = 0.3, 0.2  # Noll 4 (defocus) and 6 (astigmatism), waves
Z_BANK_ERROR = Z * np.float32([1, 1, 1, 0] + [1] * 8)  # a bank without the capture's defocus


@pytest.fixture(scope="module")
def cap():
    return ms.simulate(load_scene("chart", 72), ms.SystemConfig(), zernike=Z, snr_db=30.0,
                       seed=0)


_TORCH = tuple(int(p) for p in torch.__version__.split("+")[0].split(".")[:2])


@pytest.fixture(params=["meta-device", "float64-dtype"])
def hostile(request):
    """torch's default device set to meta, or its default dtype to float64, for one test."""
    device, dtype = torch.get_default_device(), torch.get_default_dtype()
    _unit_table.cache_clear()  # tables cached by earlier tests would hide where they are made
    if request.param == "meta-device":
        torch.set_default_device("meta")
        assert torch.zeros(1).device.type == "meta"  # the check below is live
    else:
        torch.set_default_dtype(torch.float64)
        assert torch.zeros(1).dtype == torch.float64
    try:
        yield request.param
    finally:
        torch.set_default_device(device)
        torch.set_default_dtype(dtype)


def test_hostile_defaults_catch_an_unplaced_tensor(hostile):
    # the mechanism itself: a tensor made without naming its device (dtype) cannot meet the
    # requested device's (a float32 tensor) where the operation needs them to agree
    if hostile == "meta-device" and _TORCH < (2, 13):
        pytest.skip("before torch 2.13 a CPU tensor meeting a meta tensor in index_add_ does not"
                    " raise; the pinned torch==2.13 raises")
    a = torch.zeros(3, 2, dtype=torch.float32, device="cpu")
    with pytest.raises((RuntimeError, NotImplementedError)):
        a.index_add_(0, torch.tensor([0], device="cpu"), torch.ones(1, 2))


def test_optics_and_simulator_place_their_tensors(hostile):
    cfg = ms.SystemConfig()
    bank = ms.view_psfs(cfg, zernike=Z, device="cpu", cache=False)
    assert bank.shape[:2] == (15, 15) and bank.dtype == np.float32
    assert ms.widefield_psf(cfg, zernike=Z, device="cpu").dtype == np.float32
    cap = ms.simulate(load_scene("chart", 48), cfg, snr_db=30.0, seed=0, device="cpu",
                      field_zernike=lambda fy, fx: np.multiply.outer(fy**2 + fx**2, Z),
                      field_blocks=(1, 2))
    assert np.isfinite(cap.views).all() and cap.views.dtype == np.float32


def test_realign_places_its_tensors(cap, hostile):
    np.testing.assert_array_equal(ms.realign(cap.frames, cap.config), cap.views)


@pytest.mark.parametrize("kwargs", [
    dict(zernike=Z),                                   # HQS, one block
    dict(zernike=Z, iterations=2),                     # Richardson–Lucy
    dict(zernike=Z, blocks=(2, 2)),                    # padded windows (masked products)
    dict(zernike=Z_BANK_ERROR, register=True, iterations=2),  # registration (shifts the bank)
    dict(method="geometric", iterations=2),            # geometric DAO
    dict(method="wave", iterations=2),                 # wave-optics DAO
], ids=["hqs", "rl", "blocks", "register", "geometric", "wave"])
def test_reconstruct_places_its_tensors(cap, hostile, kwargs):
    rec = ms.reconstruct(cap.views, cap.config, device="cpu", scheduler="sync", **kwargs)
    assert rec.image.shape == cap.truth.shape and rec.image.dtype == np.float32
    assert np.isfinite(rec.image).all()
    if kwargs.get("register"):  # the bank error made it measure and apply shifts (2.6 px first)
        assert len(rec.registration[0][0]) >= 2 and rec.registration[0][0][0] > 1.0


def test_depth_places_its_tensors(cap, hostile):
    n = cap.config.nnum
    grid = np.random.default_rng(0).normal(0, 0.2, (n, n, 2, 2, 2)).astype(np.float32)
    sa = SystemAberration(zernike=np.zeros((1, 1, 45), np.float32), shift_grid=grid,
                          view_shape=cap.views.shape[-2:], config=cap.config)
    for calibration in (None, sa):  # with a system aberration, the views are warped first
        d = ms.estimate_depth(cap.views, cap.config, calibration=calibration, candidates=8,
                              device="cpu")
        assert np.isfinite(d.disparity).all() and d.disparity.dtype == np.float32


def test_an_address_space_limit_keeps_the_default_device_on_the_cpu(monkeypatch):
    # CUDA does not start under a tight `ulimit -v` (an H200: not at 16 GiB, at 64 GiB it did), so
    # the default device there is the CPU, said once; otherwise CUDA where it is present
    import metasensor.backend as backend

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(backend, "_CPU_UNDER_LIMIT_WARNED", False)
    monkeypatch.setattr(backend, "address_space_limit", lambda: 3 * 2**30)
    with pytest.warns(RuntimeWarning, match="address-space limit"):
        assert backend.resolve_device(None).type == "cpu"
    assert backend.resolve_device(None).type == "cpu"  # the warning is not repeated
    for limit in (None, backend.CUDA_ADDRESS_SPACE):
        monkeypatch.setattr(backend, "address_space_limit", lambda limit=limit: limit)
        assert backend.resolve_device(None).type == "cuda"
