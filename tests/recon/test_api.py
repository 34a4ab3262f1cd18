"""``reconstruct`` on stand-in PSFs: contract shapes, flux, seamless blocks, DAO hook, errors."""

import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.recon.api import reconstruct
from recon_standin import one_torch_thread, standin_psfs, synth_views  # noqa: F401

CFG = SystemConfig()


@pytest.fixture(scope="module")
def bank():
    return standin_psfs(radius=10)


@pytest.fixture(scope="module")
def capture(bank):
    rng = np.random.default_rng(5)
    scene = np.zeros((180, 180), np.float32)
    scene[40:140, 40:140] = 0.2 + rng.random((100, 100)).astype(np.float32)  # dark margin
    from scipy.ndimage import gaussian_filter

    scene = gaussian_filter(scene, 1.0)
    return synth_views(scene, bank, CFG.scan_step_px, border=10)  # 120 x 120 field


def test_contract_shapes_flux_nonnegative(capture, bank):
    views, truth = capture
    rec = reconstruct(views, CFG, psf=bank, iterations=3)
    assert rec.image.shape == truth.shape and rec.image.dtype == np.float32
    assert rec.zernike.shape == (1, 1, 45) and not rec.zernike.any()
    assert len(rec.history[0][0]) == 3
    assert np.isfinite(rec.image).all() and rec.image.min() >= 0
    assert abs(rec.image.sum() / truth.sum() - 1) < 0.01  # flux within 1 %
    # better than the best constant image
    assert np.abs(rec.image - truth).mean() < 0.6 * np.abs(truth - truth.mean()).mean()


def test_blocks_no_seams(capture, bank):
    # 2 x 2 blocks: the gradient across the block borders is no larger than the image's own
    # gradient statistics there: its mean within the range of the row means of a band of +-15 rows
    # and within 5 % of the same row's gradient in the single-block image (which has no border);
    # the stitched image agrees with the single-block one to 2 %, their difference has no step.
    views, truth = capture
    one = reconstruct(views, CFG, psf=bank, iterations=3).image
    rec = reconstruct(views, CFG, psf=bank, iterations=3, blocks=(2, 2), overlap=20)
    img = rec.image
    border = rec.blocks[0].core[1]  # row of the horizontal block border
    grad = np.abs(np.diff(img, axis=0))
    across = grad[border - 1, 20:-20]
    band = np.concatenate([grad[border - 16:border - 1, 20:-20], grad[border:border + 15, 20:-20]])
    assert across.mean() <= band.mean(axis=1).max()
    own = np.abs(np.diff(one, axis=0))[border - 1, 20:-20]
    assert across.mean() <= 1.05 * own.mean()
    diff = img - one
    assert np.abs(diff).mean() < 0.02 * np.abs(one).mean()
    step = np.abs(np.diff(diff, axis=0))[border - 1, 20:-20].mean()
    assert step <= 0.1 * across.mean()


def test_solver_selection_and_hqs_contract(capture, bank):
    # HQS (the sparse-gradient prior) by default; Richardson-Lucy when its parameters are given
    # (iterations, subsets), asked for, or the scan step is too coarse for HQS (1 x 1 scan).
    # HQS keeps the contract: shape, float32, finite, non-negative, flux within 1 %, one residual
    # per continuation step; it fits this smooth, aberration-free scene better than 3 RL its.
    views, truth = capture
    assert reconstruct(views, CFG, psf=bank, iterations=1).solver == "rl"
    assert reconstruct(views, CFG, psf=bank, subsets=1).solver == "rl"
    lf = CFG.replace(scan=1)
    assert reconstruct(views[:, :, ::5, ::5], lf, psf=bank).solver == "rl"
    with pytest.raises(ValueError, match="scan step"):
        reconstruct(views[:, :, ::5, ::5], lf, psf=bank, solver="hqs")
    rec = reconstruct(views, CFG, psf=bank)
    assert rec.solver == "hqs" and len(rec.history[0][0]) == 8
    assert rec.image.shape == truth.shape and rec.image.dtype == np.float32
    assert np.isfinite(rec.image).all() and rec.image.min() >= 0
    assert abs(rec.image.sum() / truth.sum() - 1) < 0.01
    rl = reconstruct(views, CFG, psf=bank, iterations=3)
    assert rl.solver == "rl"
    assert np.abs(rec.image - truth).mean() < np.abs(rl.image - truth).mean()


