"""Pupil grids, amplitudes (circle, annulus, view-coordinate maps) and phases."""

import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.optics.pupil import (
    defocus_waves,
    disk_fraction,
    pupil_amplitude,
    pupil_grid,
    pupil_phase,
    view_to_pupil_map,
)
from metasensor.optics.zernike import zernike_basis


def test_grid_is_centred_and_symmetric():
    rx, ry = pupil_grid(101, 40.0)
    assert rx[50, 50] == 0 and ry[50, 50] == 0
    assert rx[0, 51] == pytest.approx(1 / 40) and ry[51, 0] == pytest.approx(1 / 40)
    np.testing.assert_array_equal(rx, -rx[:, ::-1])
    with pytest.raises(ValueError, match="odd"):
        pupil_grid(100, 40.0)


def test_circle_and_annulus_areas():
    """Area-weighted edges: sum of A equals the analytic area π R² (annulus π R²(1 − ε²))
    within 0.1 %; sum of A² is smaller by about 0.33/R."""
    radius = 30.0
    rx, ry = pupil_grid(81, radius)
    cfg = SystemConfig()
    a = pupil_amplitude(cfg, rx, ry, 1 / radius)
    assert np.sum(a) == pytest.approx(np.pi * radius**2, rel=1e-3)
    assert np.sum(a**2) == pytest.approx(np.pi * radius**2 * (1 - 0.33 / radius), rel=2e-3)
    ann = pupil_amplitude(cfg.replace(obstruction=0.4), rx, ry, 1 / radius)
    assert np.sum(ann) == pytest.approx(np.pi * radius**2 * (1 - 0.16), rel=1e-3)
    assert ann[40, 40] == 0 and a[40, 40] == 1
    frac = disk_fraction(rx, ry, 1 / radius)
    assert frac.min() >= 0 and frac.max() <= 1


def test_view_map_follows_conventions():
    """View (u, v) sees rho = −((v − c), (u − c)) / pupil_radius_px: the map inverts it."""
    cfg = SystemConfig()
    rho_x, rho_y = cfg.pupil_coords()
    u, v = view_to_pupil_map(cfg, rho_x, rho_y)
    uu, vv = np.meshgrid(np.arange(15), np.arange(15), indexing="ij")
    np.testing.assert_array_equal(u, uu)
    np.testing.assert_array_equal(v, vv)
    # a pupil point at +x (rho_x > 0) is seen by views with v < c
    assert view_to_pupil_map(cfg, np.array(0.9), np.array(0.0)) == (7, 0)


def test_amplitude_map_and_callable():
    cfg = SystemConfig()
    rx, ry = pupil_grid(61, 25.0)
    amap = np.ones((15, 15))
    amap[:, 8:] = 0.0  # views v > c see rho_x < 0
    a = pupil_amplitude(cfg, rx, ry, 1 / 25, amap)
    assert np.all(a[rx < -1.5 / 7.5] == 0) and np.all(a[(rx > 0) & (rx**2 + ry**2 < 0.9)] == 1)
    b = pupil_amplitude(cfg, rx, ry, 1 / 25, lambda x, y: 0.5 + 0 * x)
    np.testing.assert_allclose(b, 0.5 * pupil_amplitude(cfg, rx, ry, 1 / 25))
    with pytest.raises(ValueError, match="amplitude map"):
        pupil_amplitude(cfg, rx, ry, 1 / 25, np.ones((3, 3)))
    with pytest.raises(ValueError, match="non-negative"):
        pupil_amplitude(cfg, rx, ry, 1 / 25, -amap)


def test_defocus_and_phase():
    """W = (depth/λ)(sqrt(1 − NA²ρ²) − 1); the Zernike part is Σ z_j Z_j; callables add."""
    cfg = SystemConfig()
    rx, ry = pupil_grid(21, 10.0)
    w = defocus_waves(cfg, rx, ry, 1e-4)
    r2 = rx**2 + ry**2
    np.testing.assert_allclose(w, 1e-4 / 525e-9 * (np.sqrt(1 - 0.0025 * r2) - 1))
    z = np.zeros(6)
    z[5] = 0.3
    tot = pupil_phase(cfg, rx, ry, z, 1e-4, phase=lambda x, y: 0.1 * x)
    np.testing.assert_allclose(tot, w + 0.3 * zernike_basis(rx, ry, 6)[5] + 0.1 * rx)
    with pytest.raises(ValueError, match="depth"):
        defocus_waves(cfg, rx, ry, np.nan)
    with pytest.raises(ValueError, match="phase"):
        pupil_phase(cfg, rx, ry, phase=lambda x, y: np.full_like(x, np.nan))
