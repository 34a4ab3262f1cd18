"""Depth through the wave-optics simulator (ms.simulate: layered rendering with the coded-MLA
phase-space PSFs, photon/read noise, realignment): the acceptance scenes with known depth.

The simulator's ``depth`` is the image-side depth z [m]; the true disparity at view sample
(Y, X) is ``z / (d · mla_focal)`` view px per view step, with z read at sensor pixel
``(Y·d + nnum//2, X·d + nnum//2)`` (the lenslet centre, simulation.capture docstring).
Slow (PSF banks for every depth plane): not in the default suite.
"""

import numpy as np
import pytest

import metasensor as ms
from metasensor.depth import synthetic
from metasensor.depth.evaluate import evaluation_mask, score

pytestmark = pytest.mark.slow

N = 240
CFG = ms.SystemConfig(scan=5)


def _depth_map(kind: str) -> np.ndarray:
    """Image-side depth [m] on the scene grid; values in image px per view step × mla_focal."""
    x = np.linspace(-2.0, 2.0, N)
    if kind == "planes":
        z = np.full((N, N), 1.0)
        z[N // 4: 3 * N // 4, N // 4: 3 * N // 4] = -1.5
    elif kind == "slanted":
        z = x[None, :] * np.ones((N, 1))
    else:  # staircase: 4 steps from -2 to 2 px per view step
        z = np.repeat(np.linspace(-2, 2, 4), N // 4)[None, :] * np.ones((N, 1))
    return z * CFG.mla_focal


def _truth(depth: np.ndarray, cfg: ms.SystemConfig, shape) -> np.ndarray:
    d, n = cfg.scan_step_px, cfg.nnum
    ys = np.arange(shape[0]) * d + n // 2
    xs = np.arange(shape[1]) * d + n // 2
    return depth[np.ix_(ys, xs)] / (d * cfg.mla_focal)


@pytest.mark.parametrize("kind", ["planes", "slanted", "staircase"])
def test_simulated_scenes_badpix_under_10_percent(kind):
    depth = _depth_map(kind)
    tex = synthetic.random_texture((N, N), seed=11)
    cap = ms.simulate(tex, CFG, depth=depth, snr_db=30, seed=0, comparison=False,
                      depth_planes=9)
    truth = _truth(depth, cap.config, cap.views.shape[2:])
    res = ms.estimate_depth(cap.views, cap.config)
    c = cap.config.center
    # The simulator adds its depth layers without occlusion and its defocused PSFs spread each
    # layer over the full-aperture blur, diameter 2·NA·|z|: within that radius of a depth edge the
    # views mix both depths. Excluded: that radius at the largest |z| (in view px) + 1.
    margin = int(np.ceil(CFG.na * np.abs(depth).max() / CFG.pixel_pitch / 3)) + 1
    mask = evaluation_mask(truth, cap.views_clean[c, c], edge_margin=margin,
                           texture_fraction=0.1)
    s = score(res.disparity, truth, mask)
    s_all = score(res.disparity, truth)
    print(f"simulated {kind}: BadPix(0.07) {s['badpix']:.4f} MSE {s['mse']:.2e} "
          f"(coverage {s['coverage']:.2f}, edge margin {margin}); all pixels BadPix "
          f"{s_all['badpix']:.4f} MSE {s_all['mse']:.2e}")
    assert s["badpix"] < 0.10


def test_simulated_meta_imaging_beats_plain_light_field():
    depth = _depth_map("slanted")
    tex = synthetic.random_texture((N, N), seed=12)
    est = {}
    for scan in (5, 1):
        cap = ms.simulate(tex, CFG, depth=depth, scan=scan, snr_db=30, seed=0,
                          comparison=False, depth_planes=9)
        cfg = cap.config
        d = cfg.scan_step_px
        res = ms.estimate_depth(cap.views, cfg)
        truth = _truth(depth, cfg, cap.views.shape[2:])
        # common unit: image px per view step; common positions: the lenslet centres of phase
        # (0, 0), i.e. every 5th sample of the scan-5 views
        e, t = res.disparity * d, truth * d
        if scan == 5:
            e, t = e[::5, ::5], t[::5, ::5]
        est[scan] = (e, t)
    (e5, t5), (e1, t1) = est[5], est[1]
    h = min(t5.shape[0], t1.shape[0])
    w = min(t5.shape[1], t1.shape[1])
    assert np.allclose(t5[:h, :w], t1[:h, :w])
    mask = evaluation_mask(t1[:h, :w], edge_margin=1, border=1, jump=1.0)
    s5 = score(e5[:h, :w], t1[:h, :w], mask, threshold=0.35)
    s1 = score(e1[:h, :w], t1[:h, :w], mask, threshold=0.35)
    print(f"simulated slant, image px/step RMSE: scan 5 {s5['rmse']:.3f}, scan 1 {s1['rmse']:.3f}")
    assert s5["rmse"] < s1["rmse"]
