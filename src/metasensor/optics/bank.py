"""The phase-space PSF bank's wave-optics engine (:func:`metasensor.optics.psf.view_psfs`):
the field of a point at every position inside one lenslet, times the lenslet array,
propagated to the sensor, ``|.|²`` binned into pixels and regrouped into views.

Hand-written (Wu et al. 2022, Methods): no library models a microlens-array sensor.

Two evaluations of the same bank:

- *direct*: every one of the ``npos²`` point positions per lenslet is propagated (an integer
  roll of the point's field ``U0`` where the position step is a whole number of simulation
  samples, a Fourier shift otherwise);
- *band-limited* (``view_psfs(band_limited=True)``, the simulator's fine banks): the point's
  field is band-limited by the pupil to spatial frequencies ``|f| <= NA/λ``, so the field
  behind the lenslets, and its intensity on every sensor pixel, is a trigonometric polynomial
  of the point's position with frequencies ``|f| <= 2 NA/λ``. Sampling the position at
  ``P > 4 NA p_mla / λ`` points per lenslet pitch (:func:`band_positions`, 10 % margin) over
  the whole periodic grid therefore determines it, and the bank on any finer grid of
  ``npos`` positions follows by trigonometric (Dirichlet-kernel) interpolation of the
  periodic bank, one matrix product per axis and view. For the simulator's ``subsample = 3``
  bank of the prototype (45 positions per pitch) P = 29: 2.4× fewer propagations. It is not
  bit-for-bit the direct evaluation: ``U0`` is held on a finite grid, and the light cut off
  at the grid's edge adds frequencies beyond the band, which the P positions alias
  (``tests/optics/test_bank_speedups.py`` bounds the difference).

The band-limited path runs its FFTs on CPU in ``scipy.fft`` (pocketfft, on torch's intra-op
thread count), faster than torch's CPU FFT at these odd, 3- and 5-smooth sizes (measured:
docs/decisions.md, "the gigapixel demo cold"); on CUDA in torch. The direct path keeps torch's
FFT, so its banks stay bit-for-bit those of earlier versions (scipy's rounding differs in the
last bits).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from metasensor.config import SystemConfig
from metasensor.optics.pupil import disk_fraction

__all__ = ["band_positions", "BAND_MARGIN"]

#: positions per lenslet pitch of the band-limited bank: this factor times the Nyquist count
BAND_MARGIN = 1.1


def band_positions(cfg: SystemConfig) -> int:
    """Odd number of point positions per lenslet pitch that samples the bank's dependence on
    the point's position: the intensity holds frequencies up to ``2 NA/λ``, so more than
    ``4 NA · mla_pitch / λ`` positions per pitch; times :data:`BAND_MARGIN`."""
    return math.ceil(BAND_MARGIN * 4.0 * cfg.na * cfg.mla_pitch / cfg.wavelength) | 1


def _lenslet_tile(cfg: SystemConfig, oversample: int) -> np.ndarray:
    """Complex transmission of one lenslet cell, (nnum·os, nnum·os), centred on its middle."""
    m = cfg.nnum * oversample
    dx = cfg.pixel_pitch / oversample
    r = (np.arange(m) - m // 2) * dx
    x, y = np.meshgrid(r, r, indexing="xy")
    half = cfg.lenslet_diameter / 2
    if cfg.lenslet_aperture == "circular":
        frac = disk_fraction(x / half, y / half, dx / half)
    else:
        q = (np.arange(8) + 0.5) / 8 - 0.5
        fx = np.mean([(np.abs(r + d * dx) <= half) for d in q], axis=0)
        frac = fx[None, :] * fx[:, None]
    quad = np.exp(-1j * np.pi * (x**2 + y**2) / (cfg.wavelength * cfg.mla_focal))
    return np.sqrt(frac) * quad


def _transfer(n: int, dx: float, z: float, wavelength: float) -> np.ndarray:
    """Angular-spectrum (Rayleigh–Sommerfeld) transfer function in FFT order, piston removed."""
    f = np.fft.fftfreq(n, dx)
    f2 = f[None, :] ** 2 + f[:, None] ** 2
    kz = np.sqrt(np.clip(1.0 / wavelength**2 - f2, 0.0, None))
    h = np.exp(2j * np.pi * z * (kz - 1.0 / wavelength))
    h[f2 >= 1.0 / wavelength**2] = 0.0  # evanescent
    return h


def _batch_size(n: int, npos: int, dev: torch.device) -> int:
    """Point positions per batch: ~384 MiB of complex work arrays on CPU, 4 GiB on CUDA."""
    budget = (4 << 30) if dev.type == "cuda" else (384 << 20)
    return max(1, min(npos, budget // (n * n * 8 * 3)))


def _simulate_bank(cfg, u0: torch.Tensor, os_, npos, lenslets, kf, dev,
                   band_limited: bool = False) -> np.ndarray:
    """Bank (nnum, nnum, kf, kf) from the field ``u0`` (n, n) of a point at the centre of
    the central lenslet, on a grid of ``lenslets`` lenslets per axis, for ``npos`` point
    positions per lenslet pitch (the output grid): with ``band_limited`` from
    :func:`band_positions` positions where that is fewer than ``npos``, else direct (module
    docstring)."""
    n = u0.shape[0]
    dx = cfg.pixel_pitch / os_
    tile = torch.as_tensor(_lenslet_tile(cfg, os_), dtype=torch.complex64, device=dev)
    mla = tile.repeat(lenslets, lenslets)
    hz = torch.as_tensor(_transfer(n, dx, cfg.mla_focal, cfg.wavelength),
                         dtype=torch.complex64, device=dev)
    pb = band_positions(cfg)
    if band_limited and pb < npos:
        periodic = _band_limited_bank(cfg, u0, mla, hz, os_, pb, lenslets)
        w = _dirichlet(lenslets * pb, pb, npos, kf).to(dev)
        bank = torch.empty((cfg.nnum, cfg.nnum, kf, kf), dtype=torch.float32, device=dev)
        for u in range(cfg.nnum):  # one row of views at a time: a small intermediate
            torch.matmul(torch.matmul(w, periodic[u]), w.T, out=bank[u])
        del periodic
    else:
        bank = _direct_bank(cfg, u0, mla, hz, os_, npos, lenslets, kf)
    return (bank * (cfg.nnum / npos) ** 2).cpu().numpy()  # a point: (nnum/npos)² px of flux


def _direct_bank(cfg, u0, mla, hz, os_, npos, lenslets, kf) -> torch.Tensor:
    """The bank on the output window (nnum, nnum, kf, kf), one propagation per position."""
    nnum = cfg.nnum
    n = u0.shape[0]
    dev = u0.device
    # point positions per axis, s = half − i for i = 0 .. npos − 1
    half = npos // 2
    cf = kf // 2
    # one extra row and column collect the blocks that fall outside the window
    bank = torch.zeros((nnum, nnum, kf + 1, kf + 1), dtype=torch.float32, device=dev)
    mrange = (np.arange(lenslets) - lenslets // 2) * npos
    shifted = _shifted_fields(u0, nnum * os_, npos)
    rows = max(1, _batch_size(n, npos * npos, dev) // npos)
    offs = half - np.arange(npos)
    from tqdm.auto import tqdm

    starts = range(0, npos, rows)
    buf = torch.empty((min(rows, npos), npos, n, n), dtype=torch.complex64, device=dev)
    ibuf = torch.empty((min(rows, npos) * npos, n, n), dtype=torch.float32, device=dev)
    for r0 in tqdm(starts, desc="view PSFs", disable=None if len(starts) > 4 else True,
                   leave=False):
        r1 = min(npos, r0 + rows)
        u = torch.mul(shifted[r0:r1], mla, out=buf[:r1 - r0])  # the point at s, times the MLA
        inten = _propagated_intensity(u.view(-1, n, n), hz, out=ibuf[:(r1 - r0) * npos])
        pix = _bin(inten, os_)
        b = pix.shape[0]
        blocks = pix.reshape(b, lenslets, nnum, lenslets, nnum).permute(2, 4, 0, 1, 3)
        by = np.repeat(offs[r0:r1], npos)
        bx = np.tile(offs, r1 - r0)
        iy = cf + mrange[None, :] - by[:, None]
        ix = cf + mrange[None, :] - bx[:, None]
        iy = torch.as_tensor(np.where((iy >= 0) & (iy < kf), iy, kf), device=dev)[:, :, None]
        ix = torch.as_tensor(np.where((ix >= 0) & (ix < kf), ix, kf), device=dev)[:, None, :]
        bank[:, :, iy, ix] = blocks
    return bank[:, :, :kf, :kf]


def _band_limited_bank(cfg, u0, mla, hz, os_, pb, lenslets) -> torch.Tensor:
    """The periodic bank (nnum, nnum, N, N), N = lenslets·pb: every displacement of the
    grid's period for ``pb`` point positions per pitch, each position's field ``U0`` shifted
    in Fourier space (along y once per row of positions, then along x)."""
    nnum = cfg.nnum
    n = u0.shape[0]
    dev = u0.device
    big = lenslets * pb
    half = pb // 2
    k = torch.fft.fftfreq(n, device=dev, dtype=torch.float64)
    shifts = (half - torch.arange(pb, device=dev, dtype=torch.float64)) * (nnum * os_ / pb)
    ramp = torch.exp(-2j * math.pi * shifts[:, None] * k[None, :]).to(torch.complex64)
    spec = _fft(_fft(u0.to(torch.complex64).clone(), 0), 1)
    periodic = torch.zeros((nnum, nnum, big, big), dtype=torch.float32, device=dev)
    m = (np.arange(lenslets) - lenslets // 2) * pb
    s = half - np.arange(pb)
    dxi = torch.as_tensor((m[None, :] - s[:, None]) % big, device=dev)[None]  # (1, pb, L)
    chunk = _batch_size(n, pb, dev)
    buf = torch.empty((chunk, n, n), dtype=torch.complex64, device=dev)
    ibuf = torch.empty((chunk, n, n), dtype=torch.float32, device=dev)
    from tqdm.auto import tqdm

    for iy in tqdm(range(pb), desc="view PSFs", disable=None, leave=False):
        a = _fft(spec * ramp[iy][:, None], 0, inverse=True)  # shifted along y; x: frequency
        dyi = torch.as_tensor((m - s[iy]) % big, device=dev)[:, None, None]  # (L, 1, 1)
        for x0 in range(0, pb, chunk):
            x1 = min(pb, x0 + chunk)
            u = torch.mul(a[None], ramp[x0:x1, None, :], out=buf[:x1 - x0])
            u = _fft(u, 2, inverse=True).mul_(mla)  # the point at s, times the MLA
            pix = _bin(_propagated_intensity(u, hz, ibuf[:x1 - x0], scipy_cpu=True), os_)
            blocks = pix.reshape(x1 - x0, lenslets, nnum, lenslets, nnum).permute(2, 4, 1, 0, 3)
            periodic[:, :, dyi, dxi[:, x0:x1]] = blocks
    return periodic


def _dirichlet(big: int, pb: int, npos: int, kf: int) -> torch.Tensor:
    """(kf, big) float32: the values at the window's displacements ``t`` (1/npos of a pitch,
    centred) of the trigonometric polynomial through ``big`` (odd) periodic samples 1/pb of a
    pitch apart (Dirichlet kernel ``sin(πδ) / (N sin(πδ/N))``, δ in source samples)."""
    t = (np.arange(kf) - kf // 2) * (pb / npos)
    d = t[:, None] - np.arange(big)[None, :]
    den = big * np.sin(np.pi * d / big)
    near = np.abs(den) < 1e-9
    w = np.where(near, 1.0, np.sin(np.pi * d) / np.where(near, 1.0, den))
    return torch.from_numpy(w.astype(np.float32))


def _fft(x: torch.Tensor, dim: int, inverse: bool = False) -> torch.Tensor:
    """1-D FFT along ``dim`` (``x`` may be overwritten): scipy.fft on CPU, torch on CUDA."""
    if x.device.type == "cpu":
        from scipy import fft as sfft

        f = sfft.ifft if inverse else sfft.fft
        return torch.from_numpy(f(x.numpy(), axis=dim, overwrite_x=True,
                                  workers=torch.get_num_threads()))
    return torch.fft.ifft(x, dim=dim) if inverse else torch.fft.fft(x, dim=dim)


def _propagate(u: torch.Tensor, hz: torch.Tensor, scipy_cpu: bool = False) -> torch.Tensor:
    """``IFFT2(FFT2(u) · hz)`` of a batch of fields ``u`` (b, n, n) complex64 (``u`` may be
    overwritten); torch's FFT, or with ``scipy_cpu`` scipy.fft on CPU (module docstring; the
    direct bank keeps torch's, so its numbers do not change)."""
    if scipy_cpu and u.device.type == "cpu":
        from scipy import fft as sfft

        workers = torch.get_num_threads()
        f = sfft.fft2(u.numpy(), overwrite_x=True, workers=workers)
        f *= hz.numpy()
        return torch.from_numpy(sfft.ifft2(f, overwrite_x=True, workers=workers))
    return torch.fft.ifft2(torch.fft.fft2(u).mul_(hz))


