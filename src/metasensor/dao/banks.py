"""PSF banks for DAO and for the blocks it corrects: the window they need, and how they are made.

The window (:func:`psf_window`) follows the geometric ray reach of a wavefront over the used
views (conventions.md: a wavefront W displaces view (u, v) by ``(λ/NA) ∇W`` at its pupil point);
banks are ``view_psfs`` of the estimated pupil (wave optics) or the aberration-free bank
translated by measured view shifts (:func:`geometric_psfs`; the paper's geometric DAO).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from metasensor.backend import resolve_device, to_numpy
from metasensor.config import SystemConfig

__all__ = ["ray_reach_px", "psf_window", "psf_bank", "geometric_psfs", "block_psfs"]


def ray_reach_px(cfg: SystemConfig, zernike, mask=None, subsample: int = 5) -> float:
    """Largest geometric ray displacement (image pixels), ``k |∇W|`` with k = (λ/NA)/pitch, over
    the pupil footprints of the views in ``mask`` (default ``cfg.view_mask()``; each footprint a
    square of side 1/pupil_radius_px around the view's pupil point, sampled by ``subsample²``
    points, clipped to the pupil). Tip and tilt included. 0 for None / a zero vector."""
    from metasensor.dao.wavefront import shift_scale
    from metasensor.optics.zernike import zernike_gradients

    if zernike is None:
        return 0.0
    z = np.asarray(zernike, dtype=np.float64).ravel()
    if not np.isfinite(z).all():
        raise ValueError("zernike contains NaN or infinite values")
    if not np.any(z):
        return 0.0
    m = cfg.view_mask() if mask is None else np.asarray(mask, dtype=bool)
    rho_x, rho_y = cfg.pupil_coords()
    off = ((np.arange(subsample) + 0.5) / subsample - 0.5) / cfg.pupil_radius_px
    px = (rho_x[m][:, None, None] + off[None, None, :]).repeat(subsample, axis=1)
    py = (rho_y[m][:, None, None] + off[None, :, None]).repeat(subsample, axis=2)
    inside = px * px + py * py <= 1.0
    g = np.tensordot(z, zernike_gradients(px[inside], py[inside], jmax=max(z.size, 3))[:z.size],
                     axes=(0, 0))  # (2, P) waves per unit rho
    return float(shift_scale(cfg) * np.sqrt((g**2).sum(axis=0)).max()) if g.size else 0.0


def psf_window(cfg: SystemConfig, zernike=None, mask=None, margin: float | None = None) -> int:
    """Odd PSF window K (pixels) for DAO and ISA banks of the views in ``mask``:
    ``2·ceil(reach + margin) + 1``, reach = :func:`ray_reach_px`, margin (pixels; default one
    lenslet, ``nnum``, plus 10 λ/NA of sub-aperture diffraction). Much smaller than
    ``view_psfs``' default window (99.5 % of the light of *all* views, sized by the ray reach at
    the pupil rim, where high-order Zernike gradients peak), which the dark outer views need but
    the used ones do not; the light it drops is measured in ``tests/dao/test_dao.py``."""
    from metasensor.dao.wavefront import shift_scale

    if margin is None:
        margin = cfg.nnum + 10.0 * shift_scale(cfg)
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"margin must be a non-negative number of pixels, got {margin!r}")
    return 2 * int(math.ceil(ray_reach_px(cfg, zernike, mask) + margin)) + 1


def psf_bank(cfg: SystemConfig, zernike=None, amplitude=None, device=None,
             size: int | None = None, cache: bool = True) -> np.ndarray:
    """``view_psfs(cfg, zernike, amplitude=, size=, cache=)`` on ``device``: the bank of a pupil
    phase (Noll vector, waves) and amplitude ``(nnum, nnum)``; ``size`` None: ``view_psfs``'
    default window. ``cache=False`` for one-off banks (DAO's intermediate estimates)."""
    from metasensor.optics.psf import view_psfs

    kw = {"cache": bool(cache)}
    if amplitude is not None:
        kw["amplitude"] = amplitude
    if size is not None:
        kw["size"] = int(size)
    return view_psfs(cfg, zernike=zernike, device=device, **kw)


def geometric_psfs(ideal: np.ndarray, shifts: np.ndarray, device=None) -> np.ndarray:
    """Aberration-free PSFs ``(n, n, K, K)`` translated by ``shifts (n, n, 2)`` pixels (y, x)
    (Fourier shift, after padding K to hold the largest shift; every view keeps its energy;
    :func:`metasensor.dao.bank_registration.translate_psfs`) → ``(n, n, K', K')``, K' odd,
    float32 NumPy (computed on ``device``)."""
    from metasensor.dao.bank_registration import translate_psfs

    h = np.asarray(ideal, dtype=np.float32)
    s = np.asarray(shifts, dtype=np.float64)
    n, _, k, _ = h.shape
    if s.shape != (n, n, 2):
        raise ValueError(f"shifts must have shape ({n}, {n}, 2), got {s.shape}")
    dev = resolve_device(device)
    out = translate_psfs(torch.tensor(h.reshape(n * n, k, k), device=dev),
                         torch.tensor(s.reshape(n * n, 2), device=dev))
    return to_numpy(out).reshape(n, n, *out.shape[-2:]).astype(np.float32)


def block_psfs(cfg: SystemConfig, result, amplitude=None, device=None,
               size: int | None = None) -> np.ndarray:
    """The PSF bank ``(nnum, nnum, K, K)`` to reconstruct a block with after DAO.

    Parameters
    ----------
    cfg : SystemConfig
    result : DaoResult
        :func:`metasensor.dao.estimate.run_dao`'s result.
    amplitude : array_like, optional
        ``(nnum, nnum)`` pupil amplitude.
    device : str, optional
    size : int, optional
        Window K; default ``result.psf_size``.

    Returns
    -------
    numpy.ndarray
        wave: ``view_psfs`` of the estimate; geometric: the ideal bank translated by the
        estimated view shifts (never reshaped). Cached (a block's bank is reused).
    """
    size = result.psf_size if size is None else size
    if result.method == "geometric":
        return geometric_psfs(psf_bank(cfg, None, amplitude, device, size), result.shifts,
                              device)
    return psf_bank(cfg, result.zernike, amplitude, device, size)
