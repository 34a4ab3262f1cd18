"""Coherent field of a point source at the image (MLA) plane.

``U(r) = ∫ P(rho) exp(−i 2π (NA/λ) rho·r) d²rho`` (docs/conventions.md: a *forward* transform,
so a positive Noll-2 tilt moves the field along +x). Two exact evaluations of the same sum over
pupil samples, whichever is cheaper for the requested output grid (hand-written in torch, so it
runs on CPU or CUDA; the MFT is the "matrix Fourier transform" of prysm or poppy):

- ``"fft"``: the pupil is sampled on the frequency grid of an odd ``n_fft``-point FFT of pitch
  ``dx`` (padded so the pupil radius has >= 96 samples) and the centre ``n × n`` is kept;
- ``"mft"``: the pupil on its own grid, transformed onto the ``n × n`` output grid by two
  matrix products (best for finely sampled, small windows).

Either way the pupil radius has at least ``max(96, 2.2 max|∇W| + 8)`` samples (Nyquist for the
wavefront's steepest slope) and the output is not wrapped around inside the window: light
beyond it is simply not represented.

Normalisation: output samples are amplitudes whose squares are the fraction of a unit point's
photons in each ``dx × dx`` cell: ``sum |U|² = sum A² / sum A0²`` over the whole plane, A0 the
clear circular pupil sampled the same way (1 for the clear pupil).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from metasensor.config import SystemConfig
from metasensor.optics.pupil import disk_fraction, pupil_amplitude, pupil_grid, pupil_phase

__all__ = ["FieldPlan", "plan_field", "pupil_samples", "point_field", "binned_intensity_mft",
           "next_fast_odd"]

MIN_PUPIL_RADIUS = 96.0


def next_fast_odd(n: int) -> int:
    """Smallest odd integer >= n whose prime factors are 3, 5, 7, 11 (fast FFT sizes)."""
    m = max(1, int(n)) | 1
    while True:
        k = m
        for p in (3, 5, 7, 11):
            while k % p == 0:
                k //= p
        if k == 1:
            return m
        m += 2


@dataclass(frozen=True)
class FieldPlan:
    """How to evaluate the field: method, pupil radius [samples] and pupil grid size."""

    method: str
    radius: float
    pupil_n: int


def plan_field(cfg: SystemConfig, n: int, dx: float, grad_max: float,
               method: str | None = None) -> FieldPlan:
    """Choose FFT or MFT for an ``n × n`` output grid of pitch ``dx`` [m] (odd n); ``method``
    ("fft"/"mft") forces one."""
    scale = cfg.na / cfg.wavelength * dx  # pupil radius [samples] per FFT sample
    r_min = max(MIN_PUPIL_RADIUS, 2.2 * grad_max + 8.0)
    n_fft = next_fast_odd(max(n, math.ceil(r_min / scale)))
    r_mft = max(r_min, 1.1 * n * scale)  # MFT period radius·λ/NA 10 % wider than the window
    m_mft = 2 * math.ceil(r_mft) + 3
    cost_fft = 2.0 * n_fft**2 * math.log2(n_fft)
    cost_mft = float(m_mft) * n * (m_mft + n)
    if method not in (None, "fft", "mft"):
        raise ValueError(f"method must be 'fft', 'mft' or None, got {method!r}")
    if method == "mft" or (method is None and cost_mft < cost_fft):
        return FieldPlan("mft", r_mft, m_mft)
    return FieldPlan("fft", n_fft * scale, n_fft)


def pupil_samples(cfg: SystemConfig, plan: FieldPlan, zernike=None, depth: float = 0.0,
                  phase=None, amplitude=None):
    """Pupil amplitude and wavefront on the centre of the plan's grid: the ``b × b`` samples
    (b odd, ``<= plan.pupil_n``) that can hold light (within the pupil radius plus two cells);
    every other sample of the ``pupil_n²`` grid is zero.

    Returns ``(a, w, norm)``: amplitude (edge cells area-weighted), wavefront in waves (0
    outside the pupil) and the energy ``sum A0²`` of the clear reference pupil.
    """
    from metasensor.backend import check_memory

    b = min(plan.pupil_n, 2 * (math.ceil(plan.radius) + 2) + 1)
    check_memory(64.0 * b**2, f"the pupil grid ({b}² samples of a pupil "
                 f"{plan.radius:.0f} samples in radius; about 8 float64 arrays)")
    rx, ry = pupil_grid(b, plan.radius)
    step = 1.0 / plan.radius
    a = pupil_amplitude(cfg, rx, ry, step, amplitude)
    inside = a > 0
    w = np.zeros(a.shape)
    w[inside] = pupil_phase(cfg, rx[inside], ry[inside], zernike, depth, phase)
    if not np.isfinite(w).all():
        raise ValueError("pupil phase is not finite inside the pupil")
    norm = float(np.sum(disk_fraction(rx, ry, step) ** 2))
    return a, w, norm


def point_field(cfg: SystemConfig, plan: FieldPlan, a: np.ndarray, w: np.ndarray, norm: float,
                n: int, dx: float, device, dtype=torch.complex64) -> torch.Tensor:
    """Field of a unit point at the centre sample ``n // 2`` of an ``n × n`` grid of pitch dx.

    ``a, w, norm`` from :func:`pupil_samples` with the same plan. Complex tensor on device.
    """
    p = torch.polar(torch.as_tensor(a, dtype=torch.float64, device=device),
                    torch.as_tensor(2 * np.pi * w, dtype=torch.float64, device=device))
    if plan.method == "fft":
        m = plan.pupil_n
        return (_centred_dft(p, n, m) / (m * math.sqrt(norm))).to(dtype)
    m = p.shape[0]
    df = cfg.na / cfg.wavelength / plan.radius  # pupil sample spacing [1/m]
    f = (np.arange(m) - m // 2) * df
    x = (np.arange(n) - n // 2) * dx
    e = torch.as_tensor(np.exp(-2j * np.pi * np.outer(x, f)), dtype=torch.complex128,
                        device=device)
    u = e @ p @ e.T  # rows y, columns x
    u *= df * dx / math.sqrt(norm)
    return u.to(dtype)


def _centred_dft(p: torch.Tensor, n: int, m: int) -> torch.Tensor:
    """``fftshift(fft2(ifftshift(P)))`` cropped to its centre ``n × n``, where ``P`` is the
    ``m × m`` grid (odd sizes) holding ``p`` (``b × b``, b <= m) at its centre and zeros
    elsewhere: two passes of 1-D FFTs of length m, along x over the b rows of ``p`` only, then
    along y for the n output columns only (the same sums as the full 2-D FFT)."""
    b = p.shape[0]
    dev = p.device
    out_idx = torch.arange(-(n // 2), n // 2 + 1, device=dev) % m  # centred k ↔ FFT index
    at = (torch.arange(b, device=dev) - b // 2) % m  # ifftshift: centred j ↔ FFT index
    buf = p.new_zeros((b, m))
    buf[:, at] = p
    fx = torch.fft.fft(buf, dim=1)[:, out_idx]  # (b, n)
    buf = p.new_zeros((m, n))
    buf[at] = fx
    return torch.fft.fft(buf, dim=0)[out_idx]


def binned_intensity_mft(cfg: SystemConfig, plan: FieldPlan, a: np.ndarray, w: np.ndarray,
                         norm: float, n: int, dx: float, k: int, device,
                         rows: int = 1024) -> torch.Tensor:
    """|field|² of a unit point on the ``n × n`` grid (as :func:`point_field` with an MFT plan),
    summed over k x k cells: (n // k, n // k) float64. The field is formed ``rows`` output rows
    (rounded to a multiple of k) at a time, so memory stays O(n·pupil_n) instead of O(n²): the
    widefield PSF of a strongly aberrated lens needs grids of ~20,000² (6 GB per complex array)."""
    if plan.method != "mft":
        raise ValueError("binned_intensity_mft needs an MFT plan (plan_field(..., method='mft'))")
    if n % k:
        raise ValueError(f"grid size {n} is not a multiple of the bin {k}")
    p = torch.polar(torch.as_tensor(a, dtype=torch.float64, device=device),
                    torch.as_tensor(2 * np.pi * w, dtype=torch.float64, device=device))
    m = p.shape[0]
    df = cfg.na / cfg.wavelength / plan.radius
    f = (np.arange(m) - m // 2) * df
    x = (np.arange(n) - n // 2) * dx
    e = torch.as_tensor(np.exp(-2j * np.pi * np.outer(x, f)), dtype=torch.complex128,
                        device=device)
    pe = (p @ e.T) * (df * dx / math.sqrt(norm))  # (m, n): pupil rows, image columns
    step = max(k, (int(rows) // k) * k)
    out = torch.empty((n // k, n // k), dtype=torch.float64, device=device)
    for r0 in range(0, n, step):
        u = e[r0:r0 + step] @ pe
        inten = (u.real.square() + u.imag.square())
        h = inten.shape[0] // k
        out[r0 // k:r0 // k + h] = inten.reshape(h, k, n // k, k).sum(dim=(1, 3))
    return out
