"""Sub-pixel shift measurement and Fourier translation (align/shifts.py)."""

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter
from scipy.ndimage import shift as nd_shift
from skimage import data
from skimage.registration import phase_cross_correlation

from metasensor.align.shifts import fourier_shift, measure_shifts


def _scene(sigma=2.0):
    return gaussian_filter(data.camera().astype(float) / 255.0, sigma)[60:220, 90:250]


def _shifted_crops(img, shifts, margin=16):
    # reference: spline (order 5) translation of the full image, then both cropped: the moving
    # crops contain content the reference crop does not (a realistic, non-periodic case)
    mov = np.stack([nd_shift(img, s, order=5, mode="reflect") for s in shifts])
    return img[margin:-margin, margin:-margin], mov[:, margin:-margin, margin:-margin]


def test_recovers_known_subpixel_shifts(rng):
    # analytic reference: the applied shifts; tolerance 0.01 sample (measured ~1e-4)
    shifts = rng.uniform(-6, 6, (12, 2))
    ref, mov = _shifted_crops(_scene(), shifts)
    est = measure_shifts(ref, mov)
    assert np.abs(est - shifts).max() < 0.01


def test_noise_robust(rng):
    # white noise of half the image's standard deviation: error < 0.15 sample (measured 0.10)
    shifts = rng.uniform(-4, 4, (8, 2))
    ref, mov = _shifted_crops(_scene(), shifts)
    mov = mov + rng.normal(0, 0.5 * mov.std(), mov.shape)
    est = measure_shifts(ref, mov)
    assert np.abs(est - shifts).max() < 0.15


def test_gain_and_offset_do_not_bias(rng):
    shifts = np.array([[1.3, -2.7], [-0.4, 0.6]])
    ref, mov = _shifted_crops(_scene(), shifts)
    est = measure_shifts(ref, 3.0 * mov + 0.2)
    assert np.abs(est - shifts).max() < 0.01


def test_agrees_with_skimage_on_periodic_shift():
    # circular shifts (np.roll of an integer + Fourier sub-pixel part) are where skimage's
    # phase_cross_correlation is exact; both must agree within 0.02 sample
    img = _scene(3.0)[:128, :128]
    s = np.array([3.25, -5.5])
    mov = fourier_shift(torch.tensor(img)[None], torch.tensor(s)[None])[0].numpy()
    ours = measure_shifts(img, mov, window=0.0, refine=0, upsample=20)
    theirs = phase_cross_correlation(mov, img, upsample_factor=20, normalization=None)[0]
    np.testing.assert_allclose(ours, s, atol=0.02)
    np.testing.assert_allclose(ours, theirs, atol=0.02)


def test_fourier_shift_sign_and_inverse(rng):
    x = torch.tensor(rng.normal(size=(2, 33, 41)))  # odd: no Nyquist bin
    out = fourier_shift(x, torch.tensor([[2.0, -3.0], [0.0, 5.0]]))
    assert torch.allclose(out[0], torch.roll(x[0], (2, -3), (0, 1)), atol=1e-10)
    assert torch.allclose(out[1], torch.roll(x[1], (0, 5), (0, 1)), atol=1e-10)
    s = torch.tensor([[0.3, -1.7], [2.2, 0.1]])
    back = fourier_shift(fourier_shift(x, s), -s)
    assert torch.allclose(back, x, atol=1e-8)


def test_max_shift_clips():
    img = _scene()
    ref, mov = _shifted_crops(img, np.array([[0.0, 9.0]]))
    est = measure_shifts(ref, mov, max_shift=4.0)
    assert abs(est[0, 1]) <= 4.0 + 1e-12


def test_bad_input():
    with pytest.raises(ValueError, match="differ in size"):
        measure_shifts(np.zeros((8, 8)), np.zeros((8, 9)))
    with pytest.raises(ValueError, match="NaN"):
        measure_shifts(np.full((8, 8), np.nan), np.zeros((8, 8)))
    with pytest.raises(ValueError, match="batch"):
        measure_shifts(np.zeros((2, 8, 8)), np.zeros((3, 8, 8)))
    with pytest.raises(ValueError, match="too small"):
        measure_shifts(np.zeros((3, 3)), np.zeros((3, 3)))


def test_weight_excludes_a_region_the_reference_does_not_know(rng):
    # the moving image holds content the reference lacks in its left third (a block's border,
    # where a view records light from outside the block): unweighted, the estimate is pulled
    # (measured 0.1-1 sample); with weight 0 there it is the applied shift within 0.02 sample
    import torch

    from metasensor.align.shifts import measure_shifts_torch

    shifts = np.array([[1.4, -0.8], [-2.2, 1.7]])
    ref, mov = _shifted_crops(_scene(), shifts)
    mov = mov.copy()
    w = mov.shape[-1] // 3
    mov[:, :, :w] = rng.random((2, mov.shape[1], w)) * mov.max()  # unrelated content
    weight = np.ones(mov.shape[-2:], np.float32)
    weight[:, :w + 4] = 0.0
    r, m = torch.tensor(ref)[None], torch.tensor(mov)
    plain = measure_shifts_torch(r, m).numpy()
    est = measure_shifts_torch(r, m, weight=torch.tensor(weight)[None]).numpy()
    assert np.abs(est - shifts).max() < 0.02
    assert np.abs(plain - shifts).max() > 5 * np.abs(est - shifts).max()


def test_shift_precision_predicts_the_scatter_of_measured_shifts(rng):
    # Cramér–Rao: under white noise σ the scatter of each shift component is 1/precision. Measured
    # over 64 noise draws of a sharp and a blurred scene (two noise levels): the r.m.s. error per
    # component is within 25 % of 1/sqrt(precision) (measured ratios 0.89-0.96); the blurred scene
    # and the higher noise have the lower precision
    from metasensor.align.shifts import measure_shifts_torch, shift_precision

    out = {}
    for blur, noise in ((1.5, 0.02), (4.0, 0.02), (1.5, 0.06)):
        img = _scene(blur)
        ref, mov = _shifted_crops(img, np.tile([[1.3, -0.6]], (64, 1)))
        mov = mov + rng.normal(0, noise, mov.shape)
        r, m = torch.tensor(ref, dtype=torch.float64)[None], torch.tensor(mov)
        s = measure_shifts_torch(r, m)
        prec = shift_precision(r, m, s).numpy()
        err = s.numpy() - [1.3, -0.6]
        ratio = np.sqrt(np.mean(err**2)) * np.sqrt(np.median(prec))
        assert 0.75 < ratio < 1.25, (blur, noise, ratio)
        out[blur, noise] = np.median(prec)
    assert out[4.0, 0.02] < 0.5 * out[1.5, 0.02]
    assert out[1.5, 0.06] < 0.2 * out[1.5, 0.02]
