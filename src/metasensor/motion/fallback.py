"""Graceful fallback of motion correction: the reference scan frame alone where the flow fails.

Real movers (a walking person) move non-rigidly, occlude and uncover, blur within a frame and
change shading; an optical flow between the scan's sub-images is wrong on part of them, and a
sample moved to the wrong place is itself a scan artefact. The samples of the reference frame
are exact at the reference time: upsampled with a proper low-pass (cubic B-spline interpolation,
whose spectral images at the scan-lattice frequencies are suppressed) they give a picture
without scan artefact, at the resolution of one frame (``p`` times coarser; that loss is
honest). Where the flow-corrected image still shows the artefact, it is blended towards that
picture with a smooth weight (no seam); elsewhere, and everywhere outside the moving region, the
corrected image (static regions: the view itself) is kept.

Evidence of the artefact, not of texture: a scan artefact is a pattern that repeats in every
lenslet (samples of one frame displaced together against those of the others), so the high-pass
content of neighbouring lenslets agrees along *both* axes. :func:`lattice_coherence` is that
agreement, the local correlation of each lenslet's ``p × p`` pattern with its neighbours' along
rows and along columns (the smaller of the two): near 0 or below for a static scene's texture
(whose high-pass content has no reason to repeat from lenslet to lenslet; a straight static edge
repeats along one axis only), positive where a mover's samples are misplaced. The moving
region is the coherent lenslets connected to lenslets where the flow moved samples (motion
evidence from two sides); inside it the fallback weight rises with the coherence left in the
corrected image, and where the corrected image disagrees with the reference frame alone in the
band both resolve by more than the static scene's aliasing does (a sample moved to the wrong
place, occluded or uncovered at the reference time). The correction itself is the paper's
optical-flow motion correction (Wu et al., Nature 612, 62-71, 2022, Methods), :mod:`.correct`.

Hand-written: the test is specific to the scan's sample lattice. The B-spline prefilter is
scipy's (:func:`scipy.ndimage.spline_filter`); its separable evaluation at the ``p`` fixed
phases is done here with sparse matrices, so that 100 views cost little.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import ndimage, sparse

__all__ = ["FallbackOptions", "FallbackMap", "lattice_coherence", "reference_upsample",
           "fallback_map", "blend"]


@dataclass(frozen=True)
class FallbackOptions:
    """Settings of the fallback (coherence values are correlations, lengths in lenslets).

    region : lattice coherence of the realigned view above which a lenslet shows a scan
        artefact (the measurements behind the defaults: ``docs/decisions.md``, 2026-11-26).
    low, high : coherence left in the corrected image at which the fallback weight starts to
        rise (0) and is full (1); linear in between.
    window : Gaussian window (lenslets) over which neighbouring lenslets' patterns are compared.
    highpass : the pattern of a lenslet is the view minus its Gaussian blur of ``highpass · p``
        view px (content coarser than a lenslet does not count).
    flow_share : share of the frames whose flow must move a sample (>= 0.5 view px), locally,
        for a lenslet to count as moving (motion evidence besides the coherence); the moving
        region is every coherent lenslet connected to such lenslets (gaps of up to ``bridge``
        lenslets bridged), grown by ``margin`` lenslets.
    residual : the corrected image must also agree with the reference frame alone in the band
        both resolve: their difference, Gaussian-smoothed over ``residual_window`` lenslets,
        is compared with the same difference of the view far from the moving region (its
        ``residual_quantile`` percentile: the static scene's aliasing); from ``residual[0]``
        times that tolerance the fallback weight rises, reaching 1 at ``residual[1]`` times.
    warn_share : warn once when more than this share of the moving region fell back.
    """

    region: float = 0.3
    low: float = 0.0
    high: float = 0.15
    window: float = 1.5
    highpass: float = 0.6
    flow_share: float = 0.5
    bridge: int = 1
    margin: int = 1
    residual: tuple[float, float] = (1.0, 2.0)
    residual_window: float = 0.6
    residual_quantile: float = 99.0
    warn_share: float = 0.5

    def __post_init__(self):
        for name in ("region", "low", "high", "window", "highpass", "flow_share", "warn_share"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
        if not -1 < self.low < self.high <= 1:
            raise ValueError(f"need -1 < low < high <= 1, got low={self.low}, high={self.high}")
        if not 0 < self.region <= 1:
            raise ValueError(f"region must lie in (0, 1], got {self.region!r}")
        if self.window <= 0 or self.highpass <= 0:
            raise ValueError("window and highpass must be positive")
        if not (len(self.residual) == 2 and 0 < self.residual[0] < self.residual[1]):
            raise ValueError(f"residual must be two numbers 0 < a < b, got {self.residual!r}")
        if not (self.residual_window > 0 and 0 < self.residual_quantile <= 100):
            raise ValueError("residual_window must be positive and residual_quantile in (0, 100]")
        for name in ("bridge", "margin"):
            v = getattr(self, name)
            if not (isinstance(v, int) and 0 <= v <= 8):
                raise ValueError(f"{name} must be an integer in [0, 8], got {v!r}")
        if not (0 <= self.flow_share <= 1 and 0 <= self.warn_share <= 1):
            raise ValueError("flow_share and warn_share must lie in [0, 1]")


@dataclass(frozen=True)
class FallbackMap:
    """Where the correction fell back to the reference frame alone.

    weight : (H, W) float32 in [0, 1], share of the output taken from the reference frame
        alone (0 outside the moving region: those pixels are the corrected image).
    region : (H, W) float32 in [0, 1], the moving region (smooth gate).
    fraction : share of the moving region (``region > 0.5``) whose weight exceeds 0.5
        (0 when there is no moving region).
    """

    weight: np.ndarray
    region: np.ndarray
    fraction: float

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool, the low-confidence pixels (weight > 0.5)."""
        return self.weight > 0.5


def _lenslet_patterns(img: np.ndarray, p: int, highpass: float) -> np.ndarray:
    """High-pass content of every lenslet, mean removed: ``(p, p, H // p, W // p)``."""
    img = np.asarray(img, np.float64)
    hp = img - ndimage.gaussian_filter(img, highpass * p)
    h, w = img.shape[0] // p, img.shape[1] // p
    b = hp[:h * p, :w * p].reshape(h, p, w, p).transpose(1, 3, 0, 2)
    return b - b.mean(axis=(0, 1), keepdims=True)


def lattice_coherence(img: np.ndarray, period: int, window: float = 1.5,
                      highpass: float = 0.6) -> np.ndarray:
    """Scan-artefact evidence per lenslet (see the module docstring).

    Parameters
    ----------
    img : (H, W) realigned view [any intensity unit].
    period : scan period p (a lenslet is p × p view px).
    window : Gaussian window [lenslets] over which neighbouring patterns are compared.
    highpass : a lenslet's pattern is ``img`` minus its Gaussian blur of ``highpass · p`` px.

    Returns
    -------
    (H // p, W // p) float32 in [-1, 1]: the correlation of each lenslet's high-pass
    ``p × p`` pattern with its neighbours' along rows and along columns, the smaller of the
    two; near 0 or below without an artefact. The energy is floored at 5 % of the image's
    median, so flat lenslets give little evidence.
    """
    b = _lenslet_patterns(img, period, highpass)
    h, w = b.shape[2:]
    if h < 2 or w < 2:
        raise ValueError(f"image of shape {np.shape(img)} has fewer than 2 x 2 lenslets")
    cx = np.zeros((h, w))
    cy = np.zeros((h, w))
    px = (b[..., :, :-1] * b[..., :, 1:]).sum(axis=(0, 1))
    py = (b[..., :-1, :] * b[..., 1:, :]).sum(axis=(0, 1))
    cx[:, :-1] += px
    cx[:, 1:] += px
    cy[:-1] += py
    cy[1:] += py
    energy = 2.0 * (b ** 2).sum(axis=(0, 1))
    cx, cy, energy = (ndimage.gaussian_filter(a, window) for a in (cx, cy, energy))
    energy = np.maximum(energy, 0.05 * float(np.median(energy)) + 1e-30)
    return (np.minimum(cx, cy) / energy).astype(np.float32)


def _bspline_matrix(n_out: int, n_in: int, phase: int, p: int) -> sparse.csr_matrix:
    """Cubic B-spline evaluation at fine positions ``(i − phase) / p``, i < n_out, of a signal
    of n_in coefficients; indices outside mirrored as scipy's ``mode="mirror"``."""
    s = (np.arange(n_out) - phase) / p
    base = np.floor(s).astype(int)
    rows, cols, vals = [], [], []
    for k in range(-1, 3):
        j = base + k
        x = np.abs(s - j)
        wgt = np.where(x < 1, 2 / 3 - x ** 2 + x ** 3 / 2, np.where(x < 2, (2 - x) ** 3 / 6, 0.0))
        if n_in > 1:
            period = 2 * (n_in - 1)
            j = np.abs(j) % period
            j = np.where(j > n_in - 1, period - j, j)
        else:
            j = np.zeros_like(j)
        rows.append(np.arange(n_out))
        cols.append(j)
        vals.append(wgt)
    return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(n_out, n_in))


