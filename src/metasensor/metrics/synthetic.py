"""Synthetic test targets with known MTF: slanted edges and slanted-square charts.

Edges are rendered analytically, not on the grid the MTF algorithm assumes: the irradiance of a
blurred straight edge, integrated over each square pixel, is

    E(d) = 1/2 + integral_0^inf T(f) P(f) sin(2 pi f d) / (pi f) df,

with d the signed distance of the pixel centre from the edge (pixels, along the edge normal),
T the optical MTF of a rotationally symmetric PSF and P(f) = sinc(f cos t) sinc(f sin t) the
transfer of a square pixel along the normal at edge tilt t. The integral is evaluated by
composite Gauss-Legendre quadrature, one 16-point panel per period of the oscillation at the
largest |d|, on a fine grid of d, then interpolated (cubic spline).
Hence the reference MTF of such an edge is exactly ``T(f) * P(f)`` (:func:`edge_reference_mtf`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from scipy.special import ndtr

__all__ = ["gaussian_mtf", "airy_mtf", "pixel_mtf", "edge_reference_mtf", "render_edge",
           "render_gaussian_edge_supersampled", "add_noise", "render_square_chart"]


def gaussian_mtf(sigma: float) -> Callable[[np.ndarray], np.ndarray]:
    """MTF of a Gaussian PSF of standard deviation ``sigma`` pixels: exp(-2 pi^2 sigma^2 f^2)."""
    return lambda f: np.exp(-2.0 * np.pi**2 * sigma**2 * np.asarray(f, float) ** 2)


def airy_mtf(cutoff: float) -> Callable[[np.ndarray], np.ndarray]:
    """Diffraction MTF of a circular pupil, cutoff ``cutoff`` cycles/pixel (= 2 NA / lambda).

    (2/pi) (acos(nu) - nu sqrt(1 - nu^2)), nu = f / cutoff, zero beyond the cutoff.
    """
    def t(f):
        nu = np.clip(np.abs(np.asarray(f, float)) / cutoff, 0.0, 1.0)
        return (2 / np.pi) * (np.arccos(nu) - nu * np.sqrt(1 - nu**2))
    return t


def pixel_mtf(f, angle_deg: float) -> np.ndarray:
    """Transfer of a unit square pixel along a direction tilted ``angle_deg`` from an axis."""
    t = math.radians(angle_deg)
    f = np.asarray(f, float)
    return np.sinc(f * math.cos(t)) * np.sinc(f * math.sin(t))


def edge_reference_mtf(f, transfer: Callable, angle_deg: float, pixel: bool = True):
    """Analytic MTF of a rendered edge: ``|T(f) P(f)|`` (P = 1 when ``pixel`` is False)."""
    out = np.asarray(transfer(f), float)
    if pixel:
        out = out * pixel_mtf(f, angle_deg)
    return np.abs(out)


def _edge_profile(d: np.ndarray, transfer: Callable, angle_deg: float, fmax: float,
                  pixel: bool) -> np.ndarray:
    """E(d) for distances d (pixels): composite 16-point Gauss-Legendre over [0, fmax] (one panel
    per period of sin(2 pi f d) at the largest |d|: exact for polynomials of degree 31 each),
    evaluated on a 1/64-pixel grid of d and interpolated by a cubic spline (E is smooth)."""
    from scipy.interpolate import CubicSpline

    dlo, dhi = float(d.min()) - 1.0, float(d.max()) + 1.0
    panels = int(fmax * max(abs(dlo), abs(dhi))) + 16
    x, w = np.polynomial.legendre.leggauss(16)
    edges = np.linspace(0.0, fmax, panels + 1)
    h = np.diff(edges)[:, None] / 2
    f = ((edges[:-1, None] + h) + h * x[None, :]).ravel()
    g = edge_reference_mtf(f, transfer, angle_deg, pixel) * (h * w[None, :]).ravel() / (np.pi * f)
    grid = np.linspace(dlo, dhi, int((dhi - dlo) * 64) + 2)
    vals = np.empty(grid.size)
    step = max(1, 2_000_000 // f.size)
    for i in range(0, grid.size, step):
        vals[i:i + step] = np.sin(2 * np.pi * np.outer(grid[i:i + step], f)) @ g
    return 0.5 + CubicSpline(grid, vals)(d)


def _distances(shape, angle_deg, centre, horizontal):
    ny, nx = shape
    t = math.radians(angle_deg)
    yy, xx = np.mgrid[0:ny, 0:nx].astype(float)
    cy, cx = ((ny - 1) / 2, (nx - 1) / 2) if centre is None else centre
    if horizontal:  # edge along x, tilted by t: normal points to +y
        return (yy - cy) * math.cos(t) - (xx - cx) * math.sin(t)
    return (xx - cx) * math.cos(t) - (yy - cy) * math.sin(t)


def render_edge(shape: tuple[int, int], angle_deg: float, transfer: Callable, *,
                fmax: float, low: float = 0.1, high: float = 0.9,
                centre: tuple[float, float] | None = None, horizontal: bool = False,
                pixel: bool = True) -> np.ndarray:
    """Blurred slanted edge, exactly integrated over square pixels (float64 ``shape``).

    angle_deg: tilt of the edge from the vertical (or from the horizontal if ``horizontal``);
    transfer: optical MTF, a function of cycles/pixel, negligible above ``fmax``;
    low/high: levels on the two sides (``high`` on the +x side; swap them for the other polarity);
    centre: (row, col) a point on the edge (default: image centre).
    """
    d = _distances(shape, angle_deg, centre, horizontal)
    return low + (high - low) * _edge_profile(d, transfer, angle_deg, fmax, pixel)


def render_gaussian_edge_supersampled(shape, angle_deg, sigma, *, factor: int = 16,
                                      low=0.1, high=0.9, centre=None) -> np.ndarray:
    """Independent check of :func:`render_edge`: Gaussian-blurred edge Phi(d / sigma) sampled
    on a ``factor`` x finer grid and averaged over each pixel (midpoint rule)."""
    ny, nx = shape
    t = math.radians(angle_deg)
    cy, cx = ((ny - 1) / 2, (nx - 1) / 2) if centre is None else centre
    sub = (np.arange(factor) + 0.5) / factor - 0.5
    yy = (np.arange(ny)[:, None] + sub[None, :]).ravel()
    xx = (np.arange(nx)[:, None] + sub[None, :]).ravel()
    d = (xx[None, :] - cx) * math.cos(t) - (yy[:, None] - cy) * math.sin(t)
    fine = ndtr(d / sigma)
    img = fine.reshape(ny, factor, nx, factor).mean(axis=(1, 3))
    return low + (high - low) * img


def add_noise(clean: np.ndarray, snr_db: float, seed: int = 0) -> np.ndarray:
    """Add white Gaussian noise so that 10 log10(sum clean^2 / sum noise^2) = ``snr_db``."""
    clean = np.asarray(clean, float)
    sigma = math.sqrt(float(np.mean(clean**2)) / 10 ** (snr_db / 10))
    return clean + np.random.default_rng(seed).normal(0.0, sigma, clean.shape)


def render_square_chart(size: int, *, n: int = 4, angle_deg: float = 5.0,
                        sigma: float | Callable[[float], float] = 1.0, factor: int = 8,
                        low: float = 0.2, high: float = 0.8,
                        fill: float = 0.45) -> tuple[np.ndarray, list[dict]]:
    """Chart of ``n x n`` dark squares (rotated ``angle_deg``) on a bright ground, Gaussian blur.

    Each square sits in its own tile of ``size // n`` pixels, is drawn on a ``factor`` x finer
    grid, blurred by a Gaussian of ``sigma`` pixels (a number, or a function of the normalised
    field radius r in [0, 1] of the tile centre, r = distance / half-diagonal) and averaged over
    pixels. Returns (image float64 (size, size), list of {"centre": (y, x), "sigma": s}).
    """
    from scipy.ndimage import gaussian_filter

    tile = size // n
    img = np.full((size, size), high, float)
    info = []
    half_diag = math.hypot(size / 2, size / 2)
    t = math.radians(angle_deg)
    side = fill * tile
    sub = (np.arange(tile * factor) + 0.5) / factor
    yy, xx = np.meshgrid(sub, sub, indexing="ij")
    u = (xx - tile / 2) * math.cos(t) + (yy - tile / 2) * math.sin(t)
    v = -(xx - tile / 2) * math.sin(t) + (yy - tile / 2) * math.cos(t)
    inside = (np.abs(u) <= side / 2) & (np.abs(v) <= side / 2)
    fine0 = np.where(inside, low, high)
    for i in range(n):
        for j in range(n):
            cy, cx = (i + 0.5) * tile - 0.5, (j + 0.5) * tile - 0.5
            r = math.hypot(cy - (size - 1) / 2, cx - (size - 1) / 2) / half_diag
            s = float(sigma(r)) if callable(sigma) else float(sigma)
            fine = gaussian_filter(fine0, s * factor, mode="nearest")
            block = fine.reshape(tile, factor, tile, factor).mean(axis=(1, 3))
            img[i * tile:(i + 1) * tile, j * tile:(j + 1) * tile] = block
            info.append({"centre": (cy, cx), "sigma": s, "radius": r})
    return img, info
