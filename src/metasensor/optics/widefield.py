"""The PSF of a conventional 2D sensor behind the same lens (the widefield PSF).

Hand-written, as :mod:`metasensor.optics.psf` (whose pupil, window and binning it shares): the
same pupil ``P(rho) = A exp(i 2π W)`` gives the coherent field at the image plane by a forward
transform (FFT, or a row-chunked matrix Fourier transform where the field would not fit,
:mod:`metasensor.optics.coherent`), sampled finely enough for the intensity's band 2NA/λ and
integrated over pixels of the given side.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from metasensor.backend import resolve_device
from metasensor.config import SystemConfig, say_fallbacks
from metasensor.optics.coherent import binned_intensity_mft, plan_field, point_field, pupil_samples
from metasensor.optics.psf import (
    PSF_CODE_VERSION,
    _bin,
    _crop,
    _ray_reach,
    _reference_pupil,
    _window_size,
    mirrored_pupil,
)
from metasensor.optics.psf_args import check_config, check_depth, check_odd, check_zernike
from metasensor.optics.pupil import PupilFn
from metasensor.optics.symmetry import cached_mirrored

__all__ = ["widefield_psf", "WIDEFIELD_FFT_BYTES"]

# widefield fields above this many bytes (complex128) are formed by row-chunked MFT instead
# (a 3-wave lens needs ~20,000² samples: 6 GB per array by FFT)
WIDEFIELD_FFT_BYTES = 1 << 30


def widefield_psf(cfg: SystemConfig, zernike=None, depth: float = 0.0, sampling=None, *,
                  phase: PupilFn | None = None, amplitude=None, size: int | None = None,
                  device=None, cache=True) -> np.ndarray:
    """PSF of a conventional 2D sensor behind the same lens: (K, K) float32.

    Each value is the fraction of a unit point's photons on a pixel of side ``sampling``
    (default ``cfg.pixel_pitch``) [m], centre index ``K // 2`` = the point; the sum is the
    fraction of light on the K×K window (≈ 1 for the clear pupil). Same pupil arguments as
    :func:`metasensor.optics.psf.view_psfs`. ``size`` None: smallest odd K keeping >= 99.5 %
    of the energy. ``cache``: as :func:`metasensor.optics.psf.view_psfs` (the key hashes the
    pupil on the same grid, depth, ``sampling`` and ``size``; one PSF per mirror orbit of the
    pupil, whose PSF is the mirrored PSF, as for the banks).
    """
    check_config(cfg)
    say_fallbacks(cfg)
    z = check_zernike(zernike)
    depth = check_depth(depth)
    size = check_odd(size, "size")
    if sampling is None:
        sampling = cfg.pixel_pitch
    if isinstance(sampling, bool) or not isinstance(sampling, (int, float, np.floating)) \
            or not (math.isfinite(sampling) and sampling > 0):
        raise ValueError(f"sampling must be a positive pixel size in metres, got {sampling!r}")
    dev = resolve_device(device)
    a_ref, w_ref, gmax = _reference_pupil(cfg, z, depth, phase, amplitude)
    if cache is False:
        return _widefield(cfg, z, depth, phase, amplitude, sampling, size, gmax, dev)
    def compute(g):  # the PSF of the pupil mirrored by g (the orbit's canonical member)
        ph, am = mirrored_pupil(cfg, z, phase, amplitude, g)
        return _widefield(cfg, None, depth, ph, am, sampling, size, gmax, dev)

    return cached_mirrored((PSF_CODE_VERSION, "widefield_psf", cfg.optical_digest()), a_ref,
                           w_ref, (depth, float(sampling), size),
                           None if cache is True else Path(cache), compute)


def _widefield(cfg, z, depth, phase, amplitude, sampling, size, gmax, dev) -> np.ndarray:
    """:func:`widefield_psf`'s computation (its arguments checked)."""
    if size is None:  # search window: the ray bundle plus 30 λ/NA
        reach = _ray_reach(cfg, gmax) + 30.0 * cfg.wavelength / cfg.na
        npix = 2 * math.ceil(reach / sampling) + 1
    else:
        npix = size
    pix, total = _widefield_pixels(cfg, z, depth, phase, amplitude, sampling, npix, gmax, dev)
    if size is None:
        size, _ = _window_size(pix, 1, npix, total=total)
    return np.ascontiguousarray(_crop(pix, size), dtype=np.float32)


def _widefield_pixels(cfg, z, depth, phase, amplitude, sampling, npix, gmax, dev):
    """(npix, npix) float64 photon fractions on pixels of side ``sampling``, and the total
    light reaching the image plane (sum A² / sum A0²)."""
    lam_na = cfg.wavelength / cfg.na
    os_ = 3
    while sampling / os_ > 0.9 * lam_na / 4:  # sample the intensity (band 2NA/λ) at Nyquist
        os_ += 2
    dx = sampling / os_
    n = npix * os_
    plan = plan_field(cfg, n, dx, gmax)
    if plan.method == "fft" and plan.pupil_n**2 * 16 > WIDEFIELD_FFT_BYTES:
        plan = plan_field(cfg, n, dx, gmax, method="mft")  # row-chunked: bounded memory
    a, w, norm = pupil_samples(cfg, plan, z, depth, phase, amplitude)
    if plan.method == "mft" and n * n * 16 > WIDEFIELD_FFT_BYTES:
        pix = binned_intensity_mft(cfg, plan, a, w, norm, n, dx, os_, dev).cpu().numpy()
        return pix, float(np.sum(a**2) / norm)
    u0 = point_field(cfg, plan, a, w, norm, n, dx, dev, dtype=torch.complex128)
    pix = _bin(u0.real.square() + u0.imag.square(), os_).cpu().numpy()
    return pix, float(np.sum(a**2) / norm)
