"""What the telescope's turbulence truly does to the views: Kolmogorov theory of the wavefront's
modal variance, and the true motion of every view between the frames of a scan period.

- :func:`kolmogorov_residual`: Noll's residual variance after removing the first J Zernike
  modes of a Kolmogorov wavefront over a circular pupil, ``Δ_J (D/r0)^{5/3}`` rad² (Noll, JOSA
  66, 207 (1976), Table IV for J <= 21, his asymptotic ``0.2944 J^{−√3/2}`` beyond), and
  :func:`kolmogorov_mode_rms`, the r.m.s. (waves) that Noll modes ``first .. last`` carry. At
  D/r0 = 5 a frame's wavefront is 0.62 λ r.m.s. with piston removed, 87 % of whose variance is
  tip and tilt (image motion); Noll 4–45 carry 0.21 λ.
- :func:`view_motion`: every view sees the pupil through its own sub-aperture (view (u, v) at
  ``rho = −((v − c), (u − c)) / cfg.pupil_radius_px``, a square of side ``1 /
  cfg.pupil_radius_px``, docs/conventions.md), so its image moves with the sub-aperture's mean
  wavefront gradient: ``(λ / NA) ∇_rho W`` on the image plane (the convention's ray landing),
  in view pixels of ``cfg.mla_pitch / cfg.scan``. The motion of frame t is that shift minus the
  reference frame's: what a per-view motion correction has to find. The cell's mean gradient
  is the mean difference of the wavefront across the cell over its width (cubic-spline
  interpolation of the screen on the cell's edges; hand-written: a few lines).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["kolmogorov_residual", "kolmogorov_mode_rms", "view_motion"]

EDGE_POINTS = 8  # samples along each edge of a view's cell (cubic interpolation of the screen)

# Noll (1976), Table IV: residual variance Δ_J / (D/r0)^{5/3} rad² after removing modes 1..J
_NOLL_DELTA = (1.0299, 0.582, 0.134, 0.111, 0.0880, 0.0648, 0.0587, 0.0525, 0.0463, 0.0401,
               0.0377, 0.0352, 0.0328, 0.0304, 0.0279, 0.0267, 0.0255, 0.0243, 0.0232, 0.0220,
               0.0208)


def kolmogorov_residual(j: int) -> float:
    """Noll's ``Δ_J`` (rad² per (D/r0)^{5/3}): variance left after removing Noll modes 1..j
    (j >= 1) from a Kolmogorov wavefront over a circular pupil."""
    if not (isinstance(j, int | np.integer) and j >= 1):
        raise ValueError(f"j must be an integer >= 1, got {j!r}")
    if j <= len(_NOLL_DELTA):
        return _NOLL_DELTA[j - 1]
    return 0.2944 * j ** (-math.sqrt(3) / 2)


def kolmogorov_mode_rms(d_over_r0: float, first: int, last: int) -> float:
    """R.m.s. (waves) that Noll modes ``first .. last`` carry in a Kolmogorov wavefront of
    ``d_over_r0`` (first = 2: piston removed, all of the wavefront up to ``last``)."""
    if not (d_over_r0 > 0 and math.isfinite(d_over_r0)):
        raise ValueError(f"d_over_r0 must be positive, got {d_over_r0!r}")
    if not (isinstance(first, int) and isinstance(last, int) and 2 <= first <= last):
        raise ValueError(f"need integers 2 <= first <= last, got {first!r}, {last!r}")
    var = kolmogorov_residual(first - 1) - kolmogorov_residual(last)
    return math.sqrt(var * d_over_r0 ** (5 / 3)) / (2 * math.pi)


def view_motion(screens: np.ndarray, cfg, reference: int) -> np.ndarray:
    """True motion ``(T, nnum, nnum, 2)`` (dy, dx) in view pixels of every view in every frame
    relative to frame ``reference`` (module docstring).

    Parameters
    ----------
    screens : (T, s, s) wavefronts in waves over ``rho ∈ [−1, 1]²`` (the
        :mod:`metasensor.scenarios.screens` sampling).
    cfg : SystemConfig (wavelength, NA, lenslet pitch, scan, pupil radius in views).
    reference : frame index the motions are relative to.

    Returns
    -------
    numpy.ndarray
        float64; NaN for views whose sub-aperture lies outside the pupil (|rho| > 1).
    """
    scr = np.asarray(screens, dtype=np.float64)
    if scr.ndim != 3 or scr.shape[1] != scr.shape[2]:
        raise ValueError(f"screens must have shape (T, s, s), got {scr.shape}")
    if not 0 <= reference < scr.shape[0]:
        raise ValueError(f"reference {reference} outside 0 .. {scr.shape[0] - 1}")
    from scipy import ndimage

    s, n, c = scr.shape[-1], cfg.nnum, cfg.nnum // 2
    half = 0.5 / cfg.pupil_radius_px
    scale = cfg.wavelength / cfg.na / (cfg.mla_pitch / cfg.scan)
    edge = (np.arange(EDGE_POINTS) + 0.5) / EDGE_POINTS * 2 - 1  # along a cell edge, in half
    out = np.full((scr.shape[0], n, n, 2), np.nan)
    for t, screen in enumerate(scr):
        coef = ndimage.spline_filter(screen, order=3, mode="nearest")

        def wave(ry, rx, coef=coef):  # waves at pupil points (rho_y, rho_x)
            ry, rx = np.broadcast_arrays(np.asarray(ry, float), np.asarray(rx, float))
            ky, kx = (ry + 1.0) * s / 2 - 0.5, (rx + 1.0) * s / 2 - 0.5
            return ndimage.map_coordinates(coef, [ky, kx], order=3, mode="nearest",
                                           prefilter=False)

        for u in range(n):
            for v in range(n):
                ry, rx = -(u - c) / cfg.pupil_radius_px, -(v - c) / cfg.pupil_radius_px
                if rx * rx + ry * ry > 1.0:
                    continue
                # mean gradient over the cell = mean difference across it / its width
                along = edge * half
                gy = wave(ry + half, rx + along) - wave(ry - half, rx + along)
                gx = wave(ry + along, rx + half) - wave(ry + along, rx - half)
                out[t, u, v] = np.array([gy.mean(), gx.mean()]) / (2 * half) * scale
    return out - out[reference]
