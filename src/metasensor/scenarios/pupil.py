"""The annular pupil of a Cassegrain telescope, estimated from the views.

The paper (Methods, "Initial global aberration estimation") binarises the views' angular
intensity to find the pupil's shape, a ring for a Cassegrain telescope
(:func:`metasensor.dao.pupil.estimate_pupil`). At the resolution of one view
(``nnum²`` views over the pupil) a binary map gives the central obstruction only to about one
view (≈ 0.13 of the radius for nnum = 15). :func:`estimate_annulus` fits the ratio instead: the
angular intensity of view (u, v) is modelled as the area fraction of its cell (side
``1 / pupil_radius_px`` in rho, centred on the view's pupil point, docs/conventions.md) inside
the annulus ``ε ≤ |rho| ≤ 1``, blurred by a Gaussian of ``σ`` views (the lenslet's diffraction
spreads every pupil point over neighbouring pixels), times a scale; ε and σ are found by a grid
search and the scale by linear least squares (hand-written: a two-parameter fit no library
offers in this form).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from metasensor.config import SystemConfig
from metasensor.dao.pupil import angular_intensity, estimate_pupil
from metasensor.optics.pupil import disk_fraction

__all__ = ["AnnulusEstimate", "estimate_annulus", "annulus_model"]


@dataclass(frozen=True)
class AnnulusEstimate:
    """obstruction : central obstruction ratio ε (inner / outer radius); blur : σ of the
    angular blur (views); residual : r.m.s. misfit of the normalised angular intensity;
    amplitude : (nnum, nnum) binary pupil map (``estimate_pupil``, threshold 0.5);
    intensity : (nnum, nnum) measured angular intensity (brightest view = 1)."""

    obstruction: float
    blur: float
    residual: float
    amplitude: np.ndarray
    intensity: np.ndarray


def annulus_model(cfg: SystemConfig, obstruction: float, blur: float = 0.0) -> np.ndarray:
    """(nnum, nnum) modelled angular intensity of an annular pupil (peak-free scale): the area
    fraction of every view's cell inside ``obstruction ≤ |rho| ≤ 1``, blurred by ``blur`` views."""
    n, c, r = cfg.nnum, cfg.center, cfg.pupil_radius_px
    k = np.arange(n, dtype=np.float64)
    rho_x = np.broadcast_to(-(k[None, :] - c) / r, (n, n))
    rho_y = np.broadcast_to(-(k[:, None] - c) / r, (n, n))
    frac = disk_fraction(rho_x, rho_y, 1.0 / r, inner=float(obstruction))
    if blur > 0:
        frac = ndimage.gaussian_filter(frac, blur, mode="constant")
    return frac


def estimate_annulus(views, cfg: SystemConfig, background: float = 0.0,
                     ratios: np.ndarray | None = None,
                     blurs: np.ndarray | None = None) -> AnnulusEstimate:
    """Central obstruction ratio of the pupil from the views (model in the module docstring).

    Parameters
    ----------
    views : (nnum, nnum, H, W) views of one block (any intensity scale).
    cfg : the system (nnum, pupil radius in views).
    background : dark level subtracted before normalising (detector counts).
    ratios, blurs : grids searched for ε (default 0 .. 0.9 in steps of 0.005) and σ (views;
        default 0 .. 1.5 in steps of 0.05).

    Returns
    -------
    AnnulusEstimate
    """
    a = angular_intensity(views, cfg, background).astype(np.float64)
    ratios = np.arange(0.0, 0.9001, 0.005) if ratios is None else np.asarray(ratios, float)
    blurs = np.arange(0.0, 1.5001, 0.05) if blurs is None else np.asarray(blurs, float)
    if ratios.size == 0 or blurs.size == 0 or (ratios < 0).any() or (ratios >= 1).any():
        raise ValueError("ratios must be a non-empty grid in [0, 1) and blurs non-empty")
    # the model is linear in the disks: annulus(ε) = disk(1) − disk(ε), then blurred
    outer = annulus_model(cfg, 0.0)
    inner = [outer - annulus_model(cfg, e) for e in ratios]
    best = (np.inf, 0.0, 0.0)
    for s in blurs:
        for e, disk in zip(ratios, inner, strict=True):
            m = outer - disk
            if s > 0:
                m = ndimage.gaussian_filter(m, s, mode="constant")
            mm = float((m * m).sum())
            if mm <= 0:
                continue
            scale = float((m * a).sum()) / mm
            err = float(((a - scale * m) ** 2).sum())
            if err < best[0]:
                best = (err, float(e), float(s))
    err, eps, sig = best
    return AnnulusEstimate(eps, sig, float(np.sqrt(err / a.size)),
                           estimate_pupil(views, cfg, 0.5), a.astype(np.float32))