def reference_upsample(views: np.ndarray, period: int, phase: tuple[int, int],
                       rows: slice = slice(None), cols: slice = slice(None)) -> np.ndarray:
    """The samples of one scan phase interpolated onto the full view grid.

    Cubic B-spline interpolation (exact at the samples, band-limited between them; scipy's
    ``mode="mirror"`` at the borders) of ``view[r::p, c::p]``, whose sample (i, j) sits at view
    pixel ``(p·i + r, p·j + c)``. It equals ``scipy.ndimage.map_coordinates(order=3,
    mode="mirror")`` on that grid; the evaluation is hand-written as two sparse matrices (rows,
    columns) built once and applied to every view of the stack, because the grid is separable
    and the same for all views (timings: docs/decisions.md).

    Parameters
    ----------
    views : (H, W) or (N, H, W) realigned views.
    period : scan period p. phase : (r, c), the scan phase whose samples are kept.
    rows, cols : the window of the output to compute (default: all of it).

    Returns
    -------
    float32 array, ``views``' shape (or that of the window).
    """
    views = np.asarray(views, np.float32)
    single = views.ndim == 2
    stack = views[None] if single else views
    r, c = phase
    _, hgt, wid = stack.shape
    sub = stack[:, r::period, c::period].astype(np.float64)
    ys = np.arange(hgt)[rows]
    xs = np.arange(wid)[cols]
    my = _bspline_matrix(hgt, sub.shape[1], r, period)[ys]
    mx = _bspline_matrix(wid, sub.shape[2], c, period)[xs].T.tocsc()
    out = np.empty((len(stack), len(ys), len(xs)), np.float32)
    for i, s in enumerate(sub):
        coef = ndimage.spline_filter(s, order=3, mode="mirror")
        out[i] = (mx.T @ (my @ coef).T).T
    return out[0] if single else out