def test_dao_methods_use_estimated_aberration(capture, bank, monkeypatch):
    # wave DAO per block: the block's window and DAO's settings go to run_dao; the estimated
    # Noll vector reaches the block's bank (psf_fn) and the result; the DAO history is kept
    from metasensor.dao import estimate
    from metasensor.dao.estimate import DaoOptions, DaoResult

    views, _ = capture
    calls = []

    def run_dao(block_views, cfg, options, init=None, device=None, view_mask=None):
        calls.append((block_views.shape, options, init))
        z = np.zeros(45)
        z[4] = 0.1 * len(calls)
        return DaoResult(zernike=z, history=[1.0, 0.5], shifts=np.zeros((15, 15, 2)),
                         method=options.method)

    monkeypatch.setattr(estimate, "run_dao", run_dao)
    used = []

    def psf_fn(cfg, zernike, device):
        used.append(np.array(zernike))
        return bank

    rec = reconstruct(views, CFG, method="wave", iterations=1, blocks=(1, 2), psf_fn=psf_fn,
                      dao=DaoOptions(max_iter=2), scheduler="sync")
    assert len(calls) == 2 and calls[0][1].method == "wave" and calls[0][1].max_iter == 2
    assert calls[0][0][:2] == (15, 15)
    np.testing.assert_allclose(sorted(rec.zernike[0, :, 4]), [0.1, 0.2], rtol=1e-6)
    assert sorted(round(float(u[4]), 3) for u in used) == [0.1, 0.2]
    assert rec.dao_history[0][0] == [1.0, 0.5]


def test_bad_input(capture, bank):
    views, _ = capture
    with pytest.raises(ValueError, match="nnum"):
        reconstruct(views[:5, :5], CFG, psf=bank)
    with pytest.raises(ValueError, match="shape"):
        reconstruct(views[0], CFG, psf=bank)
    bad = views.copy()
    bad[0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        reconstruct(bad, CFG, psf=bank)
    with pytest.raises(ValueError, match="method"):
        reconstruct(views, CFG, method="magic", psf=bank)
    with pytest.raises(ValueError, match="blocks"):
        reconstruct(views, CFG, psf=bank, blocks=3)
    with pytest.raises(ValueError, match="psf"):
        reconstruct(views, CFG, psf=bank[..., :4])
    with pytest.raises(TypeError, match="SystemConfig"):
        reconstruct(views, {"nnum": 15}, psf=bank)
    with pytest.raises(ValueError, match="solver"):
        reconstruct(views, CFG, psf=bank, solver="magic")
    with pytest.raises(ValueError, match="scan step"):
        reconstruct(views, CFG.replace(scan=1), psf=bank, solver="hqs")
    with pytest.raises(ValueError, match="scheduler"):
        reconstruct(views, CFG, psf=bank, iterations=1, scheduler="bogus")
    for radius in (-1.0, float("nan"), "6", True):
        with pytest.raises(ValueError, match="view_radius"):
            reconstruct(views, CFG, psf=bank, view_radius=radius)
    assert np.isfinite(views).all()  # inputs untouched


def test_wave_dao_bank_uses_the_used_views_window(capture, bank, monkeypatch):
    # After wave DAO (no psf / psf_fn given) the block's bank is generated at
    # dao.banks.psf_window of the estimate, not view_psfs' all-views default window.
    from metasensor.dao import banks, estimate
    from metasensor.dao.estimate import DaoResult

    views, _ = capture
    z = np.zeros(45)
    z[4] = 0.5

    def run_dao(window, cfg, options, init=None, device=None, view_mask=None):
        return DaoResult(zernike=z, history=[1.0], shifts=np.zeros((15, 15, 2)), method="wave",
                         psf_size=banks.psf_window(cfg, z, cfg.view_mask()))

    monkeypatch.setattr(estimate, "run_dao", run_dao)
    sizes = []

    def psf_bank(cfg, zernike, amplitude=None, device=None, size=None, cache=True):
        sizes.append(size)
        return bank

    monkeypatch.setattr(banks, "psf_bank", psf_bank)
    reconstruct(views, CFG, method="wave", iterations=1, scheduler="sync")
    assert sizes == [banks.psf_window(CFG, z)]


def test_options_object_and_keywords_agree(capture, bank):
    # the settings are one frozen, validated ReconOptions; keywords name its fields
    from metasensor.recon.options import ReconOptions

    views, _ = capture
    opts = ReconOptions(psf=bank, iterations=2, overlap=12)
    a = reconstruct(views, CFG, options=opts).image
    b = reconstruct(views, CFG, psf=bank, iterations=2, overlap=12).image
    np.testing.assert_array_equal(a, b)
    with pytest.raises(TypeError, match="unknown settings"):
        reconstruct(views, CFG, psf=bank, iteration=2)
    with pytest.raises(ValueError, match="order"):
        ReconOptions(order="zigzag")
    with pytest.raises(AttributeError):
        opts.iterations = 3  # frozen
