"""PSNR / SSIM / SNR against closed forms."""

import math

import numpy as np
import pytest

from metasensor.metrics import psnr, snr_db, ssim


def test_psnr_closed_form():
    truth = np.linspace(0, 2, 64 * 64).reshape(64, 64)
    image = truth + 0.1  # MSE = 0.01, data range = 2
    assert psnr(image, truth) == pytest.approx(10 * math.log10(4 / 0.01), rel=1e-9)
    assert psnr(image, truth, data_range=1.0) == pytest.approx(20.0, rel=1e-9)
    assert psnr(truth, truth) == math.inf


def test_ssim_bounds_and_order():
    rng = np.random.default_rng(0)
    truth = rng.random((64, 64))
    assert ssim(truth, truth) == pytest.approx(1.0)
    low = ssim(truth + rng.normal(0, 0.3, truth.shape), truth)
    high = ssim(truth + rng.normal(0, 0.05, truth.shape), truth)
    assert -1 <= low < high < 1


def test_snr_db_closed_form():
    clean = np.ones((10, 10))
    assert snr_db(clean, clean + 0.1) == pytest.approx(20.0)
    assert snr_db(clean, clean) == math.inf


def test_errors_and_inputs_not_modified():
    a = np.ones((16, 16))
    b = np.zeros((16, 16))
    b[:, 8:] = 1
    before = b.copy()
    psnr(a, b)
    np.testing.assert_array_equal(b, before)
    with pytest.raises(ValueError, match="shape"):
        psnr(a, np.ones((16, 15)))
    bad = b.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="truth contains NaN"):
        ssim(a, bad)
    with pytest.raises(ValueError, match="image contains NaN"):
        psnr(bad, b)
    with pytest.raises(ValueError, match="data_range"):
        psnr(b, a)  # constant truth: range 0
    with pytest.raises(ValueError, match="2-D"):
        ssim(np.ones(16), np.ones(16))
    with pytest.raises(ValueError, match="7x7"):
        ssim(np.ones((5, 5)), b[:5, :5])
    with pytest.raises(ValueError, match="NaN"):
        snr_db(np.ones(3), np.array([1, np.nan, 1]))