def _to_pixels(a: np.ndarray, shape: tuple[int, int], p: int) -> np.ndarray:
    """Lenslet-grid values → view pixels (bilinear between lenslet centres), clipped to [0, 1]."""
    yy = (np.arange(shape[0]) - (p - 1) / 2) / p
    xx = (np.arange(shape[1]) - (p - 1) / 2) / p
    out = ndimage.map_coordinates(a.astype(np.float64), np.meshgrid(yy, xx, indexing="ij"),
                                  order=1, mode="nearest")
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def _smooth_pixels(a: np.ndarray, shape: tuple[int, int], p: int) -> np.ndarray:
    """Lenslet-grid weights, smoothed over 0.7 lenslet, on view pixels; below 0.01: exactly 0."""
    out = _to_pixels(ndimage.gaussian_filter(a, 0.7), shape, p)
    out[out < 0.01] = 0.0
    return out


def _residual_weight(view, corrected, period, phase, gate, opt) -> np.ndarray:
    """Fallback weight ``(H, W)`` from the disagreement of ``corrected`` with the reference
    frame alone in their common band (:class:`FallbackOptions` ``residual``)."""
    ref = reference_upsample(view, period, phase).astype(np.float64)
    sigma = opt.residual_window * period
    d_view = np.abs(ndimage.gaussian_filter(np.asarray(view, np.float64) - ref, sigma))
    d_corr = np.abs(ndimage.gaussian_filter(np.asarray(corrected, np.float64) - ref, sigma))
    far = ~ndimage.binary_dilation(gate > 0, iterations=2 * period)
    sample = d_view[far] if far.sum() >= 1000 else d_view.ravel()
    tol = max(float(np.percentile(sample, opt.residual_quantile)), 1e-12)
    lo, hi = opt.residual
    wgt = np.clip((d_corr / tol - lo) / (hi - lo), 0.0, 1.0)
    return ndimage.gaussian_filter(wgt, 0.7 * period)


