"""Main-lens pupil functions: grids, amplitude (circle, annulus, a given map) and phase (waves).

Normalised pupil coordinates ``rho = (rho_x, rho_y)`` with ``|rho| = 1`` at the image-side NA
(docs/conventions.md). The pupil is sampled on the centred frequency grid of an FFT of odd size
``n``: sample ``k`` sits at ``rho = (k - n // 2) / radius`` where ``radius`` is the pupil radius
in samples, so the grid is symmetric about rho = 0. Amplitudes are returned as float64 arrays
(amplitude, not intensity: the pupil intensity is ``A**2``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from metasensor.config import SystemConfig
from metasensor.optics.zernike import wavefront

__all__ = [
    "pupil_grid",
    "disk_fraction",
    "pupil_amplitude",
    "aplanatic_amplitude",
    "defocus_waves",
    "pupil_phase",
    "view_to_pupil_map",
]

PupilFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def pupil_grid(n: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Centred normalised pupil coordinates (rho_x, rho_y), each (n, n) float64.

    ``n`` odd; ``radius`` = pupil radius in samples. rho_x varies along columns, rho_y along rows.
    """
    if n < 1 or n % 2 == 0:
        raise ValueError(f"pupil grid size must be odd and positive, got {n}")
    if not radius > 0:
        raise ValueError(f"pupil radius in samples must be positive, got {radius}")
    k = (np.arange(n) - n // 2) / float(radius)
    return np.meshgrid(k, k, indexing="xy")


def disk_fraction(rho_x, rho_y, step: float, outer: float = 1.0, inner: float = 0.0,
                  supersample: int = 8) -> np.ndarray:
    """Area fraction of each sample cell (side ``step`` in rho units) inside the annulus
    ``inner <= |rho| <= outer`` (supersampled ``supersample``² points per cell)."""
    q = (np.arange(supersample) + 0.5) / supersample - 0.5
    frac = np.zeros(np.shape(rho_x))
    r_out2, r_in2 = outer**2, inner**2
    # only cells near the boundary need supersampling
    r = np.hypot(rho_x, rho_y)
    half_diag = step / np.sqrt(2.0)
    inside = (r + half_diag <= outer) & (r - half_diag >= inner)
    edge = ~inside & (r - half_diag <= outer) & (r + half_diag >= inner)
    frac[inside] = 1.0
    ex, ey = rho_x[edge], rho_y[edge]
    acc = np.zeros(ex.shape)
    for dy in q:
        for dx in q:
            r2 = (ex + dx * step) ** 2 + (ey + dy * step) ** 2
            acc += (r2 <= r_out2) & (r2 >= r_in2)
    frac[edge] = acc / supersample**2
    return frac


def view_to_pupil_map(cfg: SystemConfig, rho_x, rho_y) -> tuple[np.ndarray, np.ndarray]:
    """Indices (u, v) of the view nearest to each pupil point (clipped to the view grid).

    Inverse of conventions.md: view (u, v) sees ``rho = -((v - c), (u - c)) / pupil_radius_px``.
    """
    c = cfg.center
    r = cfg.pupil_radius_px
    u = np.clip(np.rint(c - np.asarray(rho_y) * r), 0, cfg.nnum - 1).astype(int)
    v = np.clip(np.rint(c - np.asarray(rho_x) * r), 0, cfg.nnum - 1).astype(int)
    return u, v


def aplanatic_amplitude(rho_x, rho_y, na_object: float) -> np.ndarray:
    """Pupil amplitude of an aplanatic lens collecting an isotropic point source.

    Model: a lens obeying the sine condition maps the ray at object-side angle θ to the pupil
    radius ``rho = sin θ / NA_o``; an isotropic source puts equal energy into equal solid
    angles, ``dΩ = sin θ dθ dφ ∝ rho drho dφ / cos θ``, so the energy per unit pupil area is
    proportional to ``1 / cos θ = (1 − NA_o² rho²)^(−1/2)`` and the amplitude to its square
    root (Richards & Wolf, Proc. R. Soc. A 253, 358 (1959); the ``sqrt(cos θ)`` factor of the
    Debye integral over θ in Broxton et al., Opt. Express 21, 25418 (2013), is the same law).
    The amplitude is scaled to unit mean intensity over the unit disk, whose exact mean of
    ``1 / cos θ`` is ``2 (1 − sqrt(1 − NA_o²)) / NA_o²``, so the pupil's total energy, and with
    it the photon normalisation of a PSF, is that of the uniform pupil.

    Parameters
    ----------
    rho_x, rho_y : array_like
        Normalised pupil coordinates (``|rho| = 1`` at the pupil edge).
    na_object : float
        Object-side numerical aperture ``NA_o`` in (0, 1) (the image-side NA times the
        magnification for a lens in air).

    Returns
    -------
    numpy.ndarray
        Amplitude (float64, same shape as ``rho_x``); values outside the disk are those of
        ``|rho| = 1`` clipped there (the caller's disk mask removes them).
    """
    if not 0.0 < float(na_object) < 1.0:
        raise ValueError(f"na_object must lie in (0, 1), got {na_object!r}")
    s2 = float(na_object) ** 2
    r2 = np.minimum(np.asarray(rho_x, dtype=np.float64) ** 2
                    + np.asarray(rho_y, dtype=np.float64) ** 2, 1.0)
    mean = 2.0 * (1.0 - math.sqrt(1.0 - s2)) / s2
    return (1.0 - s2 * r2) ** -0.25 / math.sqrt(mean)


def pupil_amplitude(cfg: SystemConfig, rho_x, rho_y, step: float,
                    amplitude: np.ndarray | PupilFn | None = None) -> np.ndarray:
    """Pupil amplitude on the grid (edge cells area-weighted over ``step``, the cell side in rho).

    - ``None``: clear circle, or the annulus ``cfg.obstruction <= |rho| <= 1``;
    - an ``(nnum, nnum)`` array in view coordinates (conventions.md view <-> pupil relation,
      nearest view), inside the NA circle;
    - a callable ``f(rho_x, rho_y) -> amplitude``, inside the NA circle.

    With ``cfg.apodization == "aplanatic"`` every case is multiplied by
    :func:`aplanatic_amplitude` at the object-side NA ``cfg.na * cfg.magnification``.

    Edge cells carry the fraction of their area inside the pupil (the box-filtered disk), so
    the pupil's sum (the field at the focus) equals its area exactly; its energy ``sum A**2``
    is then a little smaller (about 0.33 / radius relative): the far diffraction tail that the
    finite grid cannot hold.
    """
    apod = 1.0
    if cfg.apodization == "aplanatic":
        apod = aplanatic_amplitude(rho_x, rho_y, cfg.na * cfg.magnification)
    if amplitude is None:
        return apod * disk_fraction(rho_x, rho_y, step, inner=cfg.obstruction)
    disk = disk_fraction(rho_x, rho_y, step)
    if callable(amplitude):
        a = np.asarray(amplitude(rho_x, rho_y), dtype=np.float64)
        if a.shape != np.shape(rho_x):
            a = np.broadcast_to(a, np.shape(rho_x))
    else:
        amap = np.asarray(amplitude, dtype=np.float64)
        if amap.shape != (cfg.nnum, cfg.nnum):
            raise ValueError(
                f"amplitude map must have shape (nnum, nnum) = {(cfg.nnum, cfg.nnum)}, "
                f"got {amap.shape}"
            )
        u, v = view_to_pupil_map(cfg, rho_x, rho_y)
        a = amap[u, v]
    if not np.isfinite(a).all() or (a < 0).any():
        raise ValueError("amplitude must be finite and non-negative")
    return a * disk * apod


def defocus_waves(cfg: SystemConfig, rho_x, rho_y, depth: float) -> np.ndarray:
    """Defocus phase in waves, ``(depth / λ) (sqrt(1 − NA² |rho|²) − 1)`` (conventions.md).

    ``depth > 0``: the point is focused ``depth`` metres in front of the MLA (towards the lens).
    """
    if not np.isfinite(depth):
        raise ValueError(f"depth must be finite, got {depth!r}")
    r2 = np.asarray(rho_x) ** 2 + np.asarray(rho_y) ** 2
    arg = np.clip(1.0 - cfg.na**2 * r2, 0.0, None)
    return (depth / cfg.wavelength) * (np.sqrt(arg) - 1.0)


def pupil_phase(cfg: SystemConfig, rho_x, rho_y, zernike=None, depth: float = 0.0,
                phase: PupilFn | None = None) -> np.ndarray:
    """Wavefront in waves: Zernike sum + defocus for ``depth`` + ``phase(rho_x, rho_y)``."""
    w = defocus_waves(cfg, rho_x, rho_y, depth) if depth != 0 else np.zeros(np.shape(rho_x))
    if zernike is not None:
        w = w + wavefront(zernike, rho_x, rho_y)
    if phase is not None:
        extra = np.asarray(phase(rho_x, rho_y), dtype=np.float64)
        inside = (np.asarray(rho_x) ** 2 + np.asarray(rho_y) ** 2) <= 1.0
        if extra.shape != np.shape(rho_x):
            extra = np.broadcast_to(extra, np.shape(rho_x))
        if not np.isfinite(np.where(inside, extra, 0.0)).all():
            raise ValueError("phase callable returned NaN or infinite values inside the pupil")
        w = w + np.where(np.isfinite(extra), extra, 0.0)
    return w
