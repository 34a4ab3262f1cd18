"""Significance of a motion hypothesis in the dense view domain (leave-one-out test).

A flow estimated between two scan-phase sub-images (sampled every ``p`` view pixels) is
biased wherever the sub-images alias: a static scene then yields a *pseudo-flow* about as large
as the turbulence it is meant to find, and the warping residual between the two sub-images
(:func:`.flow.motion_confidence`, the quantity the registration minimises) cannot tell the two
apart.

The dense view itself is sampled finely enough to resolve the scene: there the question
becomes whether the moved samples agree with their neighbours from *other* frames. Every
sample is predicted from the samples around it (Gaussian kernel regression, itself left out)
once at the grid positions (static hypothesis) and once at the moved positions ``P + M``
(motion hypothesis). A pseudo-flow scatters a static scene's samples and raises that error;
a true flow gathers a moving scene's samples and lowers it.

The test assumes the dense view is smooth at the kernel's scale. Where the sub-images do not
resolve the content at all (a star's view is a disk about one lenslet, ``p`` view px, wide: one
sample per sub-image) no flow means anything. :func:`resolved_fraction` measures how much of the
local contrast the sub-images resolve (the view low-passed at their scale against the view
itself); below :data:`RESOLVED_MIN` a sample gives no evidence. The measurements behind this
design are in ``docs/decisions.md`` (2026-11-25, motion evidence). Hand-written.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["loo_error", "dense_confidence", "resolved_fraction", "RESOLVED_MIN"]

# below this resolved fraction a sample gives no evidence of motion (module docstring: star
# grids read at most 0.12, charts and natural views 0.22 or more at their 10th percentile)
RESOLVED_MIN = 0.15


def loo_error(view: np.ndarray, motion: np.ndarray, sigma: float = 0.8,
              radius: float = 2.0) -> np.ndarray:
    """Leave-one-out prediction error ``(H, W)`` (squared) of every sample of ``view``
    ``(H, W)`` placed at ``(y, x) + motion`` (``(2, H, W)``, view px): the sample minus the
    Gaussian-weighted (``sigma``) mean of the other samples within ``radius`` view px. A sample
    with no neighbour gets NaN."""
    from scipy.spatial import cKDTree

    h, w = view.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    pts = np.column_stack([(yy + motion[0]).ravel(), (xx + motion[1]).ravel()])
    vals = np.asarray(view, np.float64).ravel()
    pairs = cKDTree(pts).query_pairs(radius, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    wt = np.exp(-((pts[i] - pts[j]) ** 2).sum(axis=1) / (2 * sigma ** 2))
    n = len(vals)
    num = np.bincount(i, wt * vals[j], n) + np.bincount(j, wt * vals[i], n)
    den = np.bincount(i, wt, n) + np.bincount(j, wt, n)
    with np.errstate(invalid="ignore", divide="ignore"):
        err = (vals - num / den) ** 2
    return err.reshape(h, w)


def resolved_fraction(view: np.ndarray, period: int) -> np.ndarray:
    """Fraction ``(H, W)`` of the view's local contrast energy that sub-images sampled every
    ``period`` view px resolve: local energy of the view low-passed at their scale (Gaussian
    sigma ``period / 2``) about the local mean, over that of the view itself (windows: Gaussian
    sigma ``2 · period``). 1 for content far coarser than the sub-image grid, about
    ``1 / (π · period²)`` for white noise, small for point sources."""
    v = np.asarray(view, np.float64)
    v = v - v.mean()  # a flat view's energies are rounding error: keep them at its level, 0
    tiny = max((1e-6 * float(np.ptp(v))) ** 2, 1e-30)
    w = 2.0 * period
    mean = ndimage.gaussian_filter(v, w)
    low = ndimage.gaussian_filter(v, period / 2.0)
    e_all = ndimage.gaussian_filter((v - mean) ** 2, w)
    e_low = ndimage.gaussian_filter((low - mean) ** 2, w)
    return (e_low / np.maximum(e_all, tiny)).astype(np.float32)


FLOOR_FRAC = 0.01  # error floor: (this x the view's 0.5-99.5 % range)², see dense_confidence


def dense_confidence(view: np.ndarray, order: list[tuple[int, int]], motion: np.ndarray,
                     window: float = 2.0, floor_frac: float = FLOOR_FRAC,
                     resolved_min: float = RESOLVED_MIN,
                     resolved: np.ndarray | None = None) -> np.ndarray:
    """Per-frame ratio ``(T, h, w)`` of the local leave-one-out error (:func:`loo_error`) of the
    motion hypothesis ``motion`` (dense ``(2, H, W)`` view px) to that of the static one,
    each frame on its own sub-image grid (as :func:`.flow.sub_images`), errors averaged over
    a Gaussian ``window`` (sub-image px). < 1: the motion makes the dense view more
    consistent. Samples that the motion isolates count with their static error. Where the
    static error is below the floor ``(floor_frac · range)²``, or the motion lowers it by less
    than that, there is no evidence of motion: ratio 1 (a flat background has zero error both
    ways, not a ratio of 0). Where the sub-images do not
    resolve the content (:func:`resolved_fraction` below ``resolved_min``: point sources, noise
    on a flat background) there is no evidence either: ratio 1. ``resolved``: that fraction
    when the caller already has it (else computed here)."""
    p = int(round(len(order) ** 0.5))
    motion = np.nan_to_num(np.asarray(motion, np.float64))
    e0 = loo_error(view, np.zeros_like(motion))
    e1 = loo_error(view, motion)
    e0 = np.nan_to_num(e0)
    e1 = np.where(np.isnan(e1), e0, e1)
    lo, hi = np.percentile(view, [0.5, 99.5])
    floor = max(float(floor_frac * (hi - lo)) ** 2, 1e-30)
    h, w = view.shape[0] // p, view.shape[1] // p
    if resolved is None:
        resolved = resolved_fraction(view, p)
    unresolved = resolved < resolved_min
    ratio = np.ones((len(order), h, w), np.float32)
    for t, (r, c) in enumerate(order):
        a = ndimage.gaussian_filter(e1[r::p, c::p][:h, :w], window)
        b = ndimage.gaussian_filter(e0[r::p, c::p][:h, :w], window)
        weak = (b <= floor) | ((a < b) & (b - a <= floor))  # no evidence either way
        weak |= unresolved[r::p, c::p][:h, :w]
        ratio[t] = np.where(weak, 1.0, a / np.maximum(b, floor))
    return ratio