def fallback_map(view: np.ndarray, corrected: np.ndarray, period: int,
                 phase: tuple[int, int], flow_moved: np.ndarray,
                 options: FallbackOptions | None = None) -> FallbackMap:
    """Decide where the corrected view falls back to the reference frame alone.

    Parameters
    ----------
    view, corrected : (H, W) realigned view and its flow-corrected version.
    period : scan period p. phase : (r, c), the reference frame's scan phase.
    flow_moved : (T, h, w) bool, samples that the flow moved by at least the motion threshold
        [view px] (each frame on its sub-image grid; :func:`.flow.sub_images`).
    options : :class:`FallbackOptions` (None: defaults).

    Returns
    -------
    :class:`FallbackMap`. Warns once when more than ``options.warn_share`` of the moving
    region fell back.
    """
    opt = FallbackOptions() if options is None else options
    shape = np.shape(view)
    coh = lattice_coherence(view, period, opt.window, opt.highpass)
    left = lattice_coherence(corrected, period, opt.window, opt.highpass)
    h = min(coh.shape[0], flow_moved.shape[1])
    w = min(coh.shape[1], flow_moved.shape[2])
    share = ndimage.gaussian_filter(flow_moved[:, :h, :w].mean(axis=0, dtype=np.float64), 2.0)
    seeds = np.zeros(coh.shape, bool)
    seeds[:h, :w] = (coh[:h, :w] > opt.region) & (share >= opt.flow_share)
    region = seeds
    if seeds.any():
        # the artefact's whole extent: coherent lenslets connected (across gaps of up to
        # ``bridge`` lenslets: an occluder) to lenslets where the flow moved samples
        coherent = coh > opt.region
        labels, _ = ndimage.label(ndimage.binary_dilation(coherent, iterations=opt.bridge))
        hit = np.unique(labels[seeds])
        region = coherent & np.isin(labels, hit[hit > 0])
        region = ndimage.binary_fill_holes(ndimage.binary_closing(region, iterations=2))
        region = ndimage.binary_dilation(region, iterations=opt.margin)
    gate = _smooth_pixels(region.astype(np.float64), shape, period)
    weight = np.clip((left - opt.low) / (opt.high - opt.low), 0.0, 1.0)
    weight = _smooth_pixels(weight, shape, period) * gate
    if gate.any():
        residual = _residual_weight(view, corrected, period, phase, gate, opt)
        weight = np.maximum(weight, np.clip(residual, 0.0, 1.0) * gate)
        weight[weight < 0.01] = 0.0
    moving = gate > 0.5
    fraction = float((weight[moving] > 0.5).mean()) if moving.any() else 0.0
    if fraction > opt.warn_share:
        warnings.warn(f"motion correction fell back to the reference frame alone on "
                      f"{100 * fraction:.0f} % of the moving region (the flow did not fit "
                      f"there; resolution is one frame's; the scan period used is {period}: "
                      f"a view of another period needs its own scan order)", stacklevel=3)
    return FallbackMap(weight.astype(np.float32), gate.astype(np.float32), fraction)


def blend(views: np.ndarray, corrected: np.ndarray, fmap: FallbackMap, period: int,
          phase: tuple[int, int]) -> np.ndarray:
    """``corrected + weight · (reference − corrected)`` for ``(H, W)`` or ``(N, H, W)`` arrays
    (``reference``: :func:`reference_upsample` of ``views`` at the reference phase, computed
    only inside the bounding box of ``weight > 0``; elsewhere ``corrected`` bit for bit)."""
    corrected = np.asarray(corrected, np.float32)
    if not fmap.weight.any():
        return corrected
    ys, xs = np.nonzero(fmap.weight)
    box = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
    ref = reference_upsample(views, period, phase, *box)
    out = corrected.copy()
    part = out[..., box[0], box[1]]
    part += fmap.weight[box] * (ref - part)
    return out
