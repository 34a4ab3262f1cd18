"""Noise model: target SNR, Poisson statistics, quantisation."""

import numpy as np
import pytest

import metasensor as ms
from metasensor.simulation.capture import simulate
from metasensor.simulation.noise import NoiseModel, add_noise, apply_noise, measure_snr


@pytest.mark.parametrize("snr", [3.0, 10.0, 30.0])
def test_simulated_views_hit_the_requested_snr(snr, standin):
    # SNR = 10 log10(Σ clean² / Σ noise²) over the views; requirement: within 0.5 dB
    cfg = ms.SystemConfig(sensor_shape=(132, 132))
    scene = np.random.default_rng(0).random((132, 132)).astype(np.float32)
    cap = simulate(scene, cfg, scan=5, snr_db=snr, comparison=False)
    measured = measure_snr(cap.views_clean, cap.views)
    assert abs(measured - snr) < 0.5
    assert abs(cap.snr_db - measured) < 1e-9


def test_poisson_variance_equals_mean():
    # Poisson: var = mean (in electrons); gain 1 DN/e-, no read noise, 16-bit: quantisation adds
    # nothing (integers). Tolerance 2 % (the estimator's own spread is 0.15 % for 1e6 samples)
    for mean in (20.0, 500.0):
        clean = np.full(1_000_000, mean, np.float32)
        noisy = apply_noise(clean, NoiseModel(1.0, 0.0, 16), np.random.default_rng(3))
        assert abs(noisy.mean() / mean - 1) < 0.01
        assert abs(noisy.var() / mean - 1) < 0.02


def test_photon_budget_and_read_noise_variance():
    # var(DN) = g·mean + g²σ² + 1/12 (quantisation) for gain g; checked within 2 %
    g, sigma = 0.5, 3.0
    clean = np.full(1_000_000, 400.0, np.float32)
    noisy = apply_noise(clean, NoiseModel(g, sigma, 12), np.random.default_rng(1))
    expected = g * 400 + g * g * sigma**2 + 1 / 12
    assert abs(noisy.var() / expected - 1) < 0.02
    assert np.all(noisy == np.rint(noisy)) and noisy.max() <= 4095


def test_quantisation_and_clipping():
    clean = np.array([-5.0, 0.4, 0.6, 5000.0], np.float32)
    out = apply_noise(clean, NoiseModel(None, 0.0, 12), np.random.default_rng(0))
    np.testing.assert_array_equal(out, [0, 0, 1, 4095])


def test_add_noise_seeded_and_photons_mode():
    clean = np.random.default_rng(0).random(10000).astype(np.float32) * 1000
    a, ma = add_noise(clean, None, 2000.0, 2.0, 12, 7)
    b, _ = add_noise(clean, None, 2000.0, 2.0, 12, 7)
    assert np.array_equal(a, b) and abs(ma.photons - 2000) < 1e-9
    with pytest.raises(ValueError, match="photons"):
        add_noise(clean, None, -1.0, 2.0, 12, 0)
    with pytest.raises(ValueError, match="read_noise"):
        add_noise(clean, None, 10.0, -2.0, 12, 0)
