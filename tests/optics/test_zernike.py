"""Zernike polynomials: Noll index/normalisation conventions, orthonormality, gradients, fits."""

import numpy as np
import pytest

from metasensor.optics.zernike import (
    fit_zernike,
    noll_to_nm,
    random_zernike,
    wavefront,
    zernike_basis,
    zernike_gradients,
)


def _disk(n=300):
    t = (np.arange(n) + 0.5) / n * 2 - 1  # cell centres of an n x n grid on [-1, 1]^2
    x, y = np.meshgrid(t, t, indexing="xy")
    m = x**2 + y**2 <= 1
    return x[m], y[m]


def test_noll_table_matches_noll_1976_and_aotools():
    """Noll (1976) Table 1: j -> (n, m), even j cos, odd j sin (sign of m)."""
    expected = [(0, 0), (1, 1), (1, -1), (2, 0), (2, -2), (2, 2), (3, -1), (3, 1), (3, -3),
                (3, 3), (4, 0), (4, 2), (4, -2), (4, 4), (4, -4)]
    assert [noll_to_nm(j) for j in range(1, 16)] == expected
    from aotools.functions.zernike import zernIndex

    assert all(tuple(zernIndex(j)) == noll_to_nm(j) for j in range(1, 100))


@pytest.mark.parametrize("bad", [0, -1, 1.5, True])
def test_noll_bad_index(bad):
    with pytest.raises(ValueError, match="Noll index"):
        noll_to_nm(bad)


def test_closed_forms_and_orientation():
    """Z2 = 2x (x = columns), Z3 = 2y (y = rows), Z4 = sqrt3(2r²-1), Z5 = sqrt6 r² sin2θ,
    Z6 = sqrt6 r² cos2θ, Z7 = sqrt8 (3r³-2r) sinθ, Z11 = sqrt5 (6r⁴-6r²+1); exact to 1e-12."""
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-1, 1, (2, 500))
    r2 = x**2 + y**2
    th = np.arctan2(y, x)
    r = np.sqrt(r2)
    z = zernike_basis(x, y, 11)
    np.testing.assert_allclose(z[0], 1.0, atol=1e-12)
    np.testing.assert_allclose(z[1], 2 * x, atol=1e-12)
    np.testing.assert_allclose(z[2], 2 * y, atol=1e-12)
    np.testing.assert_allclose(z[3], np.sqrt(3) * (2 * r2 - 1), atol=1e-12)
    np.testing.assert_allclose(z[4], np.sqrt(6) * r2 * np.sin(2 * th), atol=1e-12)
    np.testing.assert_allclose(z[5], np.sqrt(6) * r2 * np.cos(2 * th), atol=1e-12)
    np.testing.assert_allclose(z[6], np.sqrt(8) * (3 * r**3 - 2 * r) * np.sin(th), atol=1e-12)
    np.testing.assert_allclose(z[10], np.sqrt(5) * (6 * r2**2 - 6 * r2 + 1), atol=1e-12)
    # on an image grid, Z2 grows with the column index and Z3 with the row index
    t = np.linspace(-1, 1, 5)
    gx, gy = np.meshgrid(t, t, indexing="xy")
    img = zernike_basis(gx, gy, 3)
    assert np.all(np.diff(img[1], axis=1) > 0) and np.allclose(np.diff(img[1], axis=0), 0)
    assert np.all(np.diff(img[2], axis=0) > 0) and np.allclose(np.diff(img[2], axis=1), 0)


def test_gram_matrix_is_identity_on_sampled_disk():
    """Orthonormality (r.m.s. normalisation): mean over the disk of Z_i Z_j = δ_ij within 1e-3
    for j <= 45 (600 x 600 cell-centre sampling of the unit disk, edge cells weighted by their
    area inside the disk)."""
    from metasensor.optics.pupil import disk_fraction

    n = 600
    t = (np.arange(n) + 0.5) / n * 2 - 1
    x, y = np.meshgrid(t, t, indexing="xy")
    f = disk_fraction(x, y, 2 / n, supersample=16)
    m = f > 0
    b = zernike_basis(x[m], y[m], 45)
    gram = (b * f[m]) @ b.T / f[m].sum()
    assert np.abs(gram - np.eye(45)).max() < 1e-3


