"""simulate(): geometry, exact realignment, photometry, point sources, field-dependent blur."""

import numpy as np
import pytest

import metasensor as ms
from metasensor.optics.field import block_centres_normalised
from metasensor.simulate.capture import simulate

CFG = ms.SystemConfig(sensor_shape=(132, 132))
N = 15


def _scene(shape=(132, 132), seed=0):
    return np.random.default_rng(seed).random(shape).astype(np.float32)


@pytest.mark.parametrize("scan", [1, 3, 5, 15])
@pytest.mark.parametrize("order", ["row-major", "serpentine"])
def test_realign_of_frames_equals_views_exactly(scan, order):
    cap = simulate(_scene(), CFG, scan=scan, scan_order=order, snr_db=25, comparison=False)
    assert cap.frames.dtype == np.uint16 and cap.frames.shape == (scan * scan, 132, 132)
    assert cap.config.scan == scan
    ly = (132 - (scan - 1) * (N // scan)) // N
    assert cap.views.shape == (N, N, ly * scan, ly * scan)
    assert cap.truth.shape == (ly * N, ly * N)
    again = ms.realign(cap.frames, cap.config, cap.scan_order)
    assert np.array_equal(again, cap.views)
    assert cap.views_clean.dtype == np.float32 and cap.views_clean.shape == cap.views.shape


def test_scan_none_uses_config_and_order_list_sets_period():
    cap = simulate(_scene(), CFG.replace(scan=3), comparison=False)
    assert cap.config.scan == 3 and len(cap.scan_order) == 9
    order = ms.scan_order(5, "serpentine")
    cap = simulate(_scene(), CFG, scan_order=order, comparison=False)
    assert cap.config.scan == 5 and cap.scan_order == order


def test_truth_is_the_scaled_scene_on_the_reconstruction_grid():
    scene = _scene()
    cap = simulate(scene, CFG, scan=5, comparison=False)
    o = (N - 3) // 2
    np.testing.assert_allclose(cap.truth, scene[o:o + 120, o:o + 120] * cap.scale, rtol=1e-6)
    assert cap.offset == o
    # brightest clean sample at the default exposure (80 % of a 12-bit full scale)
    assert abs(cap.views_clean.max() - 0.8 * 4095) < 1e-2


def test_uniform_scene_gives_flat_views_and_conserves_photons():
    # analytic: V_uv = s * Σ_yx H_uv for a uniform scene s; away from the borders every view is
    # flat (tolerance 1 %), and Σ_uv V_uv = s * (fraction of a lenslet passed by its aperture)
    # * nnum², i.e. photons on one lenslet block = scene flux over it × transmission
    shape = (222, 222)
    scene = np.full(shape, 2.0, np.float32)
    cap = simulate(scene, CFG, scan=3, comparison=False)
    v = cap.views_clean / cap.scale
    m = CFG.view_mask()
    inner = v[:, :, 10:-10, 10:-10]
    rel = inner[m].std(axis=(1, 2)) / inner[m].mean(axis=(1, 2))
    assert rel.max() < 0.01
    bank = ms.view_psfs(CFG) if not _standin() else _fake_bank()
    transmission = bank.sum() / N**2
    per_block = inner.sum(axis=(0, 1))
    np.testing.assert_allclose(per_block, 2.0 * N**2 * transmission, rtol=0.01)
    # raw frames: Σ over one frame's lenslet blocks (inner ones) = the same per block
    frame = cap.frames[0].astype(np.float64) / cap.scale
    blocks = frame[:14 * N, :14 * N].reshape(14, N, 14, N).sum(axis=(1, 3))
    np.testing.assert_allclose(blocks[2:-2, 2:-2], 2.0 * N**2 * transmission, rtol=0.01)


def _standin():
    import sys

    return getattr(sys.modules["metasensor.optics.psf"], "__file__", None) is None


def _fake_bank():
    import sys

    return sys.modules["metasensor.optics.psf"].view_psfs(CFG)


def test_point_source_reproduces_view_psfs():
    # a one-pixel scene = a point (its sub-pixel spline spread is the only model difference);
    # every in-pupil view sample at the scan spacing matches view_psfs within 1 % r.m.s.
    cfg = CFG.replace(scan=5)
    scene = np.zeros((135, 135), np.float32)
    y0 = x0 = 67
    scene[y0, x0] = 1.0
    cap = simulate(scene, cfg, comparison=False)
    v = cap.views_clean / cap.scale
    bank = ms.view_psfs(cfg) if not _standin() else _fake_bank()
    c = bank.shape[-1] // 2
    pos = np.arange(v.shape[2]) * 3 + N // 2 - y0
    sel = np.abs(pos) <= c
    ref = bank[:, :, c + pos[sel]][:, :, :, c + pos[sel]]
    got = v[:, :, sel][:, :, :, sel]
    m = cfg.view_mask()
    err = np.sqrt(np.mean((got[m] - ref[m]) ** 2)) / np.sqrt(np.mean(ref[m] ** 2))
    assert err < 0.01


def test_field_dependent_points_blurred_by_their_own_psf():
    # 2 x 2 blocks with different tilts; points at the block centres must look like the local
    # (uniform-aberration) simulation of that block's Zernike vector, and not like the others'
    shape = (192, 192)
    grid = np.zeros((2, 2, 3))
    grid[0, 0, 1], grid[0, 1, 2], grid[1, 0, 1], grid[1, 1, 2] = 0.4, 0.4, -0.4, -0.4
    yn, xn = block_centres_normalised(2, 2)
    scene = np.zeros(shape, np.float32)
    pts = [(int(round((y + 1) / 2 * 192 - 0.5)), int(round((x + 1) / 2 * 192 - 0.5)))
           for y, x in zip(yn.ravel(), xn.ravel(), strict=True)]
    for y, x in pts:
        scene[y, x] = 1.0
    cap = simulate(scene, CFG, field_zernike=grid, scan=3, comparison=False, scale=1.0)
    for k, (y, x) in [(0, pts[0]), (3, pts[3])]:
        local = np.zeros(shape, np.float32)
        local[y, x] = 1.0
        ref = simulate(local, CFG, zernike=grid.reshape(4, 3)[k], scan=3, comparison=False,
                       scale=1.0).views_clean
        other = simulate(local, CFG, zernike=grid.reshape(4, 3)[(k + 1) % 4], scan=3,
                         comparison=False, scale=1.0).views_clean
        win = _window(y, x)
        got = cap.views_clean[win]
        err = np.linalg.norm(got - ref[win]) / np.linalg.norm(ref[win])
        err_other = np.linalg.norm(got - other[win]) / np.linalg.norm(ref[win])
        assert err < 0.02 and err_other > 0.3, (k, err, err_other)


def _window(y, x, half=6, d=5):
    o = N // 2
    ys = slice(max((y - o) // d - half, 0), (y - o) // d + half)
    xs = slice(max((x - o) // d - half, 0), (x - o) // d + half)
    return (slice(None), slice(None), ys, xs)


def test_same_seed_same_capture_and_inputs_untouched():
    scene = _scene()
    keep = scene.copy()
    a = simulate(scene, CFG, scan=3, snr_db=20, seed=4, comparison=False)
    b = simulate(scene, CFG, scan=3, snr_db=20, seed=4, comparison=False)
    c = simulate(scene, CFG, scan=3, snr_db=20, seed=5, comparison=False)
    assert np.array_equal(a.frames, b.frames) and not np.array_equal(a.frames, c.frames)
    assert np.array_equal(scene, keep)


@pytest.mark.parametrize("bad,kw,msg", [
    (np.zeros((10, 10)), {}, "holds no lenslet"),
    (np.zeros((3, 40, 40)), {}, "2D array"),
    (np.full((40, 40), np.nan), {}, "NaN"),
    (-np.ones((40, 40)), {}, "non-negative"),
    (np.ones((40, 40)), {"scan": 4}, "scan period 4"),
    (np.ones((40, 40)), {"zernike": [0, np.inf]}, "zernike"),
    (np.ones((40, 40)), {"snr_db": 20, "photons": 100}, "either snr_db or photons"),
    (np.ones((40, 40)), {"bit_depth": 13}, "bit_depth"),
])
def test_bad_input_clear_error(bad, kw, msg):
    with pytest.raises((ValueError, TypeError), match=msg):
        simulate(bad, CFG, comparison=False, **kw)
