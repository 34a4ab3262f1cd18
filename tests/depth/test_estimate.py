"""estimate_depth on geometric light-field scenes with known depth (metasensor.depth.synthetic):
accuracy (BadPix, MSE), meta-imaging vs a plain light-field camera, the aberration warp, any
square view grid, the metric-depth conversion and bad input."""

from functools import cache

import numpy as np
import pytest
from scipy import ndimage

import metasensor as ms
from metasensor.depth import geometry, synthetic
from metasensor.depth.evaluate import evaluation_mask, score

CFG = ms.SystemConfig(scan=5)
SHAPE = (210, 210)  # image pixels → 70 x 70 views at scan 5


@cache
def _scene(name: str, scan: int = 5, shape=SHAPE, snr_db: float = 30.0):
    makers = {
        # disparities in IMAGE pixels per view step (÷ d = 3 for view pixels)
        "planes": lambda: synthetic.scene_planes(shape, near=-1.5, far=1.0, seed=1),
        "slanted": lambda: synthetic.scene_slanted(shape, -2.0, 2.0, seed=2),
        "staircase": lambda: synthetic.scene_staircase(shape, 4, -2.0, 2.0, seed=3),
    }
    tex, layers = makers[name]()
    return synthetic.render_views(tex, layers, CFG, scan=scan, snr_db=snr_db, seed=0)


def _textured_mask(sv, edge_margin=3):
    c = sv.config.center
    return evaluation_mask(sv.disparity, sv.views_clean[c, c], edge_margin=edge_margin,
                           texture_fraction=0.1)


@pytest.mark.parametrize("name", ["planes", "slanted", "staircase"])
def test_badpix_under_10_percent_on_textured_regions(name):
    # Acceptance: BadPix(0.07 view px per view step) < 10 % on textured regions (SNR 30 dB),
    # excluding 3 view px around depth discontinuities (the lenslet aperture blurs the views
    # over 5 view px at scan 5, so depth there is mixed by the optics) and the border.
    sv = _scene(name)
    res = ms.estimate_depth(sv.views, CFG)
    mask = _textured_mask(sv)
    s = score(res.disparity, sv.disparity, mask)
    s_all = score(res.disparity, sv.disparity)
    print(f"{name}: BadPix(0.07) {s['badpix']:.4f}  MSE {s['mse']:.2e}  coverage "
          f"{s['coverage']:.2f}; all pixels: BadPix {s_all['badpix']:.4f} MSE {s_all['mse']:.2e}")
    assert s["coverage"] > 0.5
    assert s["badpix"] < 0.10
    assert s["mse"] < 0.07**2
    # the sign convention: the near square / the left of the ramp has negative disparity
    assert np.sign(np.median(res.disparity[mask & (sv.disparity < -0.1)])) == -1


def test_meta_imaging_beats_plain_light_field_camera():
    # Same scene, optics and SNR; scan 5 (views every 3 image px) vs scan 1 (every 15 px).
    # Common unit: disparity in IMAGE pixels per view step (∝ image-side depth z, since
    # z = δ_img · mla_focal), compared on the scan-1 sample positions, which are a subset of the
    # scan-5 grid (view sample Y sits at image pixel Y·d + d//2: 15 Y + 7 = 3 (5 Y + 2) + 1).
    shape = (300, 300)
    errs = {}
    for scan in (5, 1):
        sv = _scene("slanted", scan=scan, shape=shape)
        cfg = CFG.replace(scan=scan)
        res = ms.estimate_depth(sv.views, cfg)
        d = cfg.scan_step_px
        est, tru = res.disparity * d, sv.disparity * d
        if scan == 5:
            est, tru = est[2::5, 2::5], tru[2::5, 2::5]
        errs[scan] = (est, tru)
    tru = errs[1][1]
    assert np.allclose(errs[5][1], tru)
    mask = evaluation_mask(tru, edge_margin=1, border=1, jump=1.0)  # a smooth slant: no jumps
    s5 = score(errs[5][0], tru, mask, threshold=0.35)   # 0.35 image px = 0.07 view px at scan 5
    s1 = score(errs[1][0], tru, mask, threshold=0.35)
    print(f"image-px RMSE: scan 5 {s5['rmse']:.3f}, scan 1 {s1['rmse']:.3f}; BadPix(0.35 px): "
          f"{s5['badpix']:.3f} vs {s1['badpix']:.3f}")
    assert s5["rmse"] < 0.5 * s1["rmse"]
    assert s5["badpix"] < 0.5 * s1["badpix"]


@cache
def _aberrated_scene():
    tex, layers = synthetic.scene_slanted(SHAPE, -1.5, 1.5, seed=4)
    hv = SHAPE[0] // CFG.scan_step_px
    maps = synthetic.aberration_shift_maps(CFG, (hv, hv), curvature=0.15, astig=0.1, coma=0.1)
    sv = synthetic.render_views(tex, layers, CFG, shift_maps=maps, snr_db=30, seed=0)
    raw = score(ms.estimate_depth(sv.views, CFG).disparity, sv.disparity,
                evaluation_mask(sv.disparity, border=4))
    return sv, maps, hv, raw


