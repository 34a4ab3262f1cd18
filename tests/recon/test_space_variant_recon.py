"""``reconstruct(space_variant=True)``: banks at the blocks' corners, blended in the operator."""

import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.recon.api import reconstruct
from metasensor.recon.blocks import split_blocks
from metasensor.recon.space_variant import corner_zernikes
from metasensor.solvers.hqs import HQSOptions
from metasensor.solvers.splitting import Continuation
from recon_standin import one_torch_thread, standin_psfs, synth_views  # noqa: F401

CFG = SystemConfig()


@pytest.fixture(scope="module")
def setup():
    bank = standin_psfs(radius=8)
    rng = np.random.default_rng(3)
    from scipy.ndimage import gaussian_filter

    scene = gaussian_filter(0.2 + rng.random((114, 114)).astype(np.float32), 1.0)
    views, truth = synth_views(scene, bank, CFG.scan_step_px, border=10)
    return bank, views, truth


def test_corner_zernikes_evaluate_the_field_at_the_core_corners():
    shape = (90, 120)
    blocks = split_blocks(shape, (2, 2), 3, overlap=12)
    field = lambda yn, xn: np.stack([yn, xn], axis=-1)  # noqa: E731
    z = corner_zernikes(blocks, shape, zernike=np.array([0.5]), field_zernike=field)
    b = blocks[3]  # bottom-right: core (45, 90, 60, 120)
    np.testing.assert_allclose(z[b.index][:, :2], [[0.5, 0.0], [0.5, 1.0], [1.5, 0.0],
                                                   [1.5, 1.0]], atol=1e-6)
    assert z[b.index].shape == (4, 45)
    fine = corner_zernikes(blocks, shape, zernike=np.array([0.5]), field_zernike=field,
                           points=3)[b.index]  # a 3 x 3 grid over the core, corners included
    assert fine.shape == (9, 45)
    np.testing.assert_allclose(fine[[0, 2, 6, 8], :2], z[b.index][:, :2], atol=1e-6)
    np.testing.assert_allclose(fine[4, :2], [0.5 + (67.5 / 45 - 1), 1.5 - 1.0], atol=1e-6)


def test_one_bank_at_every_corner_gives_the_plain_reconstruction(setup):
    bank, views, truth = setup
    calls = []

    def psf_fn(cfg, zernike, device):
        calls.append(np.asarray(zernike))
        return bank

    field = lambda yn, xn: np.stack([yn, xn], axis=-1) * 0.1  # noqa: E731
    quick = HQSOptions(continuation=Continuation(beta_max=64.0))
    plain = reconstruct(views, CFG, psf_fn=psf_fn, field_zernike=field, blocks=(2, 2),
                        solver_options=quick).image
    n_plain = len(calls)
    sv = reconstruct(views, CFG, psf_fn=psf_fn, field_zernike=field, blocks=(2, 2),
                     space_variant=True, solver_options=quick).image
    assert len(calls) - n_plain == 16  # four corner banks per block
    # the same model solved through the exact direct normal product instead of the bands:
    # equal up to round-off that the non-convex prior's shrinkage can amplify at a few pixels
    assert np.abs(sv - plain).mean() < 2e-3 * truth.max()
    assert np.abs(sv - plain).max() < 0.1 * truth.max()
    assert np.abs(sv - truth).mean() < 1.05 * np.abs(plain - truth).mean()
    n_sv = len(calls)
    fine = reconstruct(views, CFG, psf_fn=psf_fn, field_zernike=field, blocks=(2, 2),
                       space_variant=True, field_points=3, solver_options=quick).image
    assert len(calls) - n_sv == 36  # a 3 x 3 grid of banks per block
    assert np.abs(fine - sv).mean() < 2e-3 * truth.max()  # one bank everywhere: same model


def test_space_variant_refuses_what_it_cannot_model(setup):
    bank, views, _ = setup
    with pytest.raises(ValueError, match="solver='hqs'"):
        reconstruct(views, CFG, iterations=2, space_variant=True)
    with pytest.raises(ValueError, match="no psf"):
        reconstruct(views, CFG, psf=bank, space_variant=True)
    with pytest.raises(TypeError, match="space_variant"):
        reconstruct(views, CFG, space_variant="yes")
    with pytest.raises(ValueError, match="field_points"):
        reconstruct(views, CFG, space_variant=True, field_points=1)
