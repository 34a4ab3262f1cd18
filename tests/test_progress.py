"""Progress at the granularity a person waits on: DAO shows its updates and prints the
wavefront it found per block; simulate shows its steps; the system calibration's registration
ticks within a batch of views."""

import numpy as np

import metasensor as ms
from metasensor.simulation.scenes import load_scene


def test_reconstruct_with_dao_reports_each_blocks_wavefront(capsys):
    z = np.zeros(6)
    z[3] = 0.3  # 0.3 waves of defocus
    cap = ms.simulate(load_scene("chart", 60), ms.SystemConfig(), zernike=z, snr_db=40, seed=0,
                      comparison=False)
    from metasensor.dao.estimate import DaoOptions

    ms.reconstruct(cap.views, cap.config, method="wave", blocks=(1, 1), progress=True,
                   dao=DaoOptions(max_iter=2))
    err = capsys.readouterr().err
    assert "DAO (wave)" in err and "λ r.m.s." in err
    # within an update: what it is doing, at the granularity of a chunk of views
    assert "update 1: PSF bank of the current wavefront" in err
    assert "update 1: image from the views, round 1/3, 16/" in err
    assert "update 1: view shifts and the wavefront fit" in err
    assert "update 2: ISA image, iteration 1/5; wavefront" in err  # below 0.5 λ: the ISA
    line = next(ln for ln in err.replace("\r", "\n").splitlines() if ln.startswith("block (0, 0)"))
    assert "wavefront" in line and "DAO update(s)" in line
    assert "block (0, 0): PSF bank of the estimate ready" in err  # before the solver's steps


def test_simulate_shows_its_steps(capsys):
    ms.simulate(np.ones((30, 30), np.float32), ms.SystemConfig(), snr_db=30, seed=0,
                progress=True)
    err = capsys.readouterr().err
    assert "simulate" in err and "2D sensor and hardware AO" in err and "3/3" in err


def test_registration_ticks_every_ten_adam_steps():
    from metasensor.align.nonrigid import register_nonrigid_batch

    rng = np.random.default_rng(0)
    ref = rng.random((32, 32)).astype(np.float32)
    ticks = []
    register_nonrigid_batch(np.stack([ref, ref]), ref, grid=(3, 3), iterations=30, levels=2,
                            tick=ticks.append)
    assert ticks == [10] * 6  # 2 levels x 30 steps, a tick every 10
