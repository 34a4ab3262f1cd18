"""The DAO probe of ``method="auto"`` decides on a sub-window of a large block: the most
detailed of its centre and edges, and the same decision as on the whole block."""

import math
from dataclasses import replace

import numpy as np
import pytest

import metasensor as ms
from metasensor.dao.estimate import DaoOptions, run_dao
from metasensor.dao.wavefront import zernike_rms
from metasensor.recon.dao_choice import NEGLIGIBLE_RMS, PROBE_SAMPLES
from metasensor.recon.probe import probe_window
from metasensor.simulation.scenes import load_scene


def _window(h=50, w=70):
    """Views of a pattern of period 5 (integers: every candidate of a probe window scores the
    same, exactly)."""
    y, x = np.mgrid[:h, :w]
    return np.broadcast_to(10 + (3 * (y % 5) + 7 * (x % 5)) % 3, (3, 3, h, w)).astype(
        np.float32)


def test_probe_window_keeps_a_small_window_whole():
    win = _window()
    assert probe_window(win, 70) is win and probe_window(win, 500) is win
    assert PROBE_SAMPLES >= 8


def test_probe_window_prefers_the_centre_and_takes_texture_where_it_is():
    win = _window()
    centre = probe_window(win, 20)
    np.testing.assert_array_equal(centre, win[:, :, 15:35, 25:45])  # (h - s) // 2
    tall = probe_window(win, 60)  # 50 rows kept whole, 60 of 70 columns centred
    np.testing.assert_array_equal(tall, win[:, :, :, 5:65])
    textured = win.copy()
    textured[:, :, 30:, 50:] += np.random.default_rng(1).integers(0, 50, (20, 20))
    corner = probe_window(textured, 20)
    np.testing.assert_array_equal(corner, textured[:, :, 30:50, 50:70])
    assert np.shares_memory(corner, textured)  # a view: the window is not copied
    np.testing.assert_array_equal(probe_window(win, 20), centre)  # input not modified


@pytest.mark.parametrize("aberrated", [False, True])
def test_the_probe_of_a_sub_window_decides_as_the_whole_block(aberrated):
    z = np.zeros(12, np.float32)
    z[3], z[5] = 0.3, 0.2  # the aberration of tests/test_device_hygiene.py (its bank cached)
    cfg = ms.SystemConfig()
    cap = ms.simulate(load_scene("camera", 120), cfg, zernike=z if aberrated else None,
                      snr_db=30, seed=0, comparison=False)
    dao = replace(DaoOptions(), method="wave", max_iter=1, isa_below=math.inf)
    whole = zernike_rms(run_dao(cap.views, cfg, dao).zernike)
    part = zernike_rms(run_dao(probe_window(cap.views, 24), cfg, dao).zernike)
    assert (whole < NEGLIGIBLE_RMS) == (part < NEGLIGIBLE_RMS) == (not aberrated), (whole, part)


def test_reconstruct_refuses_a_probe_window_under_eight_samples():
    with pytest.raises(ValueError, match="dao_probe_samples"):
        ms.reconstruct(np.ones((15, 15, 8, 8), np.float32), ms.SystemConfig(), method="auto",
                       dao_probe_samples=4)