def test_calibrated_warp_reduces_depth_error_by_30_percent():
    # Field-dependent aberration (field curvature, astigmatism, coma growing with the field):
    # per-view shift maps that vary smoothly over the field, added to the parallax.
    sv, maps, hv, raw = _aberrated_scene()
    mask = evaluation_mask(sv.disparity, border=4)

    class SystemAberrationLike:  # the DAO stage's object: .shift_maps(shape)
        def shift_maps(self, shape):
            assert shape == (hv, hv)
            return maps

    cal = score(ms.estimate_depth(sv.views, CFG, calibration=SystemAberrationLike()).disparity,
                sv.disparity, mask)
    print(f"RMSE without calibration {raw['rmse']:.4f}, with {cal['rmse']:.4f}")
    assert cal["rmse"] <= 0.7 * raw["rmse"]
    assert cal["badpix"] < raw["badpix"]


def test_calibration_file_of_the_dao_stage(tmp_path):
    # a SystemAberration (dao.system_aberration) holding the shifts on a coarse 9 x 9 grid, saved as
    # system.h5 and passed by path: loaded lazily, resampled, and it still removes the error
    from metasensor.dao.system_aberration import SystemAberration

    sv, maps, hv, raw = _aberrated_scene()
    idx = np.linspace(0, hv - 1, 9).round().astype(int)
    sa = SystemAberration(zernike=np.zeros((1, 1, 45)), shift_grid=maps[..., idx[:, None], idx],
                          view_shape=(hv, hv), config=CFG)
    path = sa.save(tmp_path / "system.h5")
    mask = evaluation_mask(sv.disparity, border=4)
    by_path = ms.estimate_depth(sv.views, CFG, calibration=str(path))
    by_maps = ms.estimate_depth(sv.views, CFG, calibration=sa.shift_maps((hv, hv)))
    np.testing.assert_allclose(by_path.disparity, by_maps.disparity, atol=1e-6)
    cal = score(by_path.disparity, sv.disparity, mask)
    print(f"system.h5 (9 x 9 grid): RMSE {raw['rmse']:.4f} -> {cal['rmse']:.4f}")
    assert cal["rmse"] <= 0.7 * raw["rmse"]


def test_nine_by_nine_light_field_all_views_wide_range():
    # A camera-array-like 9 x 9 light field (sharp views, every view used), two fronto-parallel
    # planes at 1.3 and -0.8 px per view step: disparities of several pixels, any square grid.
    cfg = ms.SystemConfig(nnum=9, mla_pitch=9 * 4.6e-6, scan=1)
    rng = np.random.default_rng(7)
    tex = ndimage.gaussian_filter(rng.random((110, 110)), 1.5)
    sq = np.zeros((110, 110))
    sq[35:75, 35:75] = 1
    views = np.empty((9, 9, 70, 70), dtype=np.float32)
    for u in range(9):
        for v in range(9):
            a = (u - 4, v - 4)
            bg = ndimage.shift(tex, (1.3 * a[0], 1.3 * a[1]), order=3, mode="nearest")
            fg = ndimage.shift(tex[::-1] * sq, (-0.8 * a[0], -0.8 * a[1]), order=3)
            al = ndimage.shift(sq, (-0.8 * a[0], -0.8 * a[1]), order=1)
            views[u, v] = (bg * (1 - al) + fg)[20:90, 20:90]
    truth = np.where(sq[20:90, 20:90] > 0.5, -0.8, 1.3)
    res = ms.estimate_depth(views + 0.5, cfg, view_mask=np.ones((9, 9), bool),
                            disparity_range=(-3, 3))
    s = score(res.disparity, truth, evaluation_mask(truth, edge_margin=2))
    print(f"9x9: BadPix(0.07) {s['badpix']:.4f} MSE {s['mse']:.2e}")
    assert s["badpix"] < 0.10
    assert s["mse"] < 0.005  # no pixel filled with a mixture of the two planes


def test_contract_and_metric_depth_round_trip():
    # a fronto-parallel plane at a known object distance through a known main lens
    f, s0, s_obj = 0.05, 2.0, 2.5
    cfg = CFG.replace(focal_length=f, focus_distance=s0)
    z = geometry.object_distance_to_image_depth(s_obj, f, s0)
    d_img = float(z / cfg.mla_focal)  # image px per view step
    tex = synthetic.random_texture((150, 150), seed=5)
    sv = synthetic.render_views(tex, [synthetic.Layer(np.ones((150, 150)), d_img)], cfg,
                                snr_db=35, seed=1)
    res = ms.estimate_depth(sv.views, cfg)
    h, w = sv.views.shape[2:]
    assert res.disparity.shape == res.confidence.shape == res.depth.shape == (h, w)
    assert res.disparity.dtype == np.float32 and res.depth.dtype == np.float32
    assert 0.0 <= res.confidence.min() and res.confidence.max() <= 1.0
    assert res.depth_kind == "object" and res.depth is res.object_distance
    inner = (slice(4, -4), slice(4, -4))
    assert np.median(res.disparity[inner]) == pytest.approx(d_img / 3, abs=0.01)
    np.testing.assert_allclose(res.image_depth, res.disparity * 3 * cfg.mla_focal, rtol=1e-5)
    assert np.median(res.depth[inner]) == pytest.approx(s_obj, rel=0.03)
    # without the main-lens geometry: image-side depth only; depth is None (the contract)
    res2 = ms.estimate_depth(sv.views, CFG, refine_iterations=0)
    assert res2.depth_kind == "image" and res2.object_distance is None
    assert res2.depth is None and res2.image_depth.shape == (h, w)
    # confident where textured: the textured plane scores higher than a flat field
    flat = np.ones_like(sv.views) + 0.001 * np.random.default_rng(0).standard_normal(
        sv.views.shape).astype(np.float32)
    flat[~CFG.view_mask()] = 0
    res3 = ms.estimate_depth(flat, CFG, refine_iterations=0)
    assert np.median(res.confidence[inner]) > 2 * np.median(res3.confidence[inner])


