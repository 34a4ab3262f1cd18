"""View shifts → Zernike (dao/wavefront.py): analytic Shack–Hartmann geometry."""

import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.dao.wavefront import (
    fit_shifts,
    gradient_matrix,
    predicted_shifts,
    shift_scale,
    zernike_rms,
)
from metasensor.optics.zernike import random_zernike

CFG = SystemConfig()


@pytest.fixture(scope="module")
def matrix():
    return gradient_matrix(CFG)


def test_shift_scale_prototype():
    # (λ/NA)/pitch = 525 nm / 0.05 / 4.6 µm = 2.2826 px per unit gradient
    assert shift_scale(CFG) == pytest.approx(525e-9 / 0.05 / 4.6e-6, rel=1e-12)


def test_tilt_shifts_every_view_by_two_c_lambda_over_na(matrix):
    # conventions.md: Noll-2 of c waves shifts every PSF by +2cλ/NA along +x (Z2 = 2 rho_x)
    g, frac = matrix
    inside = frac > 0
    k = shift_scale(CFG)
    np.testing.assert_allclose(g[inside][:, 1, 1], 2 * k, rtol=1e-12)  # x shift per wave of Z2
    np.testing.assert_allclose(g[inside][:, 0, 1], 0.0, atol=1e-12)
    np.testing.assert_allclose(g[inside][:, 0, 2], 2 * k, rtol=1e-12)  # Z3 → +y


def test_defocus_gives_parallax(matrix):
    # Z4 = √3 (2ρ² − 1): ∇ = 4√3 (rho_x, rho_y), linear, so its footprint mean is the value at
    # the footprint centre rho_uv for views entirely inside the pupil. With
    # rho_uv = −((v−c), (u−c))/R the shift is −4√3 k (u−c, v−c)/R (rows, columns): tolerance 1e-9 px
    g, frac = matrix
    k = shift_scale(CFG)
    c, r = CFG.center, CFG.pupil_radius_px
    u, v = np.meshgrid(np.arange(CFG.nnum) - c, np.arange(CFG.nnum) - c, indexing="ij")
    full = frac == 1.0
    assert full.sum() > 100
    np.testing.assert_allclose(g[..., 0, 3][full], (-4 * np.sqrt(3) * k * u / r)[full], atol=1e-9)
    np.testing.assert_allclose(g[..., 1, 3][full], (-4 * np.sqrt(3) * k * v / r)[full], atol=1e-9)


def test_footprint_mean_matches_finite_differences(matrix):
    # for a high-order mode the footprint mean differs from the point gradient; the mean of the
    # x-derivative over a square equals the difference of the (y-averaged) wavefront across it
    from metasensor.optics.zernike import zernike_basis

    g, frac = matrix
    k = shift_scale(CFG)
    step = 1 / CFG.pupil_radius_px
    rho_x, rho_y = CFG.pupil_coords()
    u, v = 7, 9  # fully inside the pupil
    ys = rho_y[u, v] + (np.arange(2001) / 2000 - 0.5) * step
    right = zernike_basis(np.full_like(ys, rho_x[u, v] + step / 2), ys)[36].mean()
    left = zernike_basis(np.full_like(ys, rho_x[u, v] - step / 2), ys)[36].mean()
    assert g[u, v, 1, 36] == pytest.approx(k * (right - left) / step, rel=2e-3)


def test_fit_recovers_random_aberration_with_offset(matrix):
    z = random_zernike(1.0, seed=3)
    s = predicted_shifts(z, CFG, matrix=matrix) + np.array([4.0, -1.5])
    fit = fit_shifts(s, CFG, matrix=matrix)
    assert zernike_rms(fit.zernike - z) < 1e-9
    np.testing.assert_allclose(fit.tilt, [4.0, -1.5], atol=1e-9)
    assert fit.zernike[:3].tolist() == [0, 0, 0]


def test_fit_noise_and_outliers(matrix, rng):
    # 0.3 px white noise on 113 views: coefficient error r.m.s. < 0.1 waves (measured 0.045);
    # five views off by 20 px are rejected
    z = random_zernike(1.0, seed=4)
    s = predicted_shifts(z, CFG, matrix=matrix) + rng.normal(0, 0.3, (15, 15, 2))
    bad = [(2, 7), (7, 12), (10, 10), (4, 4), (12, 6)]
    for uv in bad:
        s[uv] += 20.0
    fit = fit_shifts(s, CFG, matrix=matrix)
    assert zernike_rms(fit.zernike - z) < 0.1
    assert not any(fit.inliers[uv] for uv in bad)
    assert fit.inliers.sum() >= 100


def test_precision_weights_lower_the_error_of_unequal_views(matrix):
    # Gauss–Markov: views of unequal noise (σ 0.1 px for most, 2 px for a third of them, as
    # DAO's precisions span at 3 λ) fitted with weights 1/σ² give a smaller error than the plain
    # fit. Over 20 draws (1 λ, rejection off): mean error 0.024 vs 0.146 λ measured; asserted
    # weighted < 0.5 × plain, and weighted better in at least 18 of 20 draws (measured 20)
    z = random_zernike(1.0, seed=6)
    used = CFG.view_mask()
    sigma = np.where(np.random.default_rng(0).random((15, 15)) < 1 / 3, 2.0, 0.1)
    err = {True: [], False: []}
    for seed in range(20):
        noise = np.random.default_rng(seed).normal(0, 1, (15, 15, 2)) * sigma[..., None]
        s = predicted_shifts(z, CFG, matrix=matrix) + noise
        for weighted in (True, False):
            fit = fit_shifts(s, CFG, mask=used, weights=1 / sigma**2 if weighted else None,
                             reject=0, matrix=matrix)
            err[weighted].append(zernike_rms(fit.zernike - z))
    w, p = np.array(err[True]), np.array(err[False])
    assert w.mean() < 0.5 * p.mean()
    assert (w < p).sum() >= 18


def test_zernike_rms_excludes_piston_tip_tilt():
    z = np.zeros(45)
    z[:3] = 5.0
    z[3], z[10] = 0.3, 0.4
    assert zernike_rms(z) == pytest.approx(0.5)


def test_bad_input(matrix):
    with pytest.raises(ValueError, match="shifts"):
        fit_shifts(np.zeros((15, 15)), CFG)
    with pytest.raises(ValueError, match="mask"):
        fit_shifts(np.zeros((15, 15, 2)), CFG, mask=np.ones((3, 3), bool), matrix=matrix)
    with pytest.raises(ValueError, match="weights"):
        fit_shifts(np.zeros((15, 15, 2)), CFG, weights=-np.ones((15, 15)), matrix=matrix)
    with pytest.raises(ValueError, match="cannot fit"):
        fit_shifts(np.zeros((15, 15, 2)), CFG, mask=np.eye(15, dtype=bool) & False,
                   matrix=matrix)
    with pytest.raises(ValueError, match="modes"):
        fit_shifts(np.zeros((15, 15, 2)), CFG, modes=[0, 4], matrix=matrix)
