"""Background pixels given the occluder's disparity, re-decided with the views that see them
(metasensor.depth.visibility). The full-size figures are bench_depth's."""

import numpy as np
import pytest
import torch
from scipy import ndimage

import metasensor as ms
from metasensor.depth.scenes import benchmark_scene, natural_scene
from metasensor.depth.visibility import Visibility, reveal_background


def _stack(sv):
    n = sv.config.nnum
    uu, vv = np.divmod(np.arange(n * n), n)
    c = sv.config.center
    views = torch.from_numpy(np.ascontiguousarray(sv.views.reshape(n * n, *sv.views.shape[2:])))
    return views, (uu - c).astype(float), (vv - c).astype(float), int(c * n + c)


def test_a_fattened_occluder_gives_the_background_back():
    sv = benchmark_scene("occluders", nnum=9, size=64, max_disparity=3.0, snr_db=40.0, seed=1)
    truth = sv.disparity
    # the three discs (nearer than the background: lower disparity) grown by 3 px
    grown = ndimage.grey_erosion(truth, size=(7, 7))
    fat = np.where(truth - grown > 0.5, grown, truth).astype(np.float32)
    changed = fat != truth
    assert changed.sum() > 100
    views, au, av, centre = _stack(sv)
    d = torch.from_numpy(fat)
    before = d.clone()
    out = reveal_background(views, au, av, centre, d, torch.ones_like(d)).numpy()
    assert torch.equal(d, before)                    # the input is not modified
    # each pixel keeps its value or takes one of its neighbourhood's
    r = Visibility().radius
    back = ndimage.maximum_filter(fat, size=2 * r + 1, mode="nearest")
    assert np.all((out == fat) | (out == back))
    err_before = np.abs(fat - truth)[changed]
    err_after = np.abs(out - truth)[changed]
    assert np.mean(err_after > 0.5) <= 0.5 * np.mean(err_before > 0.5)
    # the true occluders' own pixels stay
    assert np.mean(np.abs(out - truth)[~changed] > 0.5) <= 0.01


def test_default_estimate_is_better_with_it_on_a_photograph_scene():
    sv = natural_scene(nnum=9, size=64, max_disparity=3.0, snr_db=40.0, seed=1)
    m = np.zeros(sv.disparity.shape, bool)
    m[8:-8, 8:-8] = True
    # the refiner's removal of weak speckles, which also mends some of these pixels, off: the
    # step's own share
    kw = dict(view_mask=np.ones((9, 9), bool), refiner=ms.depth.EdgeRefiner(clean=None))
    on = ms.estimate_depth(sv.views, sv.config, **kw).disparity
    off = ms.estimate_depth(sv.views, sv.config, visibility=None, **kw).disparity
    mse_on = np.mean((on - sv.disparity)[m] ** 2)
    mse_off = np.mean((off - sv.disparity)[m] ** 2)
    assert mse_on < 0.8 * mse_off


@pytest.mark.parametrize("bad", [dict(jump=0), dict(radius=0), dict(window=-1), dict(rounds=0),
                                 dict(min_views=0), dict(tolerance=-1), dict(confident=2),
                                 dict(margin=1.0), dict(radius=2.5)])
def test_settings_are_checked(bad):
    with pytest.raises(ValueError, match="Visibility"):
        Visibility(**bad)


def test_estimate_depth_checks_the_settings_type():
    sv = benchmark_scene("planes", nnum=5, size=32, max_disparity=1.0, snr_db=None, seed=0)
    with pytest.raises(TypeError, match="visibility must be a Visibility"):
        ms.estimate_depth(sv.views, sv.config, visibility="on")


def _gap_views(n: int = 9, side: int = 64, seed: int = 0):
    """Views of a background at +3 px per view step seen through a 6-px horizontal gap between
    an occluder at 0 (above) and one at −3 (below, to the bottom): integer shifts, painted far
    to near. Only the views of the centre row (9 of 81) see the gap's middle clear."""
    rng = np.random.default_rng(seed)
    c = n // 2
    tex = [ndimage.gaussian_filter(rng.standard_normal((side, side)), 1.0) + 3.0
           for _ in range(3)]
    rows = np.arange(side)[:, None] * np.ones((1, side))
    layers = ((3, tex[0], rows >= 0), (0, tex[1], rows < 28), (-3, tex[2], rows >= 34))
    views = []
    for u in range(n):
        for v in range(n):
            img = np.zeros((side, side))
            for d, t, m in layers:
                s = (d * (u - c), d * (v - c))
                img = np.where(np.roll(m, s, axis=(0, 1)), np.roll(t, s, axis=(0, 1)), img)
            views.append(img)
    uu, vv = np.divmod(np.arange(n * n), n)
    truth = np.where(rows < 28, 0.0, np.where(rows >= 34, -3.0, 3.0)).astype(np.float32)
    return (torch.from_numpy(np.stack(views).astype(np.float32)), (uu - c).astype(float),
            (vv - c).astype(float), c * n + c, truth)


def test_a_background_gap_seen_by_one_row_of_views_is_given_back():
    views, au, av, centre, truth = _gap_views()
    gap = truth == 3.0
    # half the gap's pixels given the upper occluder's disparity, as a plane sweep leaves them
    wrong = gap & (np.random.default_rng(1).random(gap.shape) < 0.5)
    wrong[:, :12] = wrong[:, -12:] = False
    fat = torch.from_numpy(np.where(wrong, 0.0, truth).astype(np.float32))
    conf = torch.ones_like(fat)
    out = reveal_background(views, au, av, centre, fat, conf).numpy()
    share = np.mean(out[wrong] == 3.0)
    assert share >= 0.25
    assert np.mean(out[~wrong] != truth[~wrong]) <= 0.002
    # a quarter of the views (the earlier default) is more than see most of it
    strict = reveal_background(views, au, av, centre, fat, conf, Visibility(min_views=0.25))
    assert np.mean(strict.numpy()[wrong] == 3.0) <= 0.3 * share
