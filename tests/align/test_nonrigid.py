"""Non-rigid registration (align.nonrigid): recover known displacement fields.

Reference: the true shift field used to synthesise the reference image by 5th-order spline
interpolation of the moving image (a different interpolator from the cubic B-spline warp inside
the registration, so no inverse crime). Tolerance: < 0.05 px r.m.s. away from a 6-pixel border.
"""

import numpy as np
import pytest
import torch
from scipy import ndimage

from metasensor.align.nonrigid import (
    dense_field,
    register_nonrigid,
    register_nonrigid_batch,
    warp,
)

H, W = 72, 96


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """These small problems run several times faster on one torch thread on a busy machine."""
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)
INNER = (slice(None), slice(6, -6), slice(6, -6))


def _texture(seed, sigma=1.5):
    rng = np.random.default_rng(seed)
    return ndimage.gaussian_filter(rng.standard_normal((H, W)), sigma).astype(np.float32)


def _apply(moving, field):
    """reference(y, x) = moving(y + dy, x + dx), 5th-order spline."""
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    return ndimage.map_coordinates(moving, [yy + field[0], xx + field[1]], order=5,
                                   mode="reflect").astype(np.float32)


def _smooth_field():
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    return np.stack([1.5 * np.sin(2 * np.pi * xx / W) * np.cos(np.pi * yy / H) + 0.3,
                     1.2 * np.cos(2 * np.pi * yy / H) - 0.4]).astype(np.float32)


def _rms(a, b):
    return float(np.sqrt(np.mean((a - b)[INNER] ** 2)))


def test_dense_field_matches_torch_bicubic():
    c = torch.randn(2, 2, 5, 7, generator=torch.Generator().manual_seed(0))
    ref = torch.nn.functional.interpolate(c, size=(30, 41), mode="bicubic", align_corners=True)
    assert torch.allclose(dense_field(c, (30, 41)), ref, atol=1e-5)


def test_recovers_smooth_field():
    moving = _texture(1)
    true = _smooth_field()
    est = register_nonrigid(moving, _apply(moving, true), grid=(8, 10), iterations=60, lr=0.1)
    assert est.shape == (2, H, W) and est.dtype == np.float32
    assert _rms(est, true) < 0.05, _rms(est, true)


def test_recovers_rigid_subpixel_shift():
    moving = _texture(2)
    true = np.zeros((2, H, W), np.float32)
    true[0], true[1] = 0.37, -1.62
    est = register_nonrigid(moving, _apply(moving, true), grid=(1, 1), iterations=60, lr=0.1)
    assert _rms(est, true) < 0.05, _rms(est, true)
    assert abs(est[0].mean() - 0.37) < 0.01 and abs(est[1].mean() + 1.62) < 0.01


def test_batch_and_warp_consistency():
    moving = _texture(3)
    fields = [_smooth_field(), -0.5 * _smooth_field()]
    refs = np.stack([_apply(moving, f) for f in fields])
    est = register_nonrigid_batch(np.stack([moving, moving]), refs, grid=(8, 10), iterations=60,
                                  lr=0.1)
    assert est.shape == (2, 2, H, W)
    # the images are independent: batching them one by one gives the same fields
    one = register_nonrigid_batch(np.stack([moving, moving]), refs, grid=(8, 10), iterations=60,
                                  lr=0.1, batch_size=1)
    np.testing.assert_allclose(one, est, atol=1e-3)
    for k in range(2):
        assert _rms(est[k], fields[k]) < 0.05
        # warping the moving image with the estimate reproduces the reference
        warped = warp(moving, est[k])
        resid = np.sqrt(np.mean((warped - refs[k])[INNER[1:]] ** 2)) / moving.std()
        assert resid < 0.05, resid


def test_warp_known_shift():
    """warp samples at (y + dy, x + dx): a constant integer shift is an exact array shift."""
    img = _texture(4)
    sh = np.zeros((2, H, W), np.float32)
    sh[0], sh[1] = 2.0, -3.0
    out = warp(img, sh)
    np.testing.assert_allclose(out[5:-5, 5:-5], img[7:-3, 2:-8], atol=1e-5)


def test_bad_input():
    img = _texture(5)
    with pytest.raises(ValueError, match="reference"):
        register_nonrigid(img, img[:10])
    with pytest.raises(ValueError, match="NaN"):
        bad = img.copy()
        bad[0, 0] = np.nan
        register_nonrigid(bad, img)
    with pytest.raises(ValueError, match="shifts"):
        warp(img, np.zeros((2, 3, 3)))
    with pytest.raises(ValueError, match="grid"):
        register_nonrigid(img, img, grid=(0, 3))
