"""Pupil amplitude from the views' angular intensity (dao/pupil.py)."""

import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.dao.pupil import (
    angular_intensity,
    estimate_block_pupils,
    estimate_pupil,
)

CFG = SystemConfig()


def _footprint_fraction(cfg, centre=(0.0, 0.0), outer=1.0, inner=0.0, sub=21):
    """Fraction of every view's pupil footprint (a square of side 1/R around rho_uv) inside the
    annulus inner <= |rho - centre| <= outer: the views' relative light (geometric optics)."""
    rx, ry = cfg.pupil_coords()
    step = 1 / cfg.pupil_radius_px
    off = ((np.arange(sub) + 0.5) / sub - 0.5) * step
    px = rx[..., None, None] + off[None, None, None, :] - centre[0]
    py = ry[..., None, None] + off[None, None, :, None] - centre[1]
    r2 = px**2 + py**2
    return ((r2 <= outer**2) & (r2 >= inner**2)).mean(axis=(-2, -1))


def _views(frac, rng, noise=0.01):
    scene = 1.0 + 0.3 * rng.random((24, 24))
    return frac[:, :, None, None] * scene[None, None] + rng.normal(0, noise, (15, 15, 24, 24))


@pytest.mark.parametrize("threshold", [0.5, 0.65, 0.8])
def test_clear_pupil(rng, threshold):
    # reference: the views whose footprint lies at least `threshold` inside the unit disk
    frac = _footprint_fraction(CFG)
    amp = estimate_pupil(_views(frac, rng), CFG, threshold)
    expected = frac >= threshold
    # only views within 0.05 of the threshold may differ (noise, scene texture)
    differ = amp.astype(bool) != expected
    assert np.all(np.abs(frac[differ] - threshold) < 0.05)
    assert amp[7, 7] == 1 and amp[0, 0] == 0
    assert amp.dtype == np.float32 and set(np.unique(amp)) <= {0.0, 1.0}


def test_annular_pupil_dark_centre(rng):
    # Cassegrain: obstruction 0.4 → the centre views (|rho| < 0.4) are dark
    frac = _footprint_fraction(CFG, inner=0.4)
    amp = estimate_pupil(_views(frac, rng), CFG, 0.6)
    assert amp[7, 7] == 0 and amp[7, 8] == 0
    assert amp[7, 1] == 1 and amp[1, 7] == 1
    np.testing.assert_array_equal(amp.astype(bool), frac >= 0.6)


def test_vignetted_pupil_follows_the_shift(rng):
    # non-telecentric field point: the pupil image moves by 0.3 of its radius along +rho_x,
    # i.e. towards smaller v (rho_x = -(v - c)/R); the lit region follows
    frac = _footprint_fraction(CFG, centre=(0.3, 0.0))
    amp = estimate_pupil(_views(frac, rng), CFG, 0.6)
    np.testing.assert_array_equal(amp.astype(bool), frac >= 0.6)
    assert amp[7, 1] == 1 and amp[7, 13] == 0


def test_blocks_and_normalisation(rng):
    frac = _footprint_fraction(CFG)
    v = _views(frac, rng)
    ai = angular_intensity(v, CFG)
    assert ai.max() == pytest.approx(1.0)
    blocks = estimate_block_pupils(v, CFG, (2, 3))
    assert blocks.shape == (2, 3, 15, 15)
    for b in blocks.reshape(-1, 15, 15):
        assert b[7, 7] == 1 and b[0, 0] == 0


def test_bad_input():
    with pytest.raises(ValueError, match="views"):
        estimate_pupil(np.zeros((3, 15, 4, 4)), CFG)
    with pytest.raises(ValueError, match="no light"):
        estimate_pupil(np.zeros((15, 15, 4, 4)), CFG)
    with pytest.raises(ValueError, match="threshold"):
        estimate_pupil(np.ones((15, 15, 4, 4)), CFG, threshold=1.5)
    with pytest.raises(ValueError, match="NaN"):
        estimate_pupil(np.full((15, 15, 4, 4), np.nan), CFG)
    with pytest.raises(ValueError, match="blocks"):
        estimate_block_pupils(np.ones((15, 15, 4, 4)), CFG, (0, 1))
