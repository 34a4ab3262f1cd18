"""Re-deciding depth-edge pixels by the front layer's measured coverage
(metasensor.depth.edges): the coverage rule on a rendered straight edge, the gain on a hard
rendered scene at a small size (the full-size figures are bench_depth's), and the settings'
checks."""

import warnings

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.config import SystemConfig
from metasensor.depth.edges import EdgeSnap, snap_edges
from metasensor.depth.evaluate import score
from metasensor.depth.scenes import benchmark_scene
from metasensor.depth.synthetic import Layer, random_texture, render_views

N, H, W, X0, X1 = 9, 96, 40, 16, 23  # views per side, view px, the bar's first and last+1 column


def _bar():
    """A bar at -1.8 view px per view step over a background at +1.8 (40 dB): the lenslet
    footprint of column X0 is 57 % bar (truth: bar), that of column X1 43 % (truth: back)."""
    cfg = SystemConfig(nnum=N, scan=1)
    d = cfg.scan_step_px
    shape = (H * d, W * d)
    alpha = np.zeros(shape)
    alpha[:, X0 * d + d // 2: X1 * d + d // 2] = 1.0
    layers = [Layer(np.ones(shape), 1.8 * d, random_texture(shape, 1, 2.0 * d)),
              Layer(alpha, -1.8 * d, random_texture(shape, 2, 2.0 * d))]
    sv = render_views(np.full(shape, 0.5), layers, cfg, snr_db=40, seed=0,
                      view_mask=np.ones((N, N), bool))
    views = torch.from_numpy(sv.views.reshape(N * N, H, W).copy())
    uu, vv = np.divmod(np.arange(N * N), N)
    return views, uu - N // 2, vv - N // 2, sv.disparity


def test_pixels_take_the_layer_covering_more_than_half_their_footprint():
    views, au, av, truth = _bar()
    assert truth[10, X0] == pytest.approx(-1.8) and truth[10, X1] == pytest.approx(1.8)
    wrong = truth.copy()
    wrong[:, X0], wrong[:, X1] = 1.8, -1.8  # both edge columns given the other layer
    given = torch.from_numpy(wrong)
    out = snap_edges(views, au, av, given).numpy()
    assert np.array_equal(given.numpy(), wrong)  # the input is not modified
    rows = slice(8, -8)  # away from the replicated borders
    assert np.mean(np.abs(out[rows, X0] + 1.8) < 0.1) >= 0.9
    assert np.mean(np.abs(out[rows, X1] - 1.8) < 0.1) >= 0.8
    others = np.ones(truth.shape, bool)
    others[:, [X0, X1]] = False
    assert np.array_equal(out[others], wrong[others])
    # the right answer is kept
    kept = snap_edges(views, au, av, torch.from_numpy(truth)).numpy()
    assert np.mean(kept[rows] == truth[rows]) >= 0.99


def test_edge_snap_lowers_the_error_on_a_hard_scene():
    """Mixed scene (9 x 9 views, 40 dB, 64 px): the re-decision at least halves MSE x 100 and
    keeps BadPix(0.07)."""
    sv = benchmark_scene("mixed", nnum=9, size=64, max_disparity=3.0, snr_db=40.0, seed=1)
    m = np.zeros(sv.disparity.shape, bool)
    m[15:-15, 15:-15] = True
    got = {}
    for edges in (None, EdgeSnap()):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the sweep's own warnings are tested elsewhere
            res = ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((9, 9), bool),
                                    edges=edges, refiner=None)
        got[edges is None] = score(res.disparity, sv.disparity, m)
    snapped, plain = got[False], got[True]
    assert snapped["mse"] <= 0.5 * plain["mse"], (snapped, plain)
    assert snapped["badpix"] <= plain["badpix"], (snapped, plain)


@pytest.mark.parametrize("kwargs", [dict(jump=0), dict(margin=-1.0), dict(certainty=float("nan")),
                                    dict(length=-1), dict(long_length=65), dict(iterations=0),
                                    dict(length=2.5)])
def test_edge_snap_settings_are_checked(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        EdgeSnap(**kwargs)


def test_estimate_depth_refuses_other_edge_settings():
    views = np.ones((5, 5, 16, 16), np.float32)
    with pytest.raises(TypeError, match="edges must be an EdgeSnap or None"):
        ms.estimate_depth(views, SystemConfig(nnum=5, scan=1), edges={"length": 4})
