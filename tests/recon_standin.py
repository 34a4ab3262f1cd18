"""A compact wave-optics phase-space PSF bank for the recon tests (a stand-in, not the library's).

The library's PSFs are ``metasensor.optics.psf.view_psfs``; these tests keep this small, independent
model so the recon machinery (operator, blocks, dask) is exercised on a realistic-looking bank even
where the optics stage is not under test. Model (system.md §3): Airy field of the main lens (pupil
FFT, optional Zernike-like phase as a callable) at the MLA plane, times a lenslet's circular
aperture, Fourier-transformed to the lenslet's focal plane, |.|², binned to pixels.
"""

from __future__ import annotations

import numpy as np
import pytest


def standin_psfs(nnum: int = 15, radius: int = 10, os: int = 3, na: float = 0.05,
                 wavelength: float = 525e-9, pitch: float = 4.6e-6, mla_focal: float = 690e-6,
                 phase=None) -> np.ndarray:
    """(nnum, nnum, K, K) float32 bank, K = 2·radius + 1; ``phase(rx, ry)`` in waves or None."""
    dx = pitch / os
    n = 256
    f = np.fft.fftfreq(n, d=dx)
    fx, fy = np.meshgrid(f, f)
    rho_x, rho_y = fx * wavelength / na, fy * wavelength / na
    pupil = (rho_x**2 + rho_y**2 <= 1.0).astype(complex)
    if phase is not None:
        pupil = pupil * np.exp(2j * np.pi * phase(rho_x, rho_y))
    field = np.fft.fftshift(np.fft.ifft2(pupil))
    field /= np.sqrt((np.abs(field) ** 2).sum())  # one photon per point, over fine samples
    n2 = int(round(wavelength * mla_focal * os / (dx * pitch)))
    half = nnum * os // 2
    yy, xx = (np.mgrid[:n2, :n2] - n2 // 2) * 1.0
    aperture = (yy**2 + xx**2) <= (nnum * os / 2.0) ** 2
    k = 2 * radius + 1
    bank = np.zeros((nnum, nnum, k, k))
    c0 = n // 2
    for iy, dy in enumerate(range(-radius, radius + 1)):
        for ix, dxp in enumerate(range(-radius, radius + 1)):
            # lenslet displaced by (dy, dx) from the point: the point sits at -(dy, dx)
            sy, sx = -dy * os, -dxp * os
            y0, x0 = c0 - n2 // 2 - sy, c0 - n2 // 2 - sx
            if y0 < 0 or x0 < 0 or y0 + n2 > n or x0 + n2 > n:
                continue
            local = field[y0:y0 + n2, x0:x0 + n2] * aperture
            sensor = np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(local))) / n2
            inten = np.abs(sensor) ** 2
            cy = n2 // 2
            lo = cy - half - 1
            crop = inten[lo:lo + nnum * os, lo:lo + nnum * os]
            crop = crop.reshape(nnum, os, nnum, os).sum(axis=(1, 3))
            bank[:, :, iy, ix] = crop[::-1, ::-1]
    return bank.astype(np.float32)


def gaussian_psfs(nnum: int = 5, radius: int = 4, sigma: float = 1.0, shift: float = 0.3,
                  seed: int = 0) -> np.ndarray:
    """Toy bank: Gaussian blobs displaced per view (parallax-like), widths varying by view."""
    rng = np.random.default_rng(seed)
    k = 2 * radius + 1
    y, x = np.mgrid[-radius:radius + 1, -radius:radius + 1].astype(float)
    c = nnum // 2
    bank = np.zeros((nnum, nnum, k, k))
    for u in range(nnum):
        for v in range(nnum):
            s = sigma * (0.7 + 0.6 * rng.random())
            g = np.exp(-((y - shift * (u - c)) ** 2 + (x - shift * (v - c)) ** 2) / (2 * s * s))
            bank[u, v] = g / g.sum() / nnum
    return bank.astype(np.float32)


def synth_views(scene: np.ndarray, bank: np.ndarray, d: int, border: int = 10) -> tuple:
    """Views (nnum, nnum, S, S) of the central field of ``scene`` through ``bank`` (every view).

    The scene extends ``border`` view samples beyond the field on every side (light from outside
    the field enters it, as in a real capture). Returns (views, truth) with truth the field's
    (S·d, S·d) pixels. Uses the recon operator itself (for machinery tests, not quality claims).
    """
    import torch

    from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry

    n = bank.shape[0]
    total = scene.shape[0] // d
    s = total - 2 * border
    g = make_geometry((total, total), d, bank.shape[-1] // 2)
    op = PhaseSpaceOperator(bank.reshape(n * n, *bank.shape[2:]), g, device="cpu")
    dom = np.zeros(g.domain, np.float32)
    oy, ox = g.offset
    dom[oy:oy + total * d, ox:ox + total * d] = scene[:total * d, :total * d]
    samples = op.forward(torch.from_numpy(dom)).numpy()
    sl = g.sample_slices()
    views = samples[:, sl[0], sl[1]][:, border:border + s, border:border + s]
    truth = scene[border * d:(border + s) * d, border * d:(border + s) * d]
    return views.reshape(n, n, s, s).astype(np.float32), truth.astype(np.float32)


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """Run the recon tests on one torch thread (restored after): on a shared 2-core machine two
    threads per op spin against other jobs and slow these small transforms ~10x."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
