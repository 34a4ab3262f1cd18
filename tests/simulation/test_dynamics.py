"""Scene motion during the scan and turbulence phase screens."""

import math

import numpy as np
import pytest
from scipy import ndimage

import metasensor as ms
from metasensor.simulation.capture import simulate
from metasensor.simulation.motion import Motion
from metasensor.simulation.turbulence import Turbulence, screen_phase

CFG = ms.SystemConfig(sensor_shape=(132, 132))


def test_each_frame_sees_the_scene_at_its_own_time(standin):
    # frame t's samples must equal a static capture of the scene shifted by (t - t_ref) * v
    scene = np.random.default_rng(0).random((70, 70)).astype(np.float32)
    motion = Motion(shift=(0.5, -1.0))
    cap = simulate(scene, CFG, scan=3, motion=motion, comparison=False, scale=1.0)
    np.testing.assert_allclose(cap.truth, scene[5:65, 5:65], rtol=1e-6)
    p = 3
    for t, (r, c) in list(enumerate(cap.scan_order))[::4]:  # frames 0, 4, 8
        moved = motion.scene_at(scene, t - 4.0)
        ref = simulate(moved, CFG, scan=3, comparison=False, scale=1.0).views_clean
        np.testing.assert_allclose(cap.views_clean[:, :, r::p, c::p], ref[:, :, r::p, c::p],
                                   atol=1e-4 * ref.max())
    assert not np.allclose(cap.views_clean, simulate(scene, CFG, scan=3, comparison=False,
                                                     scale=1.0).views_clean, atol=1e-2)


def test_motion_kinds():
    rng = np.random.default_rng(1)
    scene = ndimage.gaussian_filter(rng.random((64, 64)), 2).astype(np.float32)
    # rigid integer shift: content moves by tau * v
    out = Motion(shift=(2, 0)).scene_at(scene, 1.0)
    np.testing.assert_allclose(out[10:50, 10:50], scene[8:48, 10:50], atol=1e-5)
    # rotation by 90 deg about the centre maps +x to +y
    rot = Motion(rotation=90.0).scene_at(scene, 1.0)
    np.testing.assert_allclose(rot[20:44, 20:44], np.rot90(scene, -1)[20:44, 20:44], atol=1e-4)
    # constant flow = rigid shift
    flow = np.zeros((2, 64, 64))
    flow[1] = 3.0
    np.testing.assert_allclose(Motion(flow=flow).scene_at(scene, 1.0),
                               Motion(shift=(0, 3)).scene_at(scene, 1.0), atol=1e-6)
    # moving object over a static background
    obj = np.ones((64, 64), np.float32)
    mask = np.zeros((64, 64), np.float32)
    mask[20:30, 20:30] = 1
    m = Motion(obj=obj, mask=mask, obj_shift=(0, 5))
    ref = m.reference_scene(scene)
    assert np.all(ref[20:30, 20:30] == 1) and np.allclose(ref[40:], scene[40:])
    later = m.scene_at(scene, 2.0)
    assert np.allclose(later[22:28, 32:38], 1, atol=1e-3) and np.allclose(later[40:], scene[40:])


def test_motion_bad_input(standin):
    with pytest.raises(ValueError, match="obj and mask"):
        Motion(obj=np.ones((4, 4)))
    with pytest.raises(ValueError, match="shift"):
        Motion(shift=(1, math.nan))
    with pytest.raises(ValueError, match="flow"):
        simulate(np.ones((132, 132)), CFG, motion=Motion(flow=np.zeros((2, 5, 5))))


def test_turbulence_screens_seeded_frozen_flow():
    turb = Turbulence(d_over_r0=4.0, wind=(0.0, 0.125), samples=32)
    a = turb.screens(5, seed=3)
    assert a.shape == (5, 32, 32) and a.dtype == np.float32
    assert np.array_equal(a, turb.screens(5, seed=3))
    assert not np.array_equal(a, turb.screens(5, seed=4))
    # frozen flow: 0.125 D/frame = 4 samples/frame; piston removed per frame
    np.testing.assert_allclose(a[1][:, :-4] - a[1][:, :-4].mean(),
                               a[0][:, 4:] - a[0][:, 4:].mean(), atol=1e-4)


def test_turbulence_structure_function_kolmogorov():
    # D(r) = 6.88 (r / r0)^(5/3) rad² (Kolmogorov); FFT screens miss low frequencies, so checked
    # at small separations (r = 2..4 samples of 64 per D) within 30 %
    turb = Turbulence(d_over_r0=5.0, wind=(0, 0), samples=64)
    screens = np.concatenate([turb.screens(1, seed=s) for s in range(12)]) * 2 * np.pi
    for lag in (2, 4):
        d = np.mean((screens[:, :, lag:] - screens[:, :, :-lag]) ** 2)
        r = lag / 64
        theory = 6.88 * (r * 5.0) ** (5 / 3)
        assert abs(d / theory - 1) < 0.3, (lag, d, theory)


def test_screen_phase_interpolates_samples():
    scr = np.random.default_rng(0).random((16, 16))
    f = screen_phase(scr)
    k = np.arange(16)
    rho = -1 + (k + 0.5) * 2 / 16
    x, y = np.meshgrid(rho, rho)
    np.testing.assert_allclose(f(x, y), scr, atol=1e-9)


@pytest.mark.slow
def test_turbulence_capture_runs_and_differs_per_frame(standin):
    cfg = ms.SystemConfig(sensor_shape=(132, 132))
    scene = np.zeros((132, 132), np.float32)
    scene[60:70, 60:70] = 1
    cap = simulate(scene, cfg, scan=3, turbulence=Turbulence(d_over_r0=3.0, samples=16),
                   comparison=False)
    assert cap.phase_screens.shape == (9, 16, 16)
    assert np.array_equal(ms.realign(cap.frames, cap.config), cap.views)
    still = simulate(scene, cfg, scan=3, comparison=False, scale=cap.scale).views_clean
    assert np.abs(cap.views_clean - still).max() > 0.05 * still.max()
