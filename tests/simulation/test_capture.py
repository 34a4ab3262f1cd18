"""simulate(): geometry, exact realignment, photometry, point sources, field-dependent blur."""

import numpy as np
import pytest

import metasensor as ms
from conftest import SMALL
from metasensor.optics.field import block_centres_normalised
from metasensor.simulation.capture import simulate

CFG = ms.SystemConfig(sensor_shape=(132, 132))
N = 15


def _scene(shape=(132, 132), seed=0):
    return np.random.default_rng(seed).random(shape).astype(np.float32)


@pytest.mark.parametrize("scan", [1, 3, 5, 15])
@pytest.mark.parametrize("order", ["row-major", "serpentine"])
def test_realign_of_frames_equals_views_exactly(scan, order, standin):
    cap = simulate(_scene(), CFG, scan=scan, scan_order=order, snr_db=25, comparison=False)
    assert cap.frames.dtype == np.uint16 and cap.frames.shape == (scan * scan, 132, 132)
    assert cap.config.scan == scan
    ly = (132 - (scan - 1) * (N // scan)) // N
    assert cap.views.shape == (N, N, ly * scan, ly * scan)
    assert cap.truth.shape == (ly * N, ly * N)
    again = ms.realign(cap.frames, cap.config, cap.scan_order)
    assert np.array_equal(again, cap.views)
    assert cap.views_clean.dtype == np.float32 and cap.views_clean.shape == cap.views.shape


def test_scan_none_uses_config_and_order_list_sets_period(standin):
    cap = simulate(_scene(), CFG.replace(scan=3), comparison=False)
    assert cap.config.scan == 3 and len(cap.scan_order) == 9
    order = ms.scan_order(5, "serpentine")
    cap = simulate(_scene(), CFG, scan_order=order, comparison=False)
    assert cap.config.scan == 5 and cap.scan_order == order


def test_truth_is_the_scaled_scene_on_the_reconstruction_grid(standin):
    scene = _scene()
    cap = simulate(scene, CFG, scan=5, comparison=False)
    o = (N - 3) // 2
    np.testing.assert_allclose(cap.truth, scene[o:o + 120, o:o + 120] * cap.scale, rtol=1e-6)
    assert cap.offset == o
    # brightest clean sample at the default exposure (80 % of a 12-bit full scale)
    assert abs(cap.views_clean.max() - 0.8 * 4095) < 1e-2


def test_uniform_scene_gives_flat_views_and_conserves_photons(view_bank):
    # analytic: V_uv = s Σ_yx H_uv for a uniform scene s, so away from the borders every view is
    # flat (tolerance 1 %), and Σ_uv V_uv = s n² T with T = Σ H / n² the fraction of a lenslet's
    # light passed by its aperture: photons on one lenslet block = scene flux over it × T (1 %)
    cfg, n = SMALL, SMALL.nnum
    scene = np.full((96, 96), 2.0, np.float32)
    cap = simulate(scene, cfg, comparison=False)
    bank = view_bank(cfg)
    edge = bank.shape[-1] // 2 + 2
    v = (cap.views_clean / cap.scale)[:, :, edge:-edge, edge:-edge]
    lit = bank.sum(axis=(2, 3)) > 0.05 * bank.sum(axis=(2, 3)).max()
    rel = v[lit].std(axis=(1, 2)) / v[lit].mean(axis=(1, 2))
    assert rel.max() < 0.01
    np.testing.assert_allclose(v.mean(axis=(2, 3)), 2.0 * bank.sum(axis=(2, 3)), rtol=0.01,
                               atol=1e-3 * bank.sum())
    transmission = bank.sum() / n**2
    np.testing.assert_allclose(v.sum(axis=(0, 1)), 2.0 * n**2 * transmission, rtol=0.01)
    # raw frames: Σ over each inner lenslet block of frame 0 = the same flux
    frame = cap.frames[0].astype(np.float64) / cap.scale
    ly = (96 - (cfg.scan - 1)) // n
    blocks = frame[:ly * n, :ly * n].reshape(ly, n, ly, n).sum(axis=(1, 3))
    k = edge // n + 1
    np.testing.assert_allclose(blocks[k:-k, k:-k], 2.0 * n**2 * transmission, rtol=0.01)


@pytest.mark.parametrize("upsample,tol", [("point", 0.01), ("spline", 0.15)])
def test_point_source_reproduces_view_psfs(view_bank, upsample, tol):
    # a point-source scene (upsample="point": each pixel a point at its centre): every view sample
    # at the scan spacing matches view_psfs within 1 % r.m.s. A one-pixel scene under the default
    # continuous (spline) model is a 0.4-px blob, not a point: it blurs the lenslet-edge steps of
    # the PSFs (measured 11.7 % r.m.s. for nnum = 5; only a bound is checked)
    cfg, n = SMALL, SMALL.nnum
    d = cfg.scan_step_px
    scene = np.zeros((96, 96), np.float32)
    y0 = x0 = 48
    scene[y0, x0] = 1.0
    cap = simulate(scene, cfg, comparison=False, upsample=upsample)
    v = cap.views_clean / cap.scale
    bank = view_bank(cfg)
    c = bank.shape[-1] // 2
    pos = np.arange(v.shape[2]) * d + n // 2 - y0
    sel = np.abs(pos) <= c
    ref = bank[:, :, c + pos[sel]][:, :, :, c + pos[sel]]
    got = v[:, :, sel][:, :, :, sel]
    err = np.sqrt(np.mean((got - ref) ** 2)) / np.sqrt(np.mean(ref**2))
    assert err < tol


def test_field_dependent_points_blurred_by_their_own_psf():
    # 1 x 2 blocks with opposite x-tilts; the point at each block centre must match the uniform-
    # aberration simulation of that block's Zernike vector (2 %) and not the other block's
    cfg = SMALL
    shape = (64, 128)
    grid = np.zeros((1, 2, 3))
    grid[0, 0, 1], grid[0, 1, 1] = 0.5, -0.5
    yn, xn = block_centres_normalised(1, 2)
    pts = [(int((y + 1) / 2 * shape[0]), int((x + 1) / 2 * shape[1]))
           for y, x in zip(yn.ravel(), xn.ravel(), strict=True)]
    scene = np.zeros(shape, np.float32)
    for y, x in pts:
        scene[y, x] = 1.0
    cap = simulate(scene, cfg, field_zernike=grid, comparison=False, scale=1.0)
    for k, (y, x) in enumerate(pts):
        local = np.zeros(shape, np.float32)
        local[y, x] = 1.0
        ref = simulate(local, cfg, zernike=grid[0, k], comparison=False, scale=1.0).views_clean
        other = simulate(local, cfg, zernike=grid[0, 1 - k], comparison=False,
                         scale=1.0).views_clean
        win = (slice(None), slice(None), slice(max(y - 12, 0), y + 8), slice(x - 12, x + 8))
        got = cap.views_clean[win]
        err = np.linalg.norm(got - ref[win]) / np.linalg.norm(ref[win])
        err_other = np.linalg.norm(got - other[win]) / np.linalg.norm(ref[win])
        assert err < 0.02 and err_other > 0.3, (k, err, err_other)


def test_same_seed_same_capture_and_inputs_untouched(standin):
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
def test_bad_input_clear_error(bad, kw, msg, standin):
    with pytest.raises((ValueError, TypeError), match=msg):
        simulate(bad, CFG, comparison=False, **kw)


def test_depth_map_renders_each_layer_with_its_own_defocus():
    # layered rendering is linear: two points at two depths = the sum of two uniform-depth
    # captures (1e-4 relative); the defocused point shows parallax across views in the direction
    # of conventions.md (+depth / mla_focal · (u − c) rows; the centroid of the aperture-windowed
    # view PSF moves by less than the spot: only > 0.5 of it is required)
    cfg = SMALL
    z = cfg.mla_focal * 1.0
    shape = (64, 64)
    depth = np.zeros(shape)
    depth[:, 32:] = z
    scene = np.zeros(shape, np.float32)
    scene[32, 16] = scene[32, 48] = 1.0
    cap = simulate(scene, cfg, depth=depth, comparison=False, scale=1.0)
    assert np.allclose(cap.depth_planes, [0, z])
    a, b = scene.copy(), scene.copy()
    a[:, 32:] = 0
    b[:, :32] = 0
    ref = (simulate(a, cfg, comparison=False, scale=1.0).views_clean
           + simulate(b, cfg, depth=z, comparison=False, scale=1.0).views_clean)
    np.testing.assert_allclose(cap.views_clean, ref, atol=1e-4 * ref.max())
    c = cfg.nnum // 2
    win = cap.views_clean[:, :, 32 - 12:32 + 12, 48 - 12:48 + 12]
    rows = np.arange(24)
    cent = [(win[u, c].sum(1) * rows).sum() / win[u, c].sum() for u in (c - 1, c + 1)]
    step = (cent[1] - cent[0]) / 2  # in view samples = pixels (d = 1)
    assert 0.5 * z / cfg.mla_focal < step < 1.2 * z / cfg.mla_focal


def test_true_zernike_reported(standin):
    grid = np.zeros((2, 2, 5))
    grid[..., 4] = [[0.1, 0.2], [0.3, 0.4]]
    cap = simulate(np.ones((132, 132), np.float32), CFG, zernike=[0, 0, 0, 0.5], scan=3,
                   field_zernike=grid, comparison=False)
    assert cap.zernike.shape == (2, 2, 5)
    np.testing.assert_allclose(cap.zernike[..., 3], 0.5)
    np.testing.assert_allclose(cap.zernike[..., 4], grid[..., 4])
    np.testing.assert_allclose(cap.field_zernike, grid)
    uni = simulate(np.ones((132, 132), np.float32), CFG, zernike=[0, 0, 0, 0.5], scan=3,
                   comparison=False)
    np.testing.assert_allclose(uni.zernike, [0, 0, 0, 0.5])


@pytest.mark.parametrize("kw", [dict(nnum=13, scan=3), dict(nnum=15, scan=5)])
def test_image_scan_config_refused_up_front_naming_the_image_scan_simulator(kw):
    cfg = ms.SystemConfig(moving="image", **kw)  # the README's 13-px, 3 x 3 example among them
    with pytest.raises(ValueError, match=r"moving MLA.*simulate_image_scan") as err:
        simulate(np.ones((150, 150), np.float32), cfg, comparison=False)
    assert "\n" not in str(err.value)
