"""Slanted-edge MTF against analytic blurs.

Reference: an edge blurred by a rotationally symmetric PSF with MTF T(f) and integrated over
square pixels has, along the edge normal at tilt t, the MTF T(f) * sinc(f cos t) * sinc(f sin t)
(metasensor.metrics.synthetic renders it exactly by quadrature, not on the algorithm's 1/4-pixel
grid). T = exp(-2 pi^2 sigma^2 f^2) (Gaussian, sigma = 0.6 px) or the diffraction MTF of a
circular pupil (2/pi)(acos(nu) - nu sqrt(1 - nu^2)), nu = f / 0.8 cycles/pixel (Airy).
Tolerance: 0.02 absolute for every frequency from 0 to Nyquist (0.5 cycles/pixel).
"""

from functools import cache

import numpy as np
import pytest
from scipy.optimize import brentq

from metasensor.metrics import mtf50, slanted_edge_mtf, snr_db
from metasensor.metrics import synthetic as S

TOL = 0.02
BLURS = {"gauss": (S.gaussian_mtf(0.6), 1.7), "airy": (S.airy_mtf(0.8), 0.8)}


@cache
def edge(kind: str, angle: float, shape: tuple[int, int], horizontal: bool = False,
         flip: bool = False) -> np.ndarray:
    tr, fmax = BLURS[kind]
    lo, hi = (0.9, 0.1) if flip else (0.1, 0.9)
    img = S.render_edge(shape, angle, tr, fmax=fmax, low=lo, high=hi, horizontal=horizontal)
    img.setflags(write=False)
    return img


def max_error(kind, angle, freq, mtf):
    ref = S.edge_reference_mtf(freq, BLURS[kind][0], angle)
    keep = freq <= 0.5 + 1e-9
    return float(np.abs(mtf - ref)[keep].max())


def analytic_mtf50(kind, angle):
    tr = BLURS[kind][0]
    return brentq(lambda f: S.edge_reference_mtf(f, tr, angle) - 0.5, 1e-4, 0.8)


def test_renderer_matches_supersampled_gaussian_edge():
    # two independent renderings of a Gaussian edge: quadrature in frequency vs 16x16 midpoint
    # sampling of Phi(d / sigma) per pixel; they agree to 2e-4 of the step
    a = S.render_edge((24, 20), 7.0, S.gaussian_mtf(0.6), fmax=1.7)
    b = S.render_gaussian_edge_supersampled((24, 20), 7.0, 0.6, factor=16)
    assert np.abs(a - b).max() < 2e-4


@pytest.mark.parametrize("kind", ["gauss", "airy"])
@pytest.mark.parametrize("angle", [2.0, 5.0, 10.0, 20.0])
def test_noiseless_edge_matches_analytic(kind, angle):
    img = edge(kind, angle, (128, 128))
    freq, mtf = slanted_edge_mtf(img)
    assert freq[0] == 0 and mtf[0] == pytest.approx(1.0)
    assert freq[-1] == pytest.approx(1.0, abs=0.01)
    assert max_error(kind, angle, freq, mtf) < TOL
    res = slanted_edge_mtf(img)
    assert res.angle_deg == pytest.approx(angle, abs=0.05)
    assert abs(res.mtf50 - analytic_mtf50(kind, angle)) < 0.005  # cycles/pixel


@pytest.mark.parametrize("horizontal,flip", [(True, False), (True, True), (False, True)])
def test_orientation_and_polarity(horizontal, flip):
    img = edge("gauss", 5.0, (128, 128), horizontal, flip)
    res = slanted_edge_mtf(img)
    assert res.orientation == ("horizontal" if horizontal else "vertical")
    assert max_error("gauss", 5.0, res.freq, res.mtf) < TOL


def test_roi_selects_the_edge():
    img = np.pad(edge("gauss", 5.0, (128, 128)), ((10, 20), (30, 5)), mode="edge")
    res = slanted_edge_mtf(img, roi=(10, 138, 30, 158))
    assert res.roi == (10, 138, 30, 158)
    assert max_error("gauss", 5.0, res.freq, res.mtf) < TOL


def test_noisy_edge_5deg_matches_analytic():
    # SNR 30 dB (10 log10(sum clean^2 / sum noise^2)); a 1024-row ROI (noise averages over rows)
    img = edge("gauss", 5.0, (1024, 160))
    noisy = S.add_noise(img, 30.0, seed=1)
    assert snr_db(img, noisy) == pytest.approx(30.0, abs=0.1)
    freq, mtf = slanted_edge_mtf(noisy)
    assert max_error("gauss", 5.0, freq, mtf) < TOL


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["gauss", "airy"])
@pytest.mark.parametrize("angle", [2.0, 5.0, 10.0, 20.0])
@pytest.mark.parametrize("seed", [0, 1])
def test_noisy_edges_match_analytic(kind, angle, seed):
    # 1024-row ROIs, wide enough for the edge to stay inside at each tilt
    shape = {2.0: (1024, 96), 5.0: (1024, 160), 10.0: (1024, 256), 20.0: (1024, 448)}[angle]
    noisy = S.add_noise(edge(kind, angle, shape), 30.0, seed=seed)
    res = slanted_edge_mtf(noisy)
    assert max_error(kind, angle, res.freq, res.mtf) < TOL
    assert abs(res.mtf50 - analytic_mtf50(kind, angle)) < 0.01


def test_figures_of_merit_and_units():
    img = edge("gauss", 5.0, (128, 128))
    res = slanted_edge_mtf(img, pixel_pitch=4.6e-6)
    np.testing.assert_allclose(res.freq_lpmm, res.freq / 4.6e-3)
    assert res.mtf50_lpmm == pytest.approx(res.mtf50 / 4.6e-3)
    assert res.at(0.0) == pytest.approx(1.0)
    # mtf50 / mtf_at on a known curve: m = 1 - f on [0, 1] -> MTF50 = 0.5
    f = np.linspace(0, 1, 11)
    assert mtf50(f, 1 - f) == pytest.approx(0.5)
    assert np.isnan(mtf50(f, np.ones_like(f)))
    from metasensor.metrics import mtf_at

    assert mtf_at(f, 1 - f, 0.25) == pytest.approx(0.75)
    with pytest.raises(ValueError, match="measured range"):
        mtf_at(f, 1 - f, 2.0)
    # a slanted edge without blur but with pixel integration still follows the pixel sinc
    sharp = S.render_edge((64, 64), 5.0, S.gaussian_mtf(0.1), fmax=8.0)
    r2 = slanted_edge_mtf(sharp)
    ref = S.pixel_mtf(r2.freq, 5.0) * np.exp(-2 * np.pi**2 * 0.1**2 * r2.freq**2)
    keep = r2.freq <= 0.5
    assert np.abs(r2.mtf - ref)[keep].max() < TOL
