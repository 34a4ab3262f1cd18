"""DAO estimates a block's wavefront on the block's most detailed sub-window of at most
``dao_samples`` view samples per side: its time and memory follow that window, not the block."""

from types import SimpleNamespace

import numpy as np
import pytest

import metasensor as ms
from metasensor.dao import estimate
from metasensor.dao.estimate import DaoOptions, run_dao
from metasensor.dao.wavefront import zernike_rms
from metasensor.recon import block
from metasensor.recon.probe import probe_window
from metasensor.simulation.scenes import load_scene


def test_dao_reads_the_most_detailed_sub_window_of_a_large_block(monkeypatch, bank_task):
    seen = []

    def fake_dao(window, cfg, options, **kw):
        seen.append(window)
        return SimpleNamespace(zernike=np.r_[0, 0, 0, 0.4], history=[0.4], fits=[0.1])

    monkeypatch.setattr(estimate, "run_dao", fake_dao)
    rng = np.random.default_rng(0)
    window = np.ones((15, 15, 90, 120), np.float32)
    window[:, :, 60:, :30] += rng.random((30, 30)).astype(np.float32)  # detail: bottom left
    before = window.copy()
    task = bank_task(psf_fn=lambda cfg, z, dev: np.zeros((15, 15, 3, 3), np.float32),
                     dao_samples=30)
    bank, merged, history, est, fit = block._bank(task, window)
    assert len(seen) == 1 and seen[0].shape == (15, 15, 30, 30)
    np.testing.assert_array_equal(seen[0], window[:, :, 60:, :30])
    assert merged[3] == np.float32(0.4) and history == [0.4]  # applied to the whole block
    np.testing.assert_array_equal(window, before)
    task.dao_samples = 200  # a window no larger than dao_samples is read whole
    block._bank(task, window)
    assert seen[1] is window


@pytest.mark.slow  # two DAO runs: about 30 s on one core
def test_a_sub_window_estimates_the_blocks_wavefront_as_the_whole_does():
    z = np.zeros(12, np.float32)
    z[3], z[5] = 0.3, 0.2  # the aberration of tests/test_device_hygiene.py (its bank cached)
    cfg = ms.SystemConfig()
    cap = ms.simulate(load_scene("camera", 120), cfg, zernike=z, snr_db=30, seed=0,
                      comparison=False)
    dao = DaoOptions(method="wave", max_iter=2)
    whole = run_dao(cap.views, cfg, dao).zernike
    part = run_dao(probe_window(cap.views, 24), cfg, dao).zernike
    n = max(len(whole), len(part), len(z))
    pad = [np.pad(np.asarray(v, np.float64), (0, n - len(v))) for v in (whole, part, z)]
    err_whole, err_part = zernike_rms(pad[0] - pad[2]), zernike_rms(pad[1] - pad[2])
    # 0.36 λ r.m.s. at 30 dB; measured 0.005 λ (40 samples a side) and 0.007 λ (24)
    assert err_whole < 0.02 and err_part < 0.02, (err_whole, err_part)


def test_reconstruct_refuses_a_dao_window_under_eight_samples():
    with pytest.raises(ValueError, match="dao_samples"):
        ms.reconstruct(np.ones((15, 15, 8, 8), np.float32), ms.SystemConfig(), method="wave",
                       dao_samples=4)


def test_reconstruct_hands_dao_samples_to_every_block(monkeypatch):
    seen = []

    def fake_dao(window, cfg, options, **kw):
        seen.append(window.shape[-2:])
        return SimpleNamespace(zernike=np.r_[0, 0, 0, 0.4], history=[0.4], fits=[0.1])

    def delta_bank(cfg, zernike, device=None):
        bank = np.zeros((cfg.nnum, cfg.nnum, 3, 3), np.float32)
        bank[:, :, 1, 1] = 1.0
        return bank

    monkeypatch.setattr(estimate, "run_dao", fake_dao)
    views = np.random.default_rng(2).random((15, 15, 40, 40)).astype(np.float32)
    ms.reconstruct(views, ms.SystemConfig(), method="wave", blocks=(1, 2), dao_samples=16,
                   psf_fn=delta_bank, solver="rl", iterations=1)
    assert len(seen) == 2 and all(s == (16, 16) for s in seen), seen
