"""PSNR / SSIM / SNR against closed forms."""

import math

import numpy as np
import pytest

from metasensor.metrics import psnr, snr_db, ssim


def test_psnr_closed_form():
    truth = np.linspace(0, 2, 64 * 64).reshape(64, 64)
    image = truth + 0.1  # MSE = 0.01, data range = 2
    assert psnr(truth=truth, image=image) == pytest.approx(10 * math.log10(4 / 0.01), rel=1e-9)
    assert psnr(truth=truth, image=image, data_range=1.0) == pytest.approx(20.0, rel=1e-9)
    assert psnr(truth=truth, image=truth) == math.inf


def test_ssim_bounds_and_order():
    rng = np.random.default_rng(0)
    truth = rng.random((64, 64))
    assert ssim(truth=truth, image=truth) == pytest.approx(1.0)
    low = ssim(truth=truth, image=truth + rng.normal(0, 0.3, truth.shape))
    high = ssim(truth=truth, image=truth + rng.normal(0, 0.05, truth.shape))
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
    psnr(truth=b, image=a)
    np.testing.assert_array_equal(b, before)
    with pytest.raises(ValueError, match="shape"):
        psnr(truth=np.ones((16, 15)), image=a)
    bad = b.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="truth contains NaN"):
        ssim(truth=bad, image=a)
    with pytest.raises(ValueError, match="image contains NaN"):
        psnr(truth=b, image=bad)
    with pytest.raises(ValueError, match="data_range"):
        psnr(truth=a, image=b)  # constant truth: range 0
    with pytest.raises(ValueError, match="2-D"):
        ssim(truth=np.ones(16), image=np.ones(16))
    with pytest.raises(ValueError, match="7x7"):
        ssim(truth=b[:5, :5], image=np.ones((5, 5)))
    with pytest.raises(ValueError, match="NaN"):
        snr_db(np.ones(3), np.array([1, np.nan, 1]))
