"""Wave-optics PSFs: the coded-MLA phase-space PSF bank (the widefield PSF of a 2D sensor behind
the same lens is in :mod:`metasensor.optics.widefield`).

Hand-written (Wu et al. 2022, Methods; docs/conventions.md): no library models a microlens-array
sensor.

Model of :func:`view_psfs`, for every point position s inside the central lenslet:
pupil ``P(rho) = A exp(i 2π W)`` -> coherent field at the MLA ``U0(r) = ∫P exp(−i2π(NA/λ)rho·r)``
(forward transform, so a Noll-2 tilt of c waves moves it by +2cλ/NA along +x; computed once, by
a matrix Fourier transform, :mod:`metasensor.optics.coherent`) -> the point at s is an integer
roll of ``U0`` (grid pitch ``dx = pixel_pitch / oversample``; a Fourier shift for output grids
that are not a whole number of samples, ``points``) -> times the lenslet array
(aperture of ``cfg.lenslet_diameter``, quadratic phase ``exp(-iπ|r - c_m|²/(λ f_ml))``) ->
angular-spectrum propagation over ``mla_focal`` (FFT) -> ``|.|²`` -> integrate over the sensor
pixels (sum ``oversample²`` samples) -> regroup pixel (u, v) of lenslet block m into view (u, v)
at displacement ``m·nnum − s``.

Window and grid: the default K is the smallest odd window keeping >= 99.5 % of the light the
lenslets collect, predicted from the widefield intensity (searched out to the largest ray
displacement ``(λ/NA) max|∇W|`` plus 30 λ/NA) convolved with one lenslet aperture, plus 2 px per
side for the cross-talk. The simulation grid holds an odd number L of whole lenslets per axis
(periodic with the lenslet array, symmetric about the central lenslet's centre): those whose
pixels reach the window plus one margin lenslet per side (light outside the grid is dropped, and
the periodic wrap-around lands in the margin), and at least ``mla_focal·λ/dx²`` samples
(angular-spectrum sampling condition). Point positions are batched on torch (CPU or CUDA);
the engine, and the band-limited evaluation that needs fewer positions than the output grid,
is :mod:`metasensor.optics.bank`.

Normalisation (photons): a unit point source fills the pupil; ``sum |U0|² = sum A² / sum A0²``
over the plane, A0 the clear disk (1 for the clear pupil, ``1 − obstruction²`` for an annulus).
``H[u, v, y, x]`` is the fraction of the point's photons reaching pixel (u, v) of the lenslet
displaced by (y, x) from the point, so ``sum H ≈ nnum² × (area fraction of a lenslet passed by
its aperture)``, less the light outside the window.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from metasensor.backend import check_memory, resolve_device
from metasensor.config import SystemConfig, say_fallbacks
from metasensor.optics.bank import (  # noqa: F401  (the engine's helpers, importable here too)
    _batch_size,
    _bin,
    _lenslet_tile,
    _propagate,
    _propagated_intensity,
    _simulate_bank,
    _transfer,
)
from metasensor.optics.coherent import (
    next_fast_odd,
    plan_field,
    point_field,
    pupil_samples,
)
from metasensor.optics.psf_args import check_config, check_depth, check_odd, check_zernike
from metasensor.optics.pupil import PupilFn, disk_fraction, pupil_amplitude, pupil_phase
from metasensor.optics.symmetry import cached_mirrored, mirror_amplitude, mirror_function

__all__ = ["view_psfs", "mirrored_pupil", "PSF_CODE_VERSION", "ENERGY_CUT"]

PSF_CODE_VERSION = "psf-2"
ENERGY_CUT = 0.005  # default windows keep >= 99.5 % of the energy

# ----------------------------------------------------------------------------- helpers
def _reference_pupil(cfg: SystemConfig, zernike, depth: float, phase: PupilFn | None,
                     amplitude) -> tuple[np.ndarray, np.ndarray, float]:
    """The pupil evaluated on a fixed 257² grid over [-1.02, 1.02]²: amplitude, wavefront
    [waves], and max over the pupil of |∇W| in waves per unit rho (numerical gradient).

    The arrays key the cache (everything the bank depends on, before any heavy work)."""
    n = 257
    t = np.linspace(-1.02, 1.02, n)
    t = 0.5 * (t - t[::-1])  # exactly odd, so a mirrored pupil samples the mirrored values
    rx, ry = np.meshgrid(t, t, indexing="xy")
    a = pupil_amplitude(cfg, rx, ry, t[1] - t[0], amplitude)
    if zernike is None and depth == 0 and phase is None:
        return a, np.zeros_like(a), 0.0
    w = pupil_phase(cfg, rx, ry, zernike, depth, phase)
    gy, gx = np.gradient(w, t[1] - t[0])
    inside = rx**2 + ry**2 <= 1.0
    return a, np.where(a > 0, w, 0.0), float(np.nanmax(np.hypot(gx, gy)[inside]))


def _ray_reach(cfg: SystemConfig, grad_max: float) -> float:
    """Largest ray displacement at the MLA, (λ/NA) max |∇W| [m] (conventions.md)."""
    return cfg.wavelength / cfg.na * grad_max


def _window_size(energy: np.ndarray, step: int, kmax: int,
                 total: float | None = None) -> tuple[int, float]:
    """Smallest odd K (<= kmax, in units of ``step`` samples) whose centred K·step window keeps
    >= 1 − ENERGY_CUT of ``total`` (default: the whole map); returns (K, kept fraction)."""
    n = energy.shape[0]
    c = n // 2
    cs = np.zeros((n + 1, n + 1))
    cs[1:, 1:] = np.cumsum(np.cumsum(energy, 0), 1)
    if total is None:
        total = cs[-1, -1]
    for k in range(1, kmax + 1, 2):
        h = (k * step) // 2
        lo, hi = c - h, c + h + 1
        kept = cs[hi, hi] - cs[lo, hi] - cs[hi, lo] + cs[lo, lo]
        if kept >= (1 - ENERGY_CUT) * total:
            return k, float(kept / total)
    h = (kmax * step) // 2
    kept = cs[c + h + 1, c + h + 1] - cs[c - h, c + h + 1] - cs[c + h + 1, c - h] + cs[c - h, c - h]
    return kmax, float(kept / total)


def _crop(arr: np.ndarray, k: int) -> np.ndarray:
    c = arr.shape[-1] // 2
    h = k // 2
    return arr[..., c - h:c + h + 1, c - h:c + h + 1]


def _default_oversample(cfg: SystemConfig, subsample: int) -> int:
    """Odd multiple of subsample, >= 3, sampling the field behind the lenslets at Nyquist/0.9."""
    band = (cfg.na + cfg.lenslet_diameter / (2 * cfg.mla_focal)) / cfg.wavelength
    dx_max = 0.9 / (2 * band)
    os_ = subsample * math.ceil(3 / subsample)
    if os_ % 2 == 0:
        os_ += subsample
    while cfg.pixel_pitch / os_ > dx_max:
        os_ += 2 * subsample
    return os_


def _check_points(cfg: SystemConfig, points, sub: int) -> int:
    """Point positions per lenslet and axis (``nnum · subsample`` when None)."""
    if points is None:
        return cfg.nnum * sub
    if isinstance(points, bool) or not isinstance(points, int | np.integer) or points < 3 \
            or points % 2 == 0:
        raise ValueError(f"points must be an odd integer >= 3, got {points!r}")
    if sub != 1:
        raise ValueError(f"points and subsample {sub} cannot be combined; give one of them")
    return int(points)


# ----------------------------------------------------------------------------- view PSFs
def view_psfs(cfg: SystemConfig, zernike=None, depth: float = 0.0, *,
              phase: PupilFn | None = None, amplitude=None, subsample: int = 1,
              size: int | None = None, device=None, cache=True,
              oversample: int | None = None, points: int | None = None,
              band_limited: bool = False) -> np.ndarray:
    """Phase-space PSF bank ``H[u, v, y, x]`` of every view, float32
    ``(nnum, nnum, K·subsample, K·subsample)``.

    Parameters
    ----------
    cfg : the system.
    zernike : Noll coefficient vector in waves (``z[j-1]`` = mode j), or None.
    depth : defocus of the point on the image side [m]; > 0 focused in front of the MLA.
    phase : optional ``f(rho_x, rho_y) -> waves`` added to the Zernike wavefront; called with
        arrays of pupil coordinates of any shape (e.g. 1-D: the samples inside the pupil),
        must return that shape.
    amplitude : pupil amplitude: None (clear circle, annulus if ``cfg.obstruction``), an
        ``(nnum, nnum)`` map in view coordinates (nearest view), or ``f(rho_x, rho_y)``.
    subsample : odd; point positions every ``pixel_pitch / subsample``, output sampled at that
        pitch (the sensor pixels are still whole pixels). Centre index ``(K·subsample)//2`` is
        zero displacement. Normalisation: each fine point carries ``1/subsample²`` of a pixel's
        flux, ``H_sub = (photons per unit point) / subsample²``; hence the sub-lattice aligned
        with the pixel grid, ``H_sub[..., c::s, c::s] * s²`` (c = (K·s)//2 % s), equals the
        subsample=1 bank and ``H_sub.sum() ≈ H_1.sum()``.
    size : K, odd number of pixels per axis (None: the smallest K keeping >= 99.5 % of the
        light, see the module docstring).
    device : torch device (None: CUDA if available, else CPU).
    cache : True (default cache folder, see :mod:`metasensor.optics.cache`), False (bypass) or
        a folder path. The key hashes the code version, ``cfg.optical_digest()`` (not the scan),
        the pupil amplitude and wavefront evaluated on a fixed 257² grid, depth, subsample, size,
        oversample, ``points`` and ``band_limited``. The cache keeps one bank per mirror orbit of
        the pupil (:mod:`metasensor.optics.symmetry`: the bank of a mirrored pupil is the
        mirrored bank), computed for the orbit's canonical member whichever member is asked
        for first, so a centred lens's symmetric field points share one computation and a call
        returns the same bank whatever the cache held before (it equals the pupil's own direct
        computation to float32 rounding, a few 1e-7 of its maximum).
    oversample : simulation samples per pixel per axis (odd multiple of subsample; default >= 3).
    points : odd number of point positions (and output samples) per lenslet pitch and axis, or
        None (``nnum · subsample``). Another value samples the bank on a grid of pitch
        ``mla_pitch / points`` (the reconstruction grid ``cfg.grid_points`` of a scan period
        that does not divide nnum); ``size`` is then counted on that grid, the lenslets sit
        every ``points`` samples, and each point carries ``(nnum / points)²`` of a sensor
        pixel's flux (as with ``subsample``). Needs ``subsample = 1``. Positions between the
        simulation samples are reached by a Fourier shift of the point's field.
    band_limited : compute the bank from :func:`metasensor.optics.bank.band_positions`
        point positions per pitch and interpolate it to the output grid where that is fewer
        (the simulator's ``subsample = 3`` banks: 2.4× fewer propagations for the prototype);
        it differs from the direct evaluation (default) by the aliasing of the point field's
        light beyond its finite grid, a few 1e-5 of the bank's maximum
        (:mod:`metasensor.optics.bank`).
    """
    z, depth, sub, size, npts, os_ = _checked_settings(cfg, zernike, depth, subsample, size,
                                                       points, oversample, band_limited)
    dev = resolve_device(device)
    a_ref, w_ref, gmax = _reference_pupil(cfg, z, depth, phase, amplitude)
    if cache is False:
        return _view_bank(cfg, z, depth, phase, amplitude, gmax, size, npts, sub, os_,
                          points is not None, band_limited, dev)
    def compute(g):  # the bank of the pupil mirrored by g (the orbit's canonical member)
        ph, am = mirrored_pupil(cfg, z, phase, amplitude, g)
        return _view_bank(cfg, None, depth, ph, am, gmax, size, npts, sub, os_,
                          points is not None, band_limited, dev)

    return cached_mirrored(
        (PSF_CODE_VERSION, "view_psfs", cfg.optical_digest()), a_ref, w_ref,
        (depth, sub, size, os_, *(() if points is None else ("points", npts)),
         *(("band",) if band_limited else ())), None if cache is True else Path(cache),
        compute)


def mirrored_pupil(cfg: SystemConfig, zernike, phase: PupilFn | None, amplitude, g):
    """The pupil mirrored by the symmetry ``g`` (:mod:`metasensor.optics.symmetry`), as the
    ``phase`` and ``amplitude`` arguments of the PSF functions (the Zernike terms folded into
    the phase; the defocus of ``depth`` is radial and stays as it is).

    Parameters
    ----------
    cfg : SystemConfig
        The system.
    zernike : numpy.ndarray or None
        Noll coefficients [waves].
    phase : callable or None
        An extra wavefront ``phase(rho_x, rho_y)`` [waves].
    amplitude : None, numpy.ndarray or callable
        As :func:`metasensor.optics.pupil.pupil_amplitude` takes it.
    g : Symmetry
        The element.

    Returns
    -------
    (callable or None, amplitude)
        The mirrored wavefront [waves] (None: no aberration) and amplitude.
    """
    amp = mirror_amplitude(amplitude, g)
    if zernike is None and phase is None:
        return None, amp
    return mirror_function(lambda x, y: pupil_phase(cfg, x, y, zernike, 0.0, phase), g), amp


def _view_bank(cfg, z, depth, phase, amplitude, gmax, size, npts, sub, os_, pointed,
               band_limited, dev) -> np.ndarray:
    """:func:`view_psfs`'s computation (its settings checked and completed)."""
    dx = cfg.pixel_pitch / os_
    grid = npts / (cfg.nnum * sub)  # output samples per pixel/subsample (1 unless ``points``)
    size = _bank_size(cfg, z, depth, phase, amplitude, gmax, size, grid, sub, os_, pointed, dev)
    lenslets, n = _grid(cfg, math.ceil(size / grid) | 1, os_)
    _check_field_grid(cfg, lenslets, n, os_)
    plan = plan_field(cfg, n, dx, gmax)
    a, w, norm = pupil_samples(cfg, plan, z, depth, phase, amplitude)
    u0 = point_field(cfg, plan, a, w, norm, n, dx, dev)
    return _simulate_bank(cfg, u0, os_, npts, lenslets, size * sub if not pointed else size,
                          dev, band_limited)


def _checked_settings(cfg: SystemConfig, zernike, depth, subsample, size, points, oversample,
                      band_limited):
    """The settings of :func:`view_psfs`, checked (one-line errors) and completed.

    Parameters
    ----------
    cfg, zernike, depth, subsample, size, points, oversample, band_limited
        As :func:`view_psfs` takes them (``depth`` in metres, ``zernike`` in waves).

    Returns
    -------
    z : numpy.ndarray or None
        The Noll vector [waves].
    depth : float
        Image-side defocus [m].
    sub : int
        The odd subsample.
    size : int or None
        The odd window K, or None (the default window).
    npts : int
        Point positions per lenslet pitch and axis.
    os_ : int
        Simulation samples per pixel and axis (an odd multiple of ``sub``).
    """
    check_config(cfg)
    say_fallbacks(cfg)
    z = check_zernike(zernike)
    depth = check_depth(depth)
    sub = check_odd(subsample, "subsample")
    size = check_odd(size, "size")
    npts = _check_points(cfg, points, sub)
    os_ = check_odd(oversample, "oversample") or _default_oversample(cfg, sub)
    if os_ % sub:
        raise ValueError(f"oversample {os_} must be a multiple of subsample {sub}")
    if not isinstance(band_limited, bool):
        raise TypeError(f"band_limited must be True or False, got {band_limited!r}")
    return z, depth, sub, size, npts, os_


def _bank_size(cfg: SystemConfig, z, depth, phase, amplitude, gmax: float, size, grid: float,
               sub: int, os_: int, on_points: bool, dev) -> int:
    """The bank's window K, after the memory checks that come before any heavy work.

    Parameters
    ----------
    cfg, z, depth, phase, amplitude
        The system and pupil as :func:`view_psfs` takes them.
    gmax : float
        Max over the pupil of ``|∇W|`` [waves per unit rho] (:func:`_reference_pupil`).
    size : int or None
        The given odd K, or None: :func:`_default_size` (on the ``points`` grid when
        ``on_points``).
    grid : float
        Output samples per pixel / subsample (1 unless ``points``).
    sub, os_ : int
        Subsample and simulation samples per pixel.
    on_points : bool
        The bank is sampled on the ``points`` grid.
    dev : torch.device
        Where the widefield intensity of the default window is computed.

    Returns
    -------
    int
        The odd K.

    Raises
    ------
    MemoryError
        The bank, at the least K its rays need, or its field grid would not fit.
    """
    reach = _ray_reach(cfg, gmax) / cfg.pixel_pitch  # the bank spans at least ±reach pixels
    k_min = size or 2 * int(reach * grid) + 1
    check_memory(4.0 * cfg.nnum**2 * (k_min * sub) ** 2, f"the PSF bank ({cfg.nnum}² views of "
                 f">= {k_min}² px: rays reach {reach:.0f} px, max |∇W| {gmax:.0f} waves/radius)")
    _check_field_grid(cfg, *_grid(cfg, math.ceil(k_min / grid) | 1, os_), os_)  # at least
    if size is None:
        size = _default_size(cfg, z, depth, phase, amplitude, gmax, dev)
        if on_points:
            size = math.ceil(size * grid - 1e-9) | 1
    return size


def _default_size(cfg, z, depth, phase, amplitude, gmax, dev) -> int:
    """Smallest odd K whose window keeps >= 99.5 % of the light through the lenslets, from the
    widefield intensity (pixel sampling) convolved with one lenslet's aperture (the light a
    lenslet at displacement d collects), plus 2 px per side for the cross-talk."""
    from scipy.signal import fftconvolve

    p = cfg.pixel_pitch
    npix = 2 * math.ceil((_ray_reach(cfg, gmax) + 30.0 * cfg.wavelength / cfg.na) / p) + 1
    from metasensor.optics.widefield import _widefield_pixels

    pix, _ = _widefield_pixels(cfg, z, depth, phase, amplitude, p, npix, gmax, dev)
    c = cfg.nnum // 2
    t = (np.arange(cfg.nnum) - c) * p / (cfg.lenslet_diameter / 2)
    gx, gy = np.meshgrid(t, t, indexing="xy")
    if cfg.lenslet_aperture == "circular":
        ap = disk_fraction(gx, gy, 2 * p / cfg.lenslet_diameter)
    else:
        ap = ((np.abs(gx) <= 1) & (np.abs(gy) <= 1)).astype(float)
    energy = np.clip(fftconvolve(pix, ap, mode="same"), 0, None)
    k, _ = _window_size(energy, 1, npix)
    return k + 4


def _grid(cfg: SystemConfig, size: int, os_: int) -> tuple[int, int]:
    """(lenslets L per axis, samples n per axis) of the simulation grid for a K = size window:
    the lenslets whose pixels reach the window plus one margin lenslet per side (cross-talk; the
    wrap-around of the periodic grid lands in the margin), and n >= mla_focal·λ/dx²; L is
    rounded up to an 11-smooth odd number (fast FFT sizes)."""
    nnum = cfg.nnum
    dx = cfg.pixel_pitch / os_
    lenslets = 2 * ((size // 2 + nnum // 2) // nnum + 1) + 1
    need = cfg.mla_focal * cfg.wavelength / dx**2  # angular-spectrum sampling: z <= N dx² / λ
    if lenslets * nnum * os_ < need:  # the smallest odd count that meets it
        lenslets += 2 * max(0, math.ceil((need / (nnum * os_) - lenslets) / 2) - 1)
        while lenslets * nnum * os_ < need:
            lenslets += 2
    lenslets = next_fast_odd(lenslets)  # 11-smooth: fast FFT sizes
    return lenslets, lenslets * nnum * os_


def _check_field_grid(cfg: SystemConfig, lenslets: int, n: int, os_: int) -> None:
    """MemoryError (one line) when the ``n × n`` field grid and the arrays of its size (field,
    transfer function, lenslet phase, a batch) would not fit."""
    check_memory(8.0 * 6 * n**2, f"the field grid ({n}² samples: {lenslets} lenslets of "
                 f"{cfg.nnum * os_} samples, for mla_focal·λ/dx² = "
                 f"{cfg.mla_focal * cfg.wavelength / (cfg.pixel_pitch / os_) ** 2:.3g})")


def __getattr__(name: str):
    """``widefield_psf`` lives in :mod:`metasensor.optics.widefield`; importing it from here
    still works."""
    if name == "widefield_psf":
        from metasensor.optics.widefield import widefield_psf

        return widefield_psf
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
