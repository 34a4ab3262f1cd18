"""Aplanatic pupil apodization: the analytic law, energy conservation, and the per-view
energies of the authors' prototype PSF bank (object-side f/1 at magnification 10)."""

import math

import numpy as np
import pytest

from metasensor import SystemConfig
from metasensor.config import ConfigError
from metasensor.optics.psf import view_psfs
from metasensor.optics.pupil import aplanatic_amplitude, disk_fraction, pupil_grid


def test_amplitude_follows_the_sine_condition_law_and_keeps_the_pupil_energy():
    na_o = 0.5
    rx, ry = pupil_grid(1201, 600.0)
    a = aplanatic_amplitude(rx, ry, na_o)
    # intensity ratio edge / centre is 1 / cos θ at sin θ = NA_o (exact)
    r = np.hypot(rx, ry)
    centre, edge = a[600, 600] ** 2, aplanatic_amplitude(1.0, 0.0, na_o) ** 2
    assert edge / centre == pytest.approx(1.0 / math.sqrt(1.0 - na_o**2), rel=1e-12)
    mid = aplanatic_amplitude(0.6, 0.0, na_o) ** 2 / centre
    assert mid == pytest.approx(1.0 / math.sqrt(1.0 - (0.6 * na_o) ** 2), rel=1e-12)
    # unit mean intensity over the disk (area-weighted edge cells; 1e-4 for the grid)
    w = disk_fraction(rx, ry, 1.0 / 600.0)
    assert float(np.sum(w * a**2) / np.sum(w)) == pytest.approx(1.0, abs=1e-4)
    assert np.all(a[r <= 1] >= a[600, 600])


def test_amplitude_and_config_refuse_impossible_apertures():
    with pytest.raises(ValueError, match="na_object"):
        aplanatic_amplitude(0.0, 0.0, 1.0)
    with pytest.raises(ConfigError, match="apodization"):
        SystemConfig(apodization="cosine")
    with pytest.raises(ConfigError, match="object-side NA"):
        SystemConfig(apodization="aplanatic", na=0.2, magnification=10.0)


def test_default_config_keeps_its_optical_digest_and_apodization_changes_it():
    plain = SystemConfig()
    assert SystemConfig(apodization="none").optical_digest() == plain.optical_digest()
    apod = SystemConfig(apodization="aplanatic")
    assert apod.optical_digest() != plain.optical_digest()
    assert apod.optical_digest() != apod.replace(magnification=5.0).optical_digest()
    assert SystemConfig.from_toml_string(apod.to_toml_string()) == apod


def test_prototype_bank_reproduces_the_authors_per_view_energies():
    """The authors' in-focus bank (psf_init.mat of the published code; object-side f/1 at
    magnification 10) has per-view energies, relative to the centre view, along the central
    row from offset 6 inwards of 1.070, 1.028, 1.015, 1.009, 1.004, 1.001 (figures read from
    that file). The prototype with the aplanatic law at NA_o = 0.05 x 10 matches them within
    3 %; the uniform pupil falls towards the edge instead."""
    theirs = np.array([1.070, 1.028, 1.015, 1.009, 1.004, 1.001, 1.000])
    cfg = SystemConfig(apodization="aplanatic")
    e = view_psfs(cfg).sum(axis=(2, 3))
    row = e[7, 13:6:-1] / e[7, 7]  # offsets 6, 5, ..., 0 on the central row
    np.testing.assert_allclose(row, theirs, rtol=0.03)
    col = e[13:6:-1, 7] / e[7, 7]
    np.testing.assert_allclose(col, row, rtol=1e-3)  # the law is radial
    plain = view_psfs(SystemConfig()).sum(axis=(2, 3))
    assert plain[7, 13] / plain[7, 7] < 1.0 < row[0]
    # total light unchanged by the apodization (photon normalisation), within 1 %
    assert e.sum() == pytest.approx(plain.sum(), rel=0.01)


# The authors' per-view energies (psf_init.mat), relative to the centre view, along the central
# row from the edge view (offset 7) inwards to the centre.
AUTHORS_ROW = np.array([1.304, 1.070, 1.028, 1.015, 1.009, 1.004, 1.001, 1.000])


def test_a_slightly_overfilled_pupil_with_the_aplanatic_law_reproduces_every_authors_energy():
    """Lenslets of 713 um focal length behind the f/10 main lens (object-side f/1 at
    magnification 10, the authors' description): the pupil's image is 31/30 of the pitch wide,
    so its rim spills onto the neighbours' edge pixels and lifts the edge view, while the
    aplanatic law shapes the inner views. All eight central-row figures within 3 %, on both
    sides; either ingredient alone misses them. The views at radius 5.5-6.5 lie within 3 % of the
    authors' band of about 1.07-1.12 (ours stay below 1.08: a radial law keeps the off-axis views
    of that ring below the on-axis one)."""
    cfg = SystemConfig(mla_focal=713e-6, apodization="aplanatic")
    assert cfg.pupil_fill == pytest.approx(31 / 30, rel=1e-12)
    assert SystemConfig().pupil_fill == pytest.approx(1.0, rel=1e-12)
    e = view_psfs(cfg).sum(axis=(2, 3))
    e = e / e[7, 7]
    np.testing.assert_allclose(e[7, 14:6:-1], AUTHORS_ROW, rtol=0.03)
    np.testing.assert_allclose(e[7, :8], AUTHORS_ROW, rtol=0.03)
    np.testing.assert_allclose(e[:8, 7], AUTHORS_ROW, rtol=0.03)
    r = np.hypot(*np.mgrid[-7:8, -7:8])
    ring = e[(r > 5.5) & (r <= 6.5)]
    assert ring.min() >= 0.97 * 1.070 and ring.max() <= 1.03 * 1.12
    # the overfill alone leaves the inner views flat (offset 6: about 1.00 against 1.070)
    flat = view_psfs(cfg.replace(apodization="none")).sum(axis=(2, 3))
    assert flat[7, 13] / flat[7, 7] < 0.97 * AUTHORS_ROW[1]
