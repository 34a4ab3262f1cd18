"""View shifts → pupil phase gradients → Zernike coefficients (the DAO wavefront sensor).

Geometry (docs/conventions.md): view (u, v) sees the pupil point
``rho_uv = −((v − c), (u − c)) / cfg.pupil_radius_px``; a wavefront W (waves) displaces that
view's image by ``(λ/NA) ∇_rho W(rho_uv)`` metres, i.e. ``k ∇W`` image pixels with
``k = (λ/NA) / pixel_pitch`` (x from d/drho_x, y from d/drho_y). Each view integrates the pupil
over its footprint, a square of side ``1/pupil_radius_px`` around ``rho_uv`` (one sensor pixel
behind the lenslet) clipped to the pupil (and to the central obstruction), so the modelled shift
is ``k`` times the gradient *averaged over that footprint* (the centroid of the view's light in
geometric optics). This is a Shack–Hartmann sensor with one sub-aperture per view.

The fit (written here: a weighted linear least squares with outlier rejection) solves
``s_uv ≈ G_uv · z + t`` for the Noll coefficients z of modes 4–45 (by default) and a nuisance
common shift t (tip/tilt and the unknown position of the reference image), so shifts may be
given relative to any reference (the centre view, or the current model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metasensor.config import SystemConfig
from metasensor.optics.zernike import noll_indices

__all__ = ["shift_scale", "gradient_matrix", "fit_shifts", "predicted_shifts", "zernike_rms",
           "ShiftFit", "DAO_MODES"]

DAO_MODES = tuple(range(4, 46))


def shift_scale(cfg: SystemConfig) -> float:
    """Image pixels of view displacement per unit pupil gradient of W (waves): (λ/NA)/pitch."""
    return cfg.wavelength / cfg.na / cfg.grid_pitch



def gradient_matrix(cfg: SystemConfig, jmax: int = 45, subsample: int = 7,
                    obstruction: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Footprint-averaged Zernike gradients of every view, in image pixels per wave.

    Returns ``G (nnum, nnum, 2, jmax)`` float64 — ``G[u, v, 0, j-1]`` the y (row) and
    ``G[u, v, 1, j-1]`` the x (column) shift of view (u, v) per wave of Noll mode j — and the
    fraction ``f (nnum, nnum)`` of each view's footprint inside the pupil (0: a dark view).
    Footprints are sampled by ``subsample²`` points.
    """
    from metasensor.optics.zernike import zernike_gradients

    if subsample < 1:
        raise ValueError(f"subsample must be >= 1, got {subsample}")
    eps = cfg.obstruction if obstruction is None else float(obstruction)
    rho_x, rho_y = cfg.pupil_coords()
    step = 1.0 / cfg.pupil_radius_px
    off = ((np.arange(subsample) + 0.5) / subsample - 0.5) * step
    px = rho_x[:, :, None, None] + off[None, None, None, :]
    py = rho_y[:, :, None, None] + off[None, None, :, None]
    px, py = np.broadcast_arrays(px, py)
    r2 = px * px + py * py
    inside = (r2 <= 1.0) & (r2 >= eps * eps)
    grads = zernike_gradients(px, py, jmax=jmax)  # (jmax, 2, n, n, s, s)
    count = inside.sum(axis=(-2, -1))
    mean = (grads * inside).sum(axis=(-2, -1)) / np.maximum(count, 1)  # (jmax, 2, n, n)
    k = shift_scale(cfg)
    # (d/dx, d/dy) → (y, x) pixel shifts
    g = np.stack([mean[:, 1], mean[:, 0]], axis=1) * k
    return np.moveaxis(g, (0, 1), (-1, -2)), count / float(subsample * subsample)


@dataclass(frozen=True)
class ShiftFit:
    """Result of :func:`fit_shifts`: ``zernike (jmax,)`` waves (fitted modes only), ``tilt (2,)``
    common (y, x) shift in pixels, ``residual_rms`` pixels over the inliers, ``inliers`` mask
    ``(nnum, nnum)``, ``residuals (nnum, nnum, 2)`` pixels (NaN outside the used views)."""

    zernike: np.ndarray
    tilt: np.ndarray
    residual_rms: float
    inliers: np.ndarray
    residuals: np.ndarray


