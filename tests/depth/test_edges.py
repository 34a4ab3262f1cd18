"""The plane sweep at thin structures and occluding edges: cubic resampling of the views and the
centre-view term of the variance cost (metasensor.depth.cost), on the hard rendered scenes at a
small size (the full-size figures are bench_depth's)."""

import functools
import warnings

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.depth import estimate
from metasensor.depth.cost import CostVolume
from metasensor.depth.evaluate import score
from metasensor.depth.geometry import view_offsets
from metasensor.depth.scenes import benchmark_scene


def _estimate(sv, **kwargs):
    n = sv.config.nnum
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the sweep's own warnings are tested elsewhere
        return ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((n, n), bool), **kwargs)


def _score(sv, disparity):
    m = np.zeros(sv.disparity.shape, bool)
    m[15:-15, 15:-15] = True
    return score(disparity, sv.disparity, m)


def test_cubic_sweep_on_a_slanted_plane_with_few_views(monkeypatch):
    """5 x 5 views at 30 dB, 96 px: bilinear resampling blurs each view by an amount that
    depends on the fractional part of its shift, which biases the cost minima (BadPix(0.07)
    34 % at this size; 13.6 % at 192 px before cubic resampling)."""
    sv = benchmark_scene("slanted", nnum=5, size=96, max_disparity=3.0, snr_db=30.0, seed=1)
    cubic = _score(sv, _estimate(sv).disparity)
    monkeypatch.setattr(estimate, "CostVolume",
                        functools.partial(CostVolume, resampling="linear"))
    linear = _score(sv, _estimate(sv).disparity)
    assert cubic["badpix"] <= 0.2 and cubic["badpix"] <= 0.6 * linear["badpix"], (cubic, linear)
    assert cubic["mse"] <= 0.6 * linear["mse"], (cubic, linear)


def test_centre_term_gives_bar_edges_the_layer_at_their_centre(monkeypatch):
    """Bars 1.5-4.5 view px wide (9 x 9 views, 40 dB, 64 px): pixels whose footprint the bar
    covers by a little more than half went to the background with the variance alone. The
    sweep's costs alone: without the re-decision of edge pixels (metasensor.depth.edges)."""
    sv = benchmark_scene("thin", nnum=9, size=64, max_disparity=3.0, snr_db=40.0, seed=1)
    with_centre = _score(sv, _estimate(sv, edges=None, refiner=None).disparity)
    monkeypatch.setattr(estimate, "CENTRE_WEIGHT", 0.0)
    variance = _score(sv, _estimate(sv, edges=None, refiner=None).disparity)
    assert with_centre["mse"] <= 0.5 * variance["mse"], (with_centre, variance)
    assert with_centre["badpix"] <= variance["badpix"], (with_centre, variance)


def test_centre_weight_adds_the_squared_distance_to_the_centre_view():
    rng = np.random.default_rng(0)
    views = torch.from_numpy(rng.random((9, 12, 14)).astype(np.float32))
    au, av = (a.ravel() for a in view_offsets(3))
    costs = {w: CostVolume(views, au, av, centre=4, max_disparity=1.0, centre_weight=w)
             .raw(0.3) for w in (0.0, 0.5, 1.0)}
    anchored = CostVolume(views, au, av, centre=4, max_disparity=1.0, cost="anchored").raw(0.3)
    torch.testing.assert_close(anchored, costs[1.0])
    torch.testing.assert_close(costs[0.5], 0.5 * (costs[0.0] + costs[1.0]))
    assert bool((costs[1.0] >= costs[0.0]).all()) and bool((costs[1.0] > costs[0.0]).any())
    for bad in (-0.1, float("nan"), "1"):
        with pytest.raises(ValueError, match="centre_weight"):
            CostVolume(views, au, av, centre=4, max_disparity=1.0, centre_weight=bad)
    with pytest.raises(ValueError, match="centre_weight"):
        CostVolume(views, au, av, centre=4, max_disparity=1.0, cost="sad", centre_weight=0.5)


def test_noise_floor_lets_a_flat_patch_take_its_surroundings():
    """A flat disc painted on a slanted background (5 x 5 views, 30 dB, 128 px): with the
    floor at 2 x the median minimum cost, noise decided the disc's interior (MSE x 100 about
    6 at this size)."""
    sv = benchmark_scene("textureless", nnum=5, size=128, max_disparity=3.0, snr_db=30.0,
                         seed=1)
    n = sv.config.nnum
    scores = {}
    for noise in (2.0, ms.depth.SemiGlobal().noise):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            # the refiner's removal of weak speckles off (it also mends some of the disc's
            # noise-decided pixels): the floor's own share
            res = ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((n, n), bool),
                                    smoothing=ms.depth.SemiGlobal(noise=noise),
                                    refiner=ms.depth.EdgeRefiner(clean=None))
        scores[noise] = _score(sv, res.disparity)
    low, default = scores[2.0], scores[ms.depth.SemiGlobal().noise]
    assert default["mse"] <= 0.5 * low["mse"] and default["badpix"] <= 0.1, (default, low)
    for bad in (0.0, -1.0, float("inf")):
        with pytest.raises(ValueError, match="noise"):
            ms.depth.SemiGlobal(noise=bad)
