"""Comparison sensors: 2D sensor, hardware AO (segmented tip-tilt mirror), plain light field."""

import numpy as np
import pytest

from conftest import SMALL
from metasensor.simulation.capture import plain_lightfield, simulate
from metasensor.simulation.comparison import SegmentedMirror


def _wavefront(x, y):
    # smooth aberration: astigmatism + coma + spherical-like terms (waves)
    r2 = x * x + y * y
    return 0.6 * (x * x - y * y) + 0.4 * (3 * r2 - 2) * x + 0.3 * (6 * r2 * r2 - 6 * r2 + 1)


def test_mirror_residual_falls_with_segment_count():
    # least-squares piston/tip/tilt per segment: the residual of a smooth wavefront falls
    # roughly as (segment size)² → 5×5 vs 15×15 ≈ 9× lower; required: 15×15 at least 4× lower
    before = SegmentedMirror(15).rms(_wavefront)
    res = {}
    for n in (5, 15):
        m = SegmentedMirror(n)
        res[n] = m.rms(m.residual(_wavefront))
    assert res[15] < res[5] / 4 < before / 4


def test_mirror_fits_piecewise_linear_wavefront_exactly():
    m = SegmentedMirror(3)
    assert m.rms(m.residual(lambda x, y: 0.7 * x - 0.2 * y + 0.1)) < 1e-12


def test_sensor2d_of_uniform_scene_is_uniform_at_the_same_scale():
    # widefield PSF sums to 1: a uniform scene s gives s·scale on the 2D sensor (1 %)
    scene = np.full((96, 96), 3.0, np.float32)
    cap = simulate(scene, SMALL, zernike=[0, 0, 0, 0.2, 0.3])
    assert cap.sensor2d.shape == cap.truth.shape == cap.hardware_ao.shape
    inner = cap.sensor2d_clean[30:-30, 30:-30]
    np.testing.assert_allclose(inner, 3.0 * cap.scale, rtol=0.01)
    np.testing.assert_allclose(cap.truth, 3.0 * cap.scale, rtol=1e-6)


def test_hardware_ao_sharper_than_2d_sensor_under_aberration():
    scene = np.zeros((64, 64), np.float32)
    scene[32, 32] = 1.0
    z = np.zeros(11)
    z[3], z[5], z[7] = 0.5, 0.6, 0.4
    cap = simulate(scene, SMALL, zernike=z)
    assert cap.hardware_ao_clean.max() > 1.3 * cap.sensor2d_clean.max()
    assert 0 < cap.ao_residual_rms < 0.2
    # noise model shared: same gain (photon budget) → noisy 2D sensor differs from clean
    cap2 = simulate(scene, SMALL, zernike=z, snr_db=20)
    assert not np.array_equal(cap2.sensor2d, cap2.sensor2d_clean)


def test_plain_lightfield_shares_scale_and_budget():
    scene = np.random.default_rng(0).random((64, 64)).astype(np.float32)
    cap = simulate(scene, SMALL, snr_db=20, comparison=False)
    lf = plain_lightfield(scene, cap)
    assert lf.config.scan == 1 and lf.views.shape[2:] == (12, 12)
    assert lf.scale == cap.scale and lf.noise.gain == pytest.approx(cap.noise.gain)
    # the 1x1 scan's samples are the 5x5 scan's phase-(2, 2) samples... of the same lenslets
    # only when the lenslet grids coincide: here phase (0, 0) of both scans is the same grid
    np.testing.assert_allclose(lf.views_clean, cap.views_clean[:, :, 0::5, 0::5][:, :, :12, :12],
                               rtol=1e-4, atol=1e-3)


def test_comparison_2d_renders_the_same_2d_sensor_without_hardware_ao():
    scene = np.random.default_rng(1).random((64, 64)).astype(np.float32)
    z = [0, 0, 0, 0.3, 0.2]
    full = simulate(scene, SMALL, zernike=z, snr_db=25, seed=4)
    only = simulate(scene, SMALL, zernike=z, snr_db=25, seed=4, comparison="2d")
    assert only.hardware_ao is None and only.hardware_ao_clean is None
    np.testing.assert_array_equal(only.sensor2d, full.sensor2d)
    np.testing.assert_array_equal(only.views, full.views)
    for bad in ("3d", 1, None):
        with pytest.raises(ValueError, match="comparison must be True, False or '2d'"):
            simulate(scene, SMALL, zernike=z, comparison=bad)
