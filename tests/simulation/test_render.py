"""The sampled convolution engine and the fine-grid → pixel-grid kernel collapse."""

import numpy as np
import pytest
import torch
from scipy import ndimage
from scipy.signal import convolve2d, fftconvolve

from metasensor.simulation.kernels import collapse, crop_energy, upsampler_response
from metasensor.simulation.render import Lattice, fft_size, sampled_conv


@pytest.mark.parametrize("oy,sy,ox,sx", [(7, 3, 7, 3), (2, 5, 4, 1), (0, 1, 0, 1), (13, 15, 4, 15)])
def test_sampled_conv_equals_direct_convolution(oy, sy, ox, sx):
    # reference: scipy's direct 'same' convolution (zero outside), sampled; exact to float32
    rng = np.random.default_rng(0)
    img = rng.random((97, 83)).astype(np.float32)
    ker = rng.random((3, 9, 9)).astype(np.float32)
    ny, nx = (97 - oy - 1) // sy + 1, (83 - ox - 1) // sx + 1
    out = sampled_conv(torch.tensor(img), torch.tensor(ker), Lattice(oy, sy, ny),
                       Lattice(ox, sx, nx), tile=40).numpy()
    for b in range(3):
        ref = convolve2d(img, ker[b], mode="same")[oy::sy, ox::sx][:ny, :nx]
        np.testing.assert_allclose(out[b], ref, atol=1e-4, rtol=0)


def test_sampled_conv_restricted_lattice_only_touches_its_samples():
    img = torch.ones((40, 40))
    ker = torch.ones((1, 3, 3))
    rows = Lattice(1, 2, 20).restrict(10, 20)
    out = sampled_conv(img, ker, rows, Lattice(0, 1, 40))
    touched = out[0].abs().sum(1) > 0
    assert touched[rows.start:rows.end].all() and touched.sum() == rows.end - rows.start


def test_fft_size_is_smooth_multiple():
    for n, m in [(100, 3), (511, 15), (7, 1)]:
        s = fft_size(n, m)
        assert s >= n and s % m == 0
        k = s
        for p in (2, 3, 5):
            while k % p == 0:
                k //= p
        assert k == 1


def test_upsampler_kinds():
    np.testing.assert_allclose(upsampler_response(3, "box"), [1 / 3] * 3)
    np.testing.assert_allclose(upsampler_response(3, "point"), [1.0])
    with pytest.raises(ValueError, match="upsample"):
        upsampler_response(3, "lanczos")


def test_upsampler_is_interpolating_and_flux_preserving():
    u = upsampler_response()
    c = len(u) // 2
    assert abs(u.sum() - 1) < 1e-12
    assert abs(u[c + 3]) < 1e-9 and abs(u[c - 3]) < 1e-9  # zero at the neighbouring pixel centres


@pytest.mark.parametrize("integrate", [False, True])
def test_collapse_equals_fine_grid_convolution(integrate):
    # analytic identity: sampling (H ⊛ u [⊛ box3]) at multiples of 3 fine cells; tolerance 1e-6
    rng = np.random.default_rng(1)
    fine = rng.random((2, 21, 21))
    out = collapse(fine, integrate=integrate)
    u = upsampler_response()
    if integrate:
        u = np.convolve(u, np.ones(3))
    big = ndimage.convolve(np.pad(fine[1], 40), np.outer(u, u), mode="constant")
    c, h = big.shape[0] // 2, out.shape[-1] // 2
    ref = big[c - 3 * h:c + 3 * h + 1:3, c - 3 * h:c + 3 * h + 1:3]
    np.testing.assert_allclose(out[1], ref, atol=1e-6)


def test_pixel_kernel_reproduces_brute_force_fine_grid_simulation():
    # the simulator's model written out literally: zoom x3 (cubic spline, /9 per fine cell),
    # convolve with the fine PSF, sample at the central fine cell of each output pixel
    rng = np.random.default_rng(2)
    scene = rng.random((40, 44))
    yy, xx = np.mgrid[-16:17, -16:17] / 3.0
    fine = np.exp(-((yy - 0.4) ** 2 + (xx + 1.1) ** 2) / 3.0) * (np.abs(xx) < 4)
    fine_scene = ndimage.zoom(scene, 3, order=3, grid_mode=True, mode="grid-constant") / 9
    brute = fftconvolve(fine_scene, fine, mode="same")[1::3, 1::3]
    kern = crop_energy(collapse(fine[None]), keep=1.0)
    fast = convolve2d(scene, kern[0], mode="same")
    inner = (slice(8, -8), slice(8, -8))  # away from the borders (zoom's edge handling)
    err = np.abs(fast[inner] - brute[inner]).max() / brute[inner].max()
    assert err < 1e-4
