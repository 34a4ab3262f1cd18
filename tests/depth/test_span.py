"""The disparity span is measured from the views, never clipped silently; plain light-field
cameras (scan 1, 5 x 5 to 9 x 9 views) with disparities of several view px per view step."""

import warnings

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.depth.evaluate import score
from metasensor.depth.scenes import SCENES, benchmark_scene
from metasensor.depth.span import measure_span


def _all_views(sv):
    n = sv.config.nnum
    return np.ones((n, n), bool)


def _estimate(sv, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a measured span that covers the scene warns of nothing
        return ms.estimate_depth(sv.views, sv.config, view_mask=_all_views(sv), **kw)


@pytest.mark.parametrize("kind,nnum,size,span", [("slanted", 5, 96, 4.0),
                                                 ("occluders", 7, 64, 3.0),
                                                 ("planes", 9, 64, 2.5)])
def test_default_span_covers_the_truth(kind, nnum, size, span):
    sv = benchmark_scene(kind, nnum=nnum, size=size, max_disparity=span, seed=3)
    res = _estimate(sv)
    assert res.span_source == "measured"
    assert res.candidates[0] <= sv.disparity.min() and res.candidates[-1] >= sv.disparity.max()
    assert max(res.saturated) <= 1e-3
    # the span is the scene's, not the widest search: within 2 view px of the truth's ends
    assert res.candidates[0] >= sv.disparity.min() - 2
    assert res.candidates[-1] <= sv.disparity.max() + 2


def test_scan1_light_field_is_not_clipped_to_the_configs_range():
    """SystemConfig(nnum=9, scan=1) has the natural range ±0.5; a scene at ±3 was clipped
    there silently (BadPix 97 %)."""
    sv = benchmark_scene("slanted", nnum=9, size=96, max_disparity=3.0, seed=1)
    res = _estimate(sv)
    m = np.zeros(sv.disparity.shape, bool)
    m[15:-15, 15:-15] = True
    s = score(res.disparity, sv.disparity, m)
    assert res.disparity.max() > 2.5 and res.disparity.min() < -2.5  # not clipped
    print(s)
    assert s["badpix"] < 0.25 and s["mse"] < 0.02, s


def test_a_given_span_that_clips_warns_and_masks():
    sv = benchmark_scene("planes", nnum=5, size=64, max_disparity=2.0, seed=0)
    with pytest.warns(RuntimeWarning, match="disparity_range"):
        res = ms.estimate_depth(sv.views, sv.config, view_mask=_all_views(sv),
                                disparity_range=(-0.5, 0.5))
    assert res.span_source == "given"
    assert res.saturated[0] > 0.15 and res.saturated[1] > 0.5  # planes at ∓1.6: beyond it


def test_measure_span_of_a_fronto_parallel_plane():
    sv = benchmark_scene("slanted", nnum=5, size=96, max_disparity=0.1, seed=2,
                         snr_db=30.0)
    shifted = sv.views.reshape(25, 96, 96)
    # a plane at +2.0 view px per view step: shift every view by 2 · offset (integer rolls)
    a = np.arange(5) - 2
    views = np.stack([np.roll(shifted[12], (2 * u, 2 * v), axis=(0, 1)) for u in a for v in a])
    est = measure_span(torch.from_numpy(views.astype(np.float32)), np.repeat(a, 5).astype(float),
                       np.tile(a, 5).astype(float), 12)
    lo, hi = est.span
    assert lo < 2.0 < hi and hi - lo < 2.5, est
    assert est.searched[0] <= -8 and est.searched[1] >= 8
    assert est.saturated == 0.0 and est.confident > 0.5


def test_scenes_are_validated():
    assert "thin" in SCENES
    with pytest.raises(ValueError, match="scene must be one of"):
        benchmark_scene("cube")
    with pytest.raises(ValueError, match="nnum"):
        benchmark_scene("planes", nnum=4)


def _plane_with_objects(blobs, size: int, side: int = 384):
    """5 x 5 views of a textured plane at +2 view px per view step carrying square objects of
    ``size`` px at +12 (integer shifts)."""
    from scipy import ndimage

    rng = np.random.default_rng(0)
    tex = (ndimage.gaussian_filter(rng.standard_normal((side + 64, side + 64)), 1.0) + 3.0)
    a = np.arange(5) - 2
    views = []
    for u in a:
        for v in a:
            img = np.roll(tex, (2 * u, 2 * v), axis=(0, 1))[:side, :side].copy()
            for y, x in blobs:
                ty, tx = 300 + y % 50, 300 + x % 50
                img[y + 12 * u:y + 12 * u + size, x + 12 * v:x + 12 * v + size] = (
                    1.5 * tex[ty:ty + size, tx:tx + size])
            views.append(img)
    au, av = np.repeat(a, 5).astype(float), np.tile(a, 5).astype(float)
    return torch.from_numpy(np.stack(views).astype(np.float32)), au, av


def test_isolated_coarse_pixels_do_not_stretch_the_span():
    # 64 objects of 2 x 2 coarse pixels (coarse factor 4), 0.7 % of the view: speckles of the
    # coarse map; with them counted the span ran to the search's ends (±16)
    small = [(y, x) for y in range(40, 340, 40) for x in range(40, 340, 40)]
    views, au, av = _plane_with_objects(small, 8)
    lo, hi = measure_span(views, au, av, 12).span
    assert lo < 2.0 < hi and hi < 8.0 and lo > -4.0, (lo, hi)
    # one object of 16 x 16 coarse pixels is a region: the span covers it
    views, au, av = _plane_with_objects([(150, 150)], 64)
    lo, hi = measure_span(views, au, av, 12).span
    assert lo < 2.0 and hi > 12.0, (lo, hi)
