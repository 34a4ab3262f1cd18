"""The telescope's truth: Kolmogorov modal variances (Noll 1976) and the views' true motion."""

import math

import numpy as np
import pytest

import metasensor as ms
from metasensor.scenarios.truth import kolmogorov_mode_rms, kolmogorov_residual, view_motion


def test_noll_residuals_and_mode_rms():
    assert kolmogorov_residual(1) == 1.0299 and kolmogorov_residual(3) == 0.134
    deltas = [kolmogorov_residual(j) for j in range(1, 60)]
    assert all(a > b for a, b in zip(deltas, deltas[1:], strict=False))
    # the asymptote continues the table within 3 % at J = 22
    assert abs(kolmogorov_residual(22) / 0.0208 - 1) < 0.03
    # D/r0 = 5: piston removed 0.62 waves, of which tip and tilt 87 % of the variance, and
    # Noll 4-45 0.21 waves
    full = kolmogorov_mode_rms(5.0, 2, 10**6)
    assert abs(full - math.sqrt(1.0299 * 5 ** (5 / 3)) / (2 * math.pi)) < 1e-3
    assert 0.61 < full < 0.63
    assert 0.86 < kolmogorov_mode_rms(5.0, 2, 3) ** 2 / full**2 < 0.88
    assert 0.21 < kolmogorov_mode_rms(5.0, 4, 45) < 0.22
    # the r.m.s. scales as (D/r0)^(5/6)
    assert math.isclose(kolmogorov_mode_rms(10.0, 4, 45) / kolmogorov_mode_rms(5.0, 4, 45),
                        2 ** (5 / 6), rel_tol=1e-9)
    with pytest.raises(ValueError, match="first"):
        kolmogorov_mode_rms(5.0, 1, 45)
    with pytest.raises(ValueError, match="j must"):
        kolmogorov_residual(0)


def test_view_motion_of_tilt_and_defocus():
    cfg = ms.SystemConfig()
    s, c = 64, cfg.nnum // 2
    k = -1.0 + (np.arange(s) + 0.5) * 2.0 / s
    x, y = np.meshgrid(k, k, indexing="xy")
    px = cfg.mla_pitch / cfg.scan  # one view pixel on the image plane (m)
    # Noll 2 (2 rho_x) of c waves moves every PSF by 2 c lambda / NA along +x
    tilt = np.stack([0.0 * x, 0.3 * 2 * x, -0.2 * 2 * y])
    m = view_motion(tilt, cfg, reference=0)
    assert m.shape == (3, cfg.nnum, cfg.nnum, 2)
    assert np.isnan(m[:, 0, 0]).all() and np.isfinite(m[:, c, c]).all()
    live = np.isfinite(m[1, ..., 0])
    # cells whose edge reaches the screen's border (|rho| = 1) read the screen extrapolated
    live[[0, -1], :] = live[:, [0, -1]] = False
    assert np.allclose(m[1, ..., 1][live], 2 * 0.3 * cfg.wavelength / cfg.na / px, rtol=1e-3)
    assert np.allclose(m[1, ..., 0][live], 0, atol=1e-9)
    assert np.allclose(m[2, ..., 0][live], -2 * 0.2 * cfg.wavelength / cfg.na / px, rtol=1e-3)
    assert np.all(m[0][live] == 0)
    # defocus b (rho_x^2 + rho_y^2): view (u, v) moves by 2 b rho of its sub-aperture; the
    # pupil is inverted on the views (rho_x = -(v - c) / radius)
    focus = np.stack([0.0 * x, 0.5 * (x**2 + y**2)])
    m = view_motion(focus, cfg, reference=0)
    for u, v in ((c, c), (c + 3, c - 2), (c - 4, c + 1)):
        want = 2 * 0.5 * cfg.wavelength / cfg.na / px / cfg.pupil_radius_px
        assert m[1, u, v, 0] == pytest.approx(-want * (u - c), abs=1e-6)
        assert m[1, u, v, 1] == pytest.approx(-want * (v - c), abs=1e-6)
    with pytest.raises(ValueError, match="reference"):
        view_motion(focus, cfg, reference=2)
