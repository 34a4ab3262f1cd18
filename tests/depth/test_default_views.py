"""The default view mask of depth estimation: the configured pupil, or every lit view where views
beyond it are lit (another camera's light field described by the sensor's default NA)."""

import warnings

import numpy as np
import pytest

import metasensor as ms
from metasensor.depth import synthetic
from metasensor.depth.pupil import LIT_FRACTION, default_view_mask
from metasensor.depth.scenes import benchmark_scene


def _flat_views(cfg, level_of):
    """Views of constant brightness ``level_of(r)`` at view radius r."""
    u = np.arange(cfg.nnum) - cfg.center
    r = np.sqrt(u[:, None] ** 2 + u[None, :] ** 2)
    return np.broadcast_to(level_of(r)[:, :, None, None], (cfg.nnum, cfg.nnum, 8, 8)).copy()


@pytest.mark.parametrize("nnum, configured", [(5, 13), (9, 37), (15, 113)])
def test_a_full_grid_of_lit_views_is_used_and_warned(nnum, configured):
    cfg = ms.SystemConfig(nnum=nnum, scan=1)
    assert cfg.view_mask().sum() == configured
    with pytest.warns(UserWarning, match=rf"using every lit view, {nnum * nnum} of the .* not the "
                                         rf"configuration's {configured}"):
        mask = default_view_mask(_flat_views(cfg, lambda r: np.ones_like(r)), cfg)
    assert mask.all()


def test_views_dark_beyond_the_pupil_keep_the_configured_mask():
    """The simulator's 15 x 15 views beyond the pupil's radius reach 0.45 of the centre's (the
    rim), inside it 0.7-1: no widening, no warning, and the lit ring inside the pupil is not
    added either."""
    cfg = ms.SystemConfig(scan=5)
    radius = cfg.pupil_radius_px
    views = _flat_views(cfg, lambda r: np.where(r > radius, 0.45, np.where(r > 6, 0.8, 1.0)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mask = default_view_mask(views, cfg)
    np.testing.assert_array_equal(mask, cfg.view_mask())


def test_a_view_beyond_the_pupil_just_below_lit_does_not_widen():
    cfg = ms.SystemConfig(nnum=9, scan=1)
    views = _flat_views(cfg, lambda r: np.where(r > cfg.pupil_radius_px,
                                                0.99 * LIT_FRACTION, 1.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(default_view_mask(views, cfg), cfg.view_mask())


def test_dark_or_empty_configured_views_keep_the_configured_mask():
    cfg = ms.SystemConfig(nnum=5, scan=1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        zeros = np.zeros((5, 5, 8, 8), np.float32)
        np.testing.assert_array_equal(default_view_mask(zeros, cfg), cfg.view_mask())


def test_estimate_on_a_rendered_5x5_light_field_uses_all_views_by_default():
    """The default on a full 5 x 5 grid equals the all-views estimate, bit for bit, and reports
    the views it used; the configuration's 13 views alone are worse on occlusions."""
    sv = benchmark_scene("occluders", nnum=5, size=64, max_disparity=3.0, snr_db=30.0, seed=1)
    with pytest.warns(UserWarning, match="beyond the configured pupil"):
        res = ms.estimate_depth(sv.views, sv.config)
    assert res.views_used.all()
    full = ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((5, 5), bool))
    np.testing.assert_array_equal(res.disparity, full.disparity)
    cross = ms.estimate_depth(sv.views, sv.config, view_mask=sv.config.view_mask())
    np.testing.assert_array_equal(cross.views_used, sv.config.view_mask())
    inner = (slice(8, -8), slice(8, -8))
    err_full = np.mean((full.disparity - sv.disparity)[inner] ** 2)
    err_cross = np.mean((cross.disparity - sv.disparity)[inner] ** 2)
    assert err_full < 0.9 * err_cross


def test_a_given_mask_is_kept_without_a_warning():
    sv = benchmark_scene("planes", nnum=5, size=48, max_disparity=2.0, snr_db=30.0, seed=1)
    mask = np.zeros((5, 5), bool)
    mask[2, :] = True
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        res = ms.estimate_depth(sv.views, sv.config, view_mask=mask)
    np.testing.assert_array_equal(res.views_used, mask)


def test_the_meta_imaging_sensors_rendered_views_keep_the_configured_mask():
    cfg = ms.SystemConfig(scan=5)
    tex, layers = synthetic.scene_planes((60, 60), near=-1.0, far=1.0, seed=1)
    sv = synthetic.render_views(tex, layers, cfg, snr_db=30, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        res = ms.estimate_depth(sv.views, cfg)
    np.testing.assert_array_equal(res.views_used, cfg.view_mask())
