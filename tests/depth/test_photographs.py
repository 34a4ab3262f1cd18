"""Depth of photograph-textured surfaces (``metasensor.depth.scenes.natural_scene``'s
textures): the cost aggregation of plain light-field views pools across the texture's own
edges. The full-size figures are bench_depth's natural rows."""

import numpy as np

import metasensor as ms
from metasensor.config import SystemConfig
from metasensor.depth.estimate import EPS_PLAIN, EPS_SCANNED
from metasensor.depth.scenes import _photo
from metasensor.depth.synthetic import Layer, render_views


def _brick_plane(size: int = 64, seed: int = 0):
    """A slanted plane (0.6 to 2.4 view px per view step) textured by the brick photograph:
    high-contrast mortar lines around flat faces. 9 x 9 views, 40 dB."""
    cfg = SystemConfig(nnum=9, scan=1)
    d = cfg.scan_step_px
    shape = (size * d, size * d)
    tex = _photo("brick", shape, np.random.default_rng(seed))
    ramp = np.linspace(0.6, 2.4, shape[1])[None, :] * np.ones((shape[0], 1))
    return render_views(np.full(shape, 0.5), [Layer(np.ones(shape), ramp * d, tex)], cfg,
                        snr_db=40, seed=seed, view_mask=np.ones((9, 9), bool))


def _scores(sv, **kw) -> tuple[float, float]:
    res = ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((9, 9), bool), **kw)
    err = (res.disparity - sv.disparity)[8:-8, 8:-8]
    return float(np.mean(np.abs(err) > 0.07)), float(100 * np.mean(err**2))


def test_brick_photograph_plane_is_found_between_its_mortar_lines():
    sv = _brick_plane()
    views = sv.views.copy()
    badpix, mse = _scores(sv)                       # default: EPS_PLAIN for scan 1
    assert np.array_equal(sv.views, views)          # the input is not modified
    assert badpix <= 0.15 and mse <= 0.5
    # the edge-aware aggregation leaves the flat faces between the mortar lines a flat cost
    badpix_edge_aware, mse_edge_aware = _scores(sv, eps=EPS_SCANNED)
    assert badpix_edge_aware >= 3 * badpix and mse_edge_aware >= 3 * mse


def test_default_eps_follows_the_scan():
    assert EPS_PLAIN > EPS_SCANNED > 0
    sv = _brick_plane(size=32)
    a = ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((9, 9), bool))
    b = ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((9, 9), bool), eps=EPS_PLAIN)
    assert np.array_equal(a.disparity, b.disparity)
