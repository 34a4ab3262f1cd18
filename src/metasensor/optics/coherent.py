"""Coherent field of a point source at the image (MLA) plane, by a matrix Fourier transform.

``U(r) = ∫ P(rho) exp(−i 2π (NA/λ) rho·r) d²rho`` (docs/conventions.md: a *forward* transform,
so a positive Noll-2 tilt moves the field along +x). The pupil is sampled on its own grid
(radius ``radius`` samples) and the transform is evaluated directly on any centred output grid
of pitch ``dx`` as two matrix products (a "matrix Fourier transform", as in prysm or poppy;
hand-written here in torch so it runs on CPU or CUDA). Unlike a zero-padded FFT the output is
not wrapped around: light beyond the output grid is simply not represented, and the pupil
sampling does not depend on the output grid.

Normalisation: output samples are amplitudes whose squares are the fraction of a unit point's
photons in each ``dx × dx`` cell: ``sum |U|² = sum A² / sum A0²`` over the whole plane, A0 the
clear circular pupil sampled the same way.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from metasensor.config import SystemConfig
from metasensor.optics.pupil import disk_fraction, pupil_amplitude, pupil_grid, pupil_phase

__all__ = ["pupil_samples", "point_field", "pupil_radius_samples"]


def pupil_radius_samples(cfg: SystemConfig, extent: float, grad_max: float) -> float:
    """Pupil radius in samples for an output window of width ``extent`` [m] and a wavefront
    whose gradient reaches ``grad_max`` waves per unit rho: at least 96 samples, 4 samples
    per wave of phase, and an MFT period ``radius·λ/NA`` 10 % wider than the window."""
    return max(96.0, 4.0 * grad_max + 8.0, 1.1 * extent * cfg.na / cfg.wavelength)


def pupil_samples(cfg: SystemConfig, radius: float, zernike=None, depth: float = 0.0,
                  phase=None, amplitude=None):
    """Pupil amplitude and wavefront on an odd grid of ``radius`` samples in pupil radius.

    Returns ``(a, w, norm)``: amplitude (edge cells area-weighted), wavefront in waves (0
    outside the pupil) and the energy ``sum A0²`` of the clear reference pupil.
    """
    m = 2 * math.ceil(radius) + 3
    rx, ry = pupil_grid(m, radius)
    step = 1.0 / radius
    a = pupil_amplitude(cfg, rx, ry, step, amplitude)
    w = pupil_phase(cfg, rx, ry, zernike, depth, phase)
    w = np.where(a > 0, w, 0.0)
    if not np.isfinite(w).all():
        raise ValueError("pupil phase is not finite inside the pupil")
    norm = float(np.sum(disk_fraction(rx, ry, step) ** 2))
    return a, w, norm


def point_field(cfg: SystemConfig, a: np.ndarray, w: np.ndarray, norm: float, radius: float,
                n: int, dx: float, device, dtype=torch.complex64) -> torch.Tensor:
    """Field of a unit point at the centre sample ``n // 2`` of an ``n × n`` grid of pitch dx.

    ``a, w, norm, radius`` from :func:`pupil_samples`. Returns a complex tensor on ``device``.
    """
    m = a.shape[0]
    df = cfg.na / cfg.wavelength / radius  # pupil sample spacing in spatial frequency [1/m]
    f = (np.arange(m) - m // 2) * df
    x = (np.arange(n) - n // 2) * dx
    kernel = np.exp(-2j * np.pi * np.outer(x, f))  # (n, m)
    e = torch.as_tensor(kernel, dtype=torch.complex128, device=device)
    p = torch.polar(torch.as_tensor(a, dtype=torch.float64),
                    torch.as_tensor(2 * np.pi * w, dtype=torch.float64)).to(device)
    u = e @ p @ e.T  # rows y, columns x
    u *= df * dx / math.sqrt(norm)
    return u.to(dtype)