def fit_shifts(shifts, cfg: SystemConfig, mask=None, weights=None, modes=DAO_MODES,
               reject: float = 4.0, min_footprint: float = 0.5,
               matrix: tuple[np.ndarray, np.ndarray] | None = None) -> ShiftFit:
    """Least-squares Zernike coefficients from measured view shifts.

    Parameters
    ----------
    shifts : array_like
        ``(nnum, nnum, 2)`` (y, x) image pixels of each view (relative to any common reference).
    cfg : SystemConfig
    mask : array_like, optional
        ``(nnum, nnum)`` views to use (default ``cfg.view_mask()``); views whose footprint lies
        less than ``min_footprint`` inside the pupil are dropped.
    weights : array_like, optional
        ``(nnum, nnum)`` non-negative per-view weights (default 1).
    modes : iterable of int
        Noll indices fitted (default 4–45); a common (y, x) shift is always fitted too.
    reject : float
        Views whose residual exceeds ``reject`` × the robust (MAD) residual scale, and at least
        0.25 px, are dropped and the fit repeated (twice at most; 0 disables).
    min_footprint : float
        Smallest share of a view's footprint inside the pupil.
    matrix : tuple, optional
        :func:`gradient_matrix`'s result (its ``jmax`` sets the Noll vector's length; default
        ``gradient_matrix(cfg, max(45, max(modes)))``).

    Returns
    -------
    ShiftFit
    """
    s = np.asarray(shifts, dtype=np.float64)
    n = cfg.nnum
    if s.shape != (n, n, 2):
        raise ValueError(f"shifts must have shape ({n}, {n}, 2), got {s.shape}")
    jmax = matrix[0].shape[-1] if matrix is not None else max(45, *(int(j) for j in modes))
    idx = noll_indices(modes, jmax)
    use = cfg.view_mask() if mask is None else np.asarray(mask, dtype=bool)
    if use.shape != (n, n):
        raise ValueError(f"mask must have shape ({n}, {n}), got {use.shape}")
    wts = np.ones((n, n)) if weights is None else np.asarray(weights, dtype=np.float64)
    if wts.shape != (n, n) or (wts < 0).any() or not np.isfinite(wts).all():
        raise ValueError(f"weights must be ({n}, {n}), finite and non-negative")
    g, frac = gradient_matrix(cfg, jmax=jmax) if matrix is None else matrix
    use = use & (frac >= min_footprint) & np.isfinite(s).all(axis=-1) & (wts > 0)
    a_full = np.concatenate([g[..., idx - 1],
                             np.broadcast_to(np.eye(2), (n, n, 2, 2))], axis=-1)  # (n,n,2,M+2)
    inl = use.copy()
    for _ in range(3):
        if 2 * inl.sum() < idx.size + 2:
            raise ValueError(f"fit_shifts: {int(inl.sum())} views cannot fit {idx.size} modes")
        sw = np.sqrt(wts[inl])[:, None, None]
        a = (a_full[inl] * sw).reshape(-1, idx.size + 2)
        b = (s[inl] * sw[..., 0]).reshape(-1)
        coef, *_ = np.linalg.lstsq(a, b, rcond=None)
        res = s - a_full @ coef
        if reject <= 0:
            break
        mag = np.linalg.norm(res, axis=-1)
        scale = 1.4826 * np.median(mag[inl]) * 1.5 if inl.any() else 0.0
        new = use & (mag <= max(reject * scale, 0.25))
        if (new == inl).all():
            break
        inl = new
    z = np.zeros(jmax)
    z[idx - 1] = coef[: idx.size]
    res = np.where(inl[..., None], res, np.nan)
    rms = float(np.sqrt(np.nanmean(np.sum(res**2, axis=-1)))) if inl.any() else float("nan")
    return ShiftFit(zernike=z, tilt=coef[idx.size:], residual_rms=rms, inliers=inl, residuals=res)


def predicted_shifts(zernike, cfg: SystemConfig,
                     matrix: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Modelled (y, x) pixel shifts ``(nnum, nnum, 2)`` of every view for a Noll vector."""
    z = np.asarray(zernike, dtype=np.float64)
    if z.ndim != 1:
        raise ValueError(f"zernike must be a 1-D Noll vector, got shape {z.shape}")
    g, _ = gradient_matrix(cfg, jmax=max(z.size, 3)) if matrix is None else matrix
    return g[..., : z.size] @ z


def zernike_rms(zernike, modes=DAO_MODES) -> float:
    """r.m.s. (waves) over the pupil of the wavefront made of ``modes`` of a Noll vector (the
    modes are orthonormal, so this is the Euclidean norm of those coefficients)."""
    z = np.asarray(zernike, dtype=np.float64)
    idx = np.asarray([j for j in modes if j <= z.size], dtype=int)
    return float(np.sqrt(np.sum(z[idx - 1] ** 2))) if idx.size else 0.0