def test_bad_input_one_line_errors_and_inputs_unchanged():
    sv = _scene("planes")
    views = sv.views[:, :, :24, :24].copy()
    before = views.copy()
    ms.estimate_depth(views, CFG, candidates=8, refine_iterations=1)
    np.testing.assert_array_equal(views, before)
    with pytest.raises(ValueError, match="shape"):
        ms.estimate_depth(views[0], CFG)
    with pytest.raises(ValueError, match="nnum"):
        ms.estimate_depth(views[:13, :13], CFG)
    bad = views.copy()
    bad[7, 7, 3, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        ms.estimate_depth(bad, CFG)
    with pytest.raises(TypeError, match="SystemConfig"):
        ms.estimate_depth(views, {"nnum": 15})
    mask = CFG.view_mask().copy()
    mask[7, 7] = False
    with pytest.raises(ValueError, match="centre view"):
        ms.estimate_depth(views, CFG, view_mask=mask)
    with pytest.raises(ValueError, match="calibration shift maps must have shape"):
        ms.estimate_depth(views, CFG, calibration=np.zeros((15, 15, 2, 5, 5)))
    with pytest.raises(ValueError, match="NaN"):
        ms.estimate_depth(views, CFG, calibration=np.full((15, 15, 2), np.nan))
    with pytest.raises(FileNotFoundError, match="system calibration"):
        ms.estimate_depth(views, CFG, calibration="/nonexistent/system.h5")
    with pytest.raises(ValueError, match="disparity_range"):
        ms.estimate_depth(views, CFG, disparity_range=(1.0, -1.0))
    with pytest.raises(ValueError, match="non-positive mean"):
        ms.estimate_depth(views - 10.0, CFG)
    # field-constant shifts (nnum, nnum, 2) are accepted and broadcast
    ms.estimate_depth(views, CFG, calibration=np.zeros((15, 15, 2)), candidates=8,
                      refine_iterations=0)


def test_fill_gives_textureless_regions_the_surrounding_depth():
    # a plane at 0.3 view px per view step with a textureless disc (radius 15 view px): the plane
    # sweep cannot see depth inside it (confidence ~0); filling from the confident surround does
    tex = synthetic.random_texture(SHAPE, seed=6)
    yy, xx = np.mgrid[:SHAPE[0], :SHAPE[1]]
    tex = np.where((yy - 105) ** 2 + (xx - 105) ** 2 < 45**2, 0.55, tex).astype(np.float32)
    sv = synthetic.render_views(tex, [synthetic.Layer(np.ones(SHAPE), 0.9)], CFG, snr_db=30)
    inner = ((yy - 105) ** 2 + (xx - 105) ** 2 < 30**2)[1::3, 1::3]
    raw = ms.estimate_depth(sv.views, CFG, fill=False)
    filled = ms.estimate_depth(sv.views, CFG, fill=True)
    assert raw.confidence[inner].mean() < 0.2 < raw.confidence[~inner].mean()
    bad_raw = np.mean(np.abs(raw.disparity[inner] - 0.3) > 0.07)
    bad_filled = np.mean(np.abs(filled.disparity[inner] - 0.3) > 0.07)
    print(f"textureless disc: BadPix {bad_raw:.3f} without fill, {bad_filled:.3f} with")
    assert bad_raw > 0.3 and bad_filled < 0.05
    # confident pixels are left as they were
    sure = raw.confidence >= 0.1
    np.testing.assert_array_equal(filled.disparity[sure], raw.disparity[sure])


def test_views_smaller_than_the_fill_radius_run_with_default_settings():
    # 12-px views (a small crop): the default fill radius shrinks to the views' side
    views = np.random.default_rng(3).random((5, 5, 12, 12)).astype(np.float32)
    cfg = ms.SystemConfig(nnum=5, mla_pitch=5 * 4.6e-6, mla_focal=5 * 46e-6, scan=1)
    res = ms.estimate_depth(views, cfg)
    assert res.disparity.shape == (12, 12) and np.isfinite(res.disparity).all()
    with pytest.raises(ValueError, match="fill_radius"):
        ms.estimate_depth(views, cfg, fill_radius=16)  # asked for explicitly: refused