def test_gradients_match_finite_differences():
    """Analytic gradients vs central differences (h = 1e-6), including rho = 0; to 1e-6."""
    rng = np.random.default_rng(1)
    x, y = rng.uniform(-1, 1, (2, 200))
    x[0] = y[0] = 0.0
    h = 1e-6
    g = zernike_gradients(x, y, 45)
    gx = (zernike_basis(x + h, y, 45) - zernike_basis(x - h, y, 45)) / (2 * h)
    gy = (zernike_basis(x, y + h, 45) - zernike_basis(x, y - h, 45)) / (2 * h)
    np.testing.assert_allclose(g[:, 0], gx, atol=1e-6 * np.abs(gx).max())
    np.testing.assert_allclose(g[:, 1], gy, atol=1e-6 * np.abs(gy).max())
    assert g.shape == (45, 2, 200)


def test_wavefront_is_the_coefficient_sum():
    x, y = _disk(64)
    z = random_zernike(0.7, seed=3)
    np.testing.assert_allclose(wavefront(z, x, y), z @ zernike_basis(x, y, 45), atol=1e-12)
    np.testing.assert_allclose(wavefront(np.zeros(5), x, y), 0.0)


def test_fit_recovers_random_coefficients():
    """Least squares on a 128² grid inside the disk recovers random vectors to 1e-3 waves rms."""
    n = 128
    t = (np.arange(n) - (n - 1) / 2) / (n / 2)
    x, y = np.meshgrid(t, t, indexing="xy")
    for seed in range(3):
        z = random_zernike(1.0, modes=range(1, 46), seed=seed)
        w = wavefront(z, x, y)
        fit = fit_zernike(w, x, y, jmax=45)
        assert np.sqrt(np.mean((fit - z) ** 2)) < 1e-3
    # restricted modes: entries outside are exactly 0, masked NaNs are ignored
    w = wavefront(z, x, y)
    w[0, 0] = np.nan
    fit = fit_zernike(w, x, y, modes=range(4, 46))
    assert np.all(fit[:3] == 0)


def test_fit_bad_input():
    x, y = np.meshgrid(np.linspace(-1, 1, 8), np.linspace(-1, 1, 8))
    with pytest.raises(ValueError, match="w must have the shape"):
        fit_zernike(np.zeros(3), x, y)
    with pytest.raises(ValueError, match="modes"):
        fit_zernike(np.zeros_like(x), x, y, modes=[0, 3])
    with pytest.raises(ValueError, match="cannot fit"):
        fit_zernike(np.zeros_like(x), x, y, mask=np.zeros_like(x, bool))


def test_random_zernike_rms_and_seed():
    """sqrt(sum z[modes]²) == rms exactly; seeded; other modes 0; r.m.s. over the disk = rms."""
    z = random_zernike(0.5, modes=range(4, 46), jmax=45, seed=7)
    assert z.shape == (45,)
    assert np.isclose(np.sqrt(np.sum(z[3:] ** 2)), 0.5)
    assert np.all(z[:3] == 0)
    np.testing.assert_array_equal(z, random_zernike(0.5, seed=7))
    assert not np.allclose(z, random_zernike(0.5, seed=8))
    x, y = _disk(400)
    assert abs(np.std(wavefront(z, x, y)) - 0.5) < 5e-3
    with pytest.raises(ValueError, match="rms"):
        random_zernike(-1.0)
    with pytest.raises(ValueError, match="modes"):
        random_zernike(1.0, modes=range(4, 60), jmax=45)
