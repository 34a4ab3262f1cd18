"""A single cheap lens (the paper's 3D-printed plastic singlet, f = 135 mm, f/10): field-dependent
aberrations from third-order (Seidel) theory of a thin lens with the stop at the lens.

Thin-lens Seidel sums (Welford, *Aberrations of Optical Systems*, §7.4; object at infinity,
conjugate variable C = −1, shape factor B = (c1 + c2)/(c1 − c2), power K = 1/f, marginal ray
height y = f / (2 N), Lagrange invariant H = y θ for the field angle θ = h / f of image height h):

    S_I   = y⁴K³/4 · [(n/(n−1))² + (n+2)/(n(n−1)²) · (B + 2(n²−1)/(n+2) · C)² − n/(n+2) · C²]
    S_II  = −y²K²H/2 · [(n+1)/(n(n−1)) · B + (2n+1)/n · C]
    S_III = H² K,   S_IV = H² K / n

Wavefront coefficients W040 = S_I/8, W131 = S_II/2, W222 = S_III/2, W220 = S_IV/4 (metres;
Wyant & Creath), converted to r.m.s.-normalised Noll coefficients in waves for a field point at
azimuth φ:  Z4 (field curvature + the focus part of astigmatism) = (W220 + W222/2)/(2√3);
Z5, Z6 (astigmatism) = W222/(2√6) · (sin 2φ, cos 2φ); Z7, Z8 (coma) = W131/(3√8) · (sin φ, cos φ);
Z11 (spherical) = W040/(6√5). The defocus part of spherical aberration and the tilt parts of coma
are dropped (focus set on axis; image positions at the PSF centroids, i.e. no distortion).
So astigmatism and field curvature grow as r², coma as r, with r the field radius. The optical
axis is the scene centre; image heights use the scene's physical size (``cfg.pixel_pitch``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SingleLens"]


@dataclass(frozen=True)
class SingleLens:
    """Thin singlet: focal length [m], f-number, refractive index, shape factor B (1: plano-convex,
    curved side to the object), ``strength`` scales all aberrations (1 = the Seidel values)."""

    focal_length: float = 0.135
    f_number: float = 10.0
    index: float = 1.49
    shape_factor: float = 1.0
    strength: float = 1.0

    def __post_init__(self) -> None:
        for name in ("focal_length", "f_number", "strength"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be positive, got {v!r}")
        if not self.index > 1:
            raise ValueError(f"index must exceed 1, got {self.index!r}")

    def seidel(self, field_angle) -> dict[str, np.ndarray]:
        """Wavefront coefficients W040, W131, W222, W220 [m] at field angles [rad]."""
        n, b, c = self.index, self.shape_factor, -1.0
        k = 1.0 / self.focal_length
        y = self.focal_length / (2.0 * self.f_number)
        h = y * np.asarray(field_angle, dtype=np.float64)
        s1 = y**4 * k**3 / 4 * ((n / (n - 1)) ** 2 + (n + 2) / (n * (n - 1) ** 2)
                                * (b + 2 * (n * n - 1) / (n + 2) * c) ** 2 - n / (n + 2) * c * c)
        s2 = -(y * y * k * k * h / 2) * ((n + 1) / (n * (n - 1)) * b + (2 * n + 1) / n * c)
        s3 = h * h * k
        s4 = h * h * k / n
        return {"W040": np.full_like(h, s1 / 8), "W131": s2 / 2, "W222": s3 / 2, "W220": s4 / 4}

    def config(self, cfg):
        """``cfg`` with the image-side NA of this lens, 1 / (2 N)."""
        return cfg.replace(na=1.0 / (2.0 * self.f_number))

    def field_zernike(self, cfg, shape: tuple[int, int]):
        """Callable ``f(yn, xn) -> (..., 11)`` Noll vectors [waves] over normalised field
        coordinates of a scene of ``shape`` at ``cfg.pixel_pitch``, at ``cfg.wavelength``."""
        h, w = shape
        half_y, half_x = h * cfg.pixel_pitch / 2.0, w * cfg.pixel_pitch / 2.0
        lam = cfg.wavelength
        strength = self.strength

        def zern(yn, xn):
            yn, xn = np.broadcast_arrays(np.asarray(yn, float), np.asarray(xn, float))
            py, px = yn * half_y, xn * half_x
            theta = np.hypot(py, px) / self.focal_length
            phi = np.arctan2(py, px)
            s = self.seidel(theta)
            out = np.zeros((*yn.shape, 11))
            out[..., 3] = (s["W220"] + s["W222"] / 2) / (2 * math.sqrt(3))
            out[..., 4] = s["W222"] * np.sin(2 * phi) / (2 * math.sqrt(6))
            out[..., 5] = s["W222"] * np.cos(2 * phi) / (2 * math.sqrt(6))
            out[..., 6] = s["W131"] * np.sin(phi) / (3 * math.sqrt(8))
            out[..., 7] = s["W131"] * np.cos(phi) / (3 * math.sqrt(8))
            out[..., 10] = s["W040"] / (6 * math.sqrt(5))
            return out * strength / lam

        return zern
