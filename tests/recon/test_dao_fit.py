"""DAO's shift-fit residual per block and the one warning when a block was not isoplanatic."""

import warnings

import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.recon.dao_fit import FIT_WARN_PX, nonuniform_blocks, warn_dao_fit
from recon_standin import one_torch_thread, standin_psfs, synth_views  # noqa: F401

CFG = SystemConfig()


def test_nonuniform_blocks_reads_the_threshold_and_skips_blocks_without_dao():
    fits = np.array([[0.1, np.nan], [0.51, 2.0]])
    assert nonuniform_blocks(fits) == [(1, 0), (1, 1)]
    assert nonuniform_blocks(fits, threshold=1.0) == [(1, 1)]
    assert nonuniform_blocks(None) == []
    assert nonuniform_blocks(np.full((2, 2), FIT_WARN_PX)) == []  # at the threshold: kept
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="threshold"):
            nonuniform_blocks(fits, threshold=bad)
    with pytest.raises(ValueError, match="fits must be"):
        nonuniform_blocks(np.zeros(3))


def test_warn_dao_fit_warns_once_naming_the_blocks():
    with pytest.warns(UserWarning, match=r"up to 2\.00 px .* 2 of 4 blocks \(\(1, 0\), \(1, 1\)"):
        assert warn_dao_fit(np.array([[0.1, 0.2], [0.6, 2.0]]), (2, 2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert not warn_dao_fit(np.array([[0.1, 0.2], [0.45, np.nan]]), (2, 2))
        assert not warn_dao_fit(None, (2, 2))


def _fake_dao(monkeypatch, bank, fit_px):
    """DAO replaced by a fixed estimate whose last shift fit left ``fit_px`` pixels."""
    from metasensor.dao import banks, estimate
    from metasensor.dao.estimate import DaoResult

    z = np.zeros(45)
    z[4] = 0.3

    def run_dao(window, cfg, options, init=None, device=None, view_mask=None):
        return DaoResult(zernike=z, history=[0.3, 0.01], shifts=np.zeros((15, 15, 2)),
                         method="wave", fits=[1.5, fit_px])

    monkeypatch.setattr(estimate, "run_dao", run_dao)
    monkeypatch.setattr(banks, "psf_bank", lambda *a, **k: bank)


@pytest.fixture(scope="module")
def bank():
    return standin_psfs(radius=10)


@pytest.fixture(scope="module")
def views(bank):
    rng = np.random.default_rng(0)
    scene = (0.2 + rng.random((180, 180))).astype(np.float32)
    return synth_views(scene, bank, CFG.scan_step_px, border=10)[0]


def test_reconstruction_carries_the_fit_and_warns_on_a_mixed_block(monkeypatch, bank, views):
    from metasensor import reconstruct

    _fake_dao(monkeypatch, bank, 0.9)
    with pytest.warns(UserWarning, match="one-wavefront fit left up to 0.90 px"):
        rec = reconstruct(views, CFG, method="wave", blocks=(1, 2), solver="rl", iterations=1,
                          scheduler="sync")
    np.testing.assert_allclose(rec.dao_fit_px, [[0.9, 0.9]])


def test_isoplanatic_fit_and_no_dao_stay_silent(monkeypatch, bank, views):
    from metasensor import reconstruct

    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        rec = reconstruct(views, CFG, psf=bank, solver="rl", iterations=1)
        assert rec.dao_fit_px is None
        _fake_dao(monkeypatch, bank, 0.1)
        rec = reconstruct(views, CFG, method="wave", solver="rl", iterations=1,
                          scheduler="sync")
    np.testing.assert_allclose(rec.dao_fit_px, [[0.1]])
