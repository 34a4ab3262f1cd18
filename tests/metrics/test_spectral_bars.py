"""Spectral fidelity / resolved frequency and bar-group resolution against analytic cases."""

import itertools
import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d, uniform_filter1d
from scipy.special import ndtr

from metasensor.metrics.bars import bar_contrast, bar_resolution
from metasensor.metrics.spectral import regional_fidelity, resolved_frequency, spectral_fidelity
from metasensor.simulation.bars import LOCATIONS, bar_chart, bar_groups


def _gauss_blur(img, sigma):
    f = np.hypot(np.fft.fftfreq(img.shape[0])[:, None], np.fft.fftfreq(img.shape[1])[None])
    return np.real(np.fft.ifft2(np.fft.fft2(img) * np.exp(-2 * (math.pi * sigma * f) ** 2)))


def test_gaussian_blur_ratio_and_resolved_frequency_are_analytic():
    truth = np.random.default_rng(0).random((256, 256))
    sigma = 1.5
    fid = spectral_fidelity(_gauss_blur(truth, sigma), truth, window=False)
    expected = (1 - np.exp(-2 * (math.pi * sigma * fid.frequency) ** 2)) ** 2
    np.testing.assert_allclose(fid.ratio, expected, atol=5e-3)
    f50 = math.sqrt(-math.log(1 - math.sqrt(0.5)) / (2 * (math.pi * sigma) ** 2))
    assert fid.resolved == pytest.approx(f50, rel=2e-3)
    # windowed (the default) on the same periodic pair, and per region: the same limit
    assert resolved_frequency(_gauss_blur(truth, sigma), truth) == pytest.approx(f50, rel=0.01)
    regions = regional_fidelity(_gauss_blur(truth, sigma), truth)
    assert len(regions) == 10
    assert all(r.resolved == pytest.approx(f50, rel=0.03) for r in regions.values())


def test_resolved_frequency_limits_and_flat_estimate():
    truth = np.random.default_rng(1).random((64, 64))
    assert spectral_fidelity(truth, truth).resolved == 0.5  # exact: every bin resolved
    flat = np.full_like(truth, truth.mean())
    fid = spectral_fidelity(flat, truth)
    np.testing.assert_allclose(fid.ratio, 1.0, atol=1e-9)  # flat reads exactly 1 everywhere
    assert fid.resolved == 0.0
    with pytest.raises(ValueError, match="differs from truth"):
        spectral_fidelity(truth[:32], truth)
    with pytest.raises(ValueError, match="threshold"):
        spectral_fidelity(truth, truth, threshold=0)


def test_regions_see_a_local_blur():
    truth = np.random.default_rng(2).random((192, 192))
    est = truth.copy()
    est[128:, 128:] = gaussian_filter1d(gaussian_filter1d(truth, 2.0, 0), 2.0, 1)[128:, 128:]
    regions = regional_fidelity(est, truth)
    assert regions["bottom-right"].resolved < 0.15
    assert regions["top-left"].resolved == 0.5 and regions["centre"].resolved == 0.5


def test_sharp_chart_resolves_every_group_everywhere():
    groups = bar_groups(256)
    assert {g.location for g in groups} == set(LOCATIONS)
    res = bar_resolution(bar_chart(256), groups)
    assert all(loc["period_px"] == 2.0 for loc in res.values())
    flat = bar_resolution(np.full((256, 256), 0.5), groups)
    assert all(loc["period_px"] is None and loc["frequency"] == 0.0 for loc in flat.values())


def _analytic_contrast(g, sigma):
    """Michelson contrast of a 3-bar group blurred across its bars by a Gaussian (and by the
    pixel's box, as a Gaussian of variance 1/12), read at the bar and gap centres."""
    s = math.sqrt(sigma**2 + 1 / 12)
    p = g.period

    def ink(x):
        return sum(ndtr((x - k * p) / s) - ndtr((x - k * p - p / 2) / s) for k in range(3))

    bars = [0.95 - 0.9 * ink(x) for x in (0.25 * p, 1.25 * p, 2.25 * p)]
    gaps = [0.95 - 0.9 * ink(x) for x in (0.75 * p, 1.75 * p)]
    return (min(gaps) - max(bars)) / (min(gaps) + max(bars))


def test_bar_groups_just_above_and_below_the_limit():
    size, sigma = 512, 2.0
    chart = gaussian_filter1d(bar_chart(size).astype(np.float64), sigma, axis=1)  # across x
    groups = [g for g in bar_groups(size) if g.vertical and g.location == "centre"]
    above = below = 0
    for g in groups:
        want = _analytic_contrast(g, sigma)
        got = bar_contrast(chart, g)
        assert got.contrast == pytest.approx(want, abs=0.03)
        if want >= 0.13:
            above += 1
            assert got.resolved, (g.period, want, got)
        elif want <= 0.07:
            below += 1
            assert not got.resolved, (g.period, want, got)
    # the limit (contrast 0.1) lies between 5 and 6 px for sigma = 2: both sides present
    assert above >= 3 and below >= 3
    assert _analytic_contrast(groups[5], sigma) < 0.1 < _analytic_contrast(groups[6], sigma)


def test_phase_reversed_group_is_not_resolved():
    chart = bar_chart(512).astype(np.float64)
    g = next(g for g in bar_groups(512) if g.vertical and g.period == 8.0)
    reversed_ = uniform_filter1d(chart, 11, axis=1)  # box MTF at 1/8 cycle/px: sinc(1.375) < 0
    r = bar_contrast(reversed_, g)
    assert r.contrast < -0.05 and not r.resolved
    assert bar_contrast(chart, g).resolved


def _centre(g, size):
    return (g.y0 + g.extent / 2 - size / 2, g.x0 + g.extent / 2 - size / 2)


def test_field_layout_is_symmetric_about_the_axis_with_coarse_groups_inward():
    size = 384
    groups = bar_groups(size, layout="field")
    assert len(groups) >= len(bar_groups(size))  # at least the rows layout's groups
    for a, b in itertools.combinations(groups, 2):  # no two groups overlap
        assert (a.y0 + a.extent <= b.y0 or b.y0 + b.extent <= a.y0
                or a.x0 + a.extent <= b.x0 or b.x0 + b.extent <= a.x0)
    by_loc = {}
    for g in groups:
        by_loc.setdefault(g.location, {})[(g.period, g.vertical)] = _centre(g, size)
    top, left = by_loc["top"], by_loc["left"]
    for (p, v), (y, x) in top.items():  # left = top transposed (bars turned), others mirrored
        assert left[(p, not v)] == pytest.approx((x, y))
        assert by_loc["bottom"][(p, v)] == pytest.approx((-y, x))
        assert by_loc["right"][(p, not v)] == pytest.approx((x, -y))
    for (p, v), (y, x) in by_loc["top-left"].items():
        assert by_loc["bottom-right"][(p, v)] == pytest.approx((-y, -x))
    for loc in ("top", "top-left"):
        r = {k: math.hypot(*c) for k, c in by_loc[loc].items()}
        coarse, fine = max(r)[0], min(r)[0]
        assert max(r[(coarse, v)] for v in (True, False)) < min(r[(fine, v)] for v in (True, False))
    res = bar_resolution(bar_chart(size, layout="field"), groups)
    assert all(loc["period_px"] == 2.0 for loc in res.values())
    with pytest.raises(ValueError, match="layout"):
        bar_groups(size, layout="diagonal")