def _propagated_intensity(u: torch.Tensor, hz: torch.Tensor, out: torch.Tensor | None = None,
                          scipy_cpu: bool = False) -> torch.Tensor:
    """``|IFFT2(FFT2(u) · hz)|²`` (:func:`_propagate`), float32 (b, n, n), into ``out`` if
    given (a reused buffer: no fresh pages per batch)."""
    ri = torch.view_as_real(_propagate(u, hz, scipy_cpu))
    inten = torch.square(ri[..., 0], out=out)
    return inten.addcmul_(ri[..., 1], ri[..., 1])


def _shifted_fields(u0: torch.Tensor, per_lenslet: int, npos: int):
    """``U0(r − s)`` for the ``npos²`` point positions ``s = (half − i, half − j)`` grid
    samples of ``per_lenslet / npos`` simulation samples each: indexable ``[i0:i1]`` →
    ``(i1 − i0, npos, n, n)``. An integer step is one strided view of a periodic copy of U0
    (no copy per position); a fractional one shifts U0 in Fourier space (exact: the periodic
    field is band-limited to NA/λ, sampled above Nyquist)."""
    n = u0.shape[0]
    half = npos // 2
    if per_lenslet % npos == 0:
        step = per_lenslet // npos
        # pre-shifted by +half·step: position (i, j) starts at (i·step, j·step)
        big = torch.roll(u0, (half * step, half * step), (0, 1)).repeat(2, 2).contiguous()
        return torch.as_strided(big, (npos, npos, n, n), (step * 2 * n, step, 2 * n, 1))
    spec = torch.fft.fft2(u0)
    k = torch.fft.fftfreq(n, device=u0.device, dtype=torch.float64)
    shifts = (half - torch.arange(npos, device=u0.device, dtype=torch.float64)) \
        * (per_lenslet / npos)
    ramp = torch.exp(-2j * math.pi * shifts[:, None] * k[None, :]).to(spec.dtype)  # (npos, n)

    class _Lazy:
        def __getitem__(self, rows: slice):
            ry = ramp[rows]  # (b, n)
            return torch.fft.ifft2(spec[None, None] * ry[:, None, :, None]
                                   * ramp[None, :, None, :])

    return _Lazy()


def _bin(inten: torch.Tensor, k: int) -> torch.Tensor:
    """Sum k x k blocks of the last two axes (sizes divisible by k)."""
    *lead, h, w = inten.shape
    a = inten.reshape(*lead, h // k, k, w)
    acc = a[..., 0, :].clone()
    for i in range(1, k):
        acc += a[..., i, :]
    a = acc.reshape(*lead, h // k, w // k, k)
    acc = a[..., 0].clone()
    for i in range(1, k):
        acc += a[..., i]
    return acc
