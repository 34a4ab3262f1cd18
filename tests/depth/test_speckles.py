"""Removing speckles from a disparity map (metasensor.depth.speckle): what is removed, what
it is replaced by, what is kept. The full-size figures are bench_depth's."""

import warnings

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.depth.scenes import benchmark_scene
from metasensor.depth.speckle import Speckles, remove_speckles


def _map():
    d = torch.ones((40, 40))
    d[:, 20:] = -1.0                      # two layers
    d[10, 5] = -3.0                       # a lone outlier on the background
    d[30, 30:32] = 2.5                    # a two-pixel outlier on the front
    d[5:35, 12] = -1.0                    # a one-pixel-wide bar, 30 px long
    d[25:27, 8:10] = 0.2                  # a 2 x 2 object, another layer
    return d


def test_small_isolated_segments_take_their_neighbours_value():
    d = _map()
    before = d.clone()
    out = remove_speckles(d, amax=4.0)
    assert torch.equal(d, before)         # the input is not modified
    assert float(out[10, 5]) == 1.0 and bool((out[30, 30:32] == -1.0).all())
    assert bool((out[25:27, 8:10] == 1.0).all())   # 4 px <= size: removed
    assert bool((out[5:35, 12] == -1.0).all())     # the thin bar is kept
    changed = out != d
    assert int(changed.sum()) == 1 + 2 + 4
    # a smaller size keeps the 2 x 2 object; a step beyond the gaps joins everything
    assert bool((remove_speckles(d, 4.0, Speckles(size=3))[25:27, 8:10] == 0.2).all())
    assert torch.equal(remove_speckles(d, 4.0, Speckles(step=40.0)), d)


def test_estimate_depth_removes_speckles_on_plain_light_field_views_only():
    sv = benchmark_scene("occluders", nnum=5, size=48, max_disparity=3.0, snr_db=30.0, seed=3)
    # the refiner's own removal of weak speckles off, so that this scene keeps some for the last
    refiner = ms.depth.EdgeRefiner(clean=None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        on = ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((5, 5), bool),
                               refiner=refiner)
        off = ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((5, 5), bool),
                                refiner=refiner, speckles=None)
    again = remove_speckles(torch.from_numpy(off.disparity), 2.0).numpy()
    np.testing.assert_array_equal(on.disparity, again)
    assert (on.disparity != off.disparity).any()   # this scene has speckles
    # a removal restricted to weak pixels reads the estimator's confidence
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        weak = ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((5, 5), bool),
                                 refiner=refiner, speckles=Speckles(confidence=0.3))
    again = remove_speckles(torch.from_numpy(off.disparity), 2.0, Speckles(confidence=0.3),
                            torch.from_numpy(off.confidence)).numpy()
    np.testing.assert_array_equal(weak.disparity, again)


def test_only_weak_speckle_pixels_are_replaced_when_a_confidence_is_set():
    d = _map()
    conf = torch.ones_like(d)
    conf[10, 5] = 0.1                     # the lone outlier is weak
    conf[30, 30] = 0.19                   # one of the two-pixel outlier's pixels is weak
    out = remove_speckles(d, 4.0, Speckles(confidence=0.2), conf)
    changed = out != d
    assert int(changed.sum()) == 2 and bool(changed[10, 5]) and bool(changed[30, 30])
    assert float(out[10, 5]) == 1.0 and float(out[30, 30]) == -1.0
    # at confidence 1 every speckle pixel is weak: the same as without the setting
    assert torch.equal(remove_speckles(d, 4.0, Speckles(confidence=1.0), conf * 0.5),
                       remove_speckles(d, 4.0))
    with pytest.raises(ValueError, match="confidence"):
        remove_speckles(d, 4.0, Speckles(confidence=0.2))
    with pytest.raises(ValueError, match="shape"):
        remove_speckles(d, 4.0, Speckles(confidence=0.2), conf[:-1])


@pytest.mark.parametrize("kwargs", [dict(size=0), dict(size=2.5), dict(step=0),
                                    dict(step=float("inf")), dict(confidence=0),
                                    dict(confidence=1.5)])
def test_speckle_settings_are_checked(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        Speckles(**kwargs)


def test_estimate_depth_checks_the_speckles_type():
    views = np.random.default_rng(0).random((5, 5, 16, 16)).astype(np.float32)
    with pytest.raises(TypeError, match="speckles"):
        ms.estimate_depth(views, ms.SystemConfig(nnum=5, scan=1), speckles=4)
