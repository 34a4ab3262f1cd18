"""Field maps from a chart of slanted squares with a known, field-dependent Gaussian blur.

Reference: each square is blurred by a Gaussian of sigma(r) = 0.6 + 1.2 r pixels (r = normalised
field radius of its tile) and pixel-integrated (8x finer grid), so the MTF50 of its edges is the
root of exp(-2 pi^2 sigma^2 f^2) sinc(f cos t) sinc(f sin t) = 0.5, t = 5 degrees.
Tolerance: 0.006 cycles/pixel.
"""

from functools import cache

import numpy as np
import pytest
from scipy.optimize import brentq

from metasensor.metrics import field_mtf, find_edge_rois
from metasensor.metrics import synthetic as S


def sigma_of_r(r):
    return 0.6 + 1.2 * r


@cache
def chart():
    img, info = S.render_square_chart(240, n=3, angle_deg=5.0, sigma=sigma_of_r)
    img.setflags(write=False)
    return img, info


def analytic_mtf50(sigma, angle=5.0):
    return brentq(lambda f: S.gaussian_mtf(sigma)(f) * S.pixel_mtf(f, angle) - 0.5, 1e-4, 1.0)


def test_finds_four_edges_per_square_and_mtf50_matches():
    img, info = chart()
    rois = find_edge_rois(img)
    assert len(rois) == 4 * len(info)
    assert {r["side"] for r in rois} == {"left", "right", "top", "bottom"}
    fm = field_mtf(img, rois)
    assert all(e is None for e in fm.errors)
    for r, m in zip(rois, fm.mtf50, strict=True):
        expected = analytic_mtf50(info[r["square"]]["sigma"])
        assert abs(m - expected) < 0.006
    s = fm.summary()
    assert s["centre_mtf50"] == pytest.approx(analytic_mtf50(sigma_of_r(0.0)), abs=0.006)
    assert s["edge_mtf50"] < s["centre_mtf50"]
    assert s["edge_over_centre"] == pytest.approx(s["edge_mtf50"] / s["centre_mtf50"])
    pos = fm.positions(3)
    assert len(pos) == 3 and fm.radius[pos[0]] < fm.radius[pos[-1]]


def test_bright_squares_on_dark_and_distractors():
    img, info = chart()
    inv = 1.0 - img
    inv[5:12, 100:140] = 0.8  # a bar, not a square: must be ignored
    rois = find_edge_rois(inv)
    assert len(rois) == 4 * len(info)
    fm = field_mtf(inv, rois)
    assert np.all(np.isfinite(fm.mtf50))


def test_reference_image_used_to_find_rois():
    img, info = chart()
    fm = field_mtf(img * 0.5 + 0.1, reference=img)
    assert len(fm.mtf50) == 4 * len(info)


def test_failed_roi_is_reported_not_fatal():
    img, _ = chart()
    fm = field_mtf(img, [(0, 40, 0, 40), find_edge_rois(img)[0]["roi"]])
    assert np.isnan(fm.mtf50[0]) and "straight edge" in fm.errors[0]  # a corner of a square
    assert np.isfinite(fm.mtf50[1])


def test_errors():
    with pytest.raises(ValueError, match="NaN"):
        find_edge_rois(np.full((50, 50), np.nan))
    with pytest.raises(ValueError, match="constant"):
        find_edge_rois(np.ones((50, 50)))
    with pytest.raises(ValueError, match="no slanted-edge squares"):
        field_mtf(np.random.default_rng(0).random((50, 50)))
    with pytest.raises(ValueError, match="empty"):
        field_mtf(np.ones((50, 50)), rois=[])
    with pytest.raises(ValueError, match="roi"):
        field_mtf(np.ones((50, 50)), rois=[(0, 60, 0, 10)])


def test_simulator_resolution_chart():
    # the simulator's ISO 12233-style chart (12 slanted squares around a Siemens star, bar
    # groups): most square sides are found, and the sharp (area-sampled) chart has the MTF50 of
    # the square pixel aperture alone, sinc(f) = 0.5 at f = 0.603 cycles/pixel (tolerance 0.03)
    from metasensor.simulation.scenes import resolution_chart

    img = resolution_chart(512)
    fm = field_mtf(img)
    assert len(fm.mtf50) >= 40 and np.all(np.isfinite(fm.mtf50))
    assert np.all(np.abs(fm.mtf50 - 0.603) < 0.03)
    s = fm.summary()  # no ROI within 1/3 of the centre (the star is there): nearest group used
    assert s["n_centre"] >= 1 and s["centre_radius"] < s["edge_radius"]


def test_mtf50_above_nyquist_is_counted_and_flagged():
    from metasensor.metrics.evaluation import _summary_text
    from metasensor.metrics.field import FieldMTF

    fm = FieldMTF(rois=np.zeros((3, 4), int), centres=np.zeros((3, 2)),
                  radius=np.array([0.1, 0.5, 0.9]), mtf50=np.array([0.3, 0.62, np.nan]),
                  results=[None] * 3, errors=[None] * 3, shape=(100, 100))
    s = fm.summary()
    assert s["n_above_nyquist"] == 1 and s["n_measured"] == 2
    text = _summary_text({"shape": (100, 100), "field": s})
    assert "above Nyquist" in text and "field radius" in text
