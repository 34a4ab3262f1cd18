"""Dense disparity, confidence and metric depth from a view stack (multi-view stereo).

Pipeline (the paper's Fig. 6 and Methods, "Depth estimation"):

1. Views inside the pupil (``cfg.view_mask()``), each divided by its mean (vignetting and the
   coded aperture dim the outer views); optionally warped by the system aberration's per-view
   shift maps (``calibration``) so that only the parallax is left.
2. Plane sweep: a cost volume over ``candidates`` disparities (variance of the aligned views
   resampled by cubic convolution, plus ``CENTRE_WEIGHT / scan²`` times the squared distance of
   their mean to the centre view, which gives a pixel straddling an occluding edge the layer at
   its centre; or SAD to the centre view; optional half-pupil occlusion handling,
   ``metasensor.depth.cost``), each slice aggregated by a
   guided filter steered by the centre view (edge-aware cost-volume filtering, Hosni et al. 2013)
   and, by default, the per-pixel costs also regularised by semi-global matching
   (``metasensor.depth.sgm``, Hirschmüller 2008), which decides at depth edges and thin
   structures (where the two disagree by more than ``AGREE_PX`` at the outermost view).
3. Winner-take-all with a parabola fit, a peak-ratio confidence, then Gauss–Newton refinement of
   the disparity on the views themselves (continuous, no candidate grid).
4. Optional confidence-weighted, edge-aware filling of low-confidence pixels; then, by
   default, each depth-edge pixel given the layer that covers more than half its footprint, as
   the views measure it (``metasensor.depth.edges``), and, for plain light-field views (scan 1),
   a small learned choice of each edge pixel's layer between the two of its neighbourhood
   (``metasensor.depth.learned``) and the removal of speckles (``metasensor.depth.speckle``).
5. Disparity → image-side depth ``z = δ · d · mla_focal``; with the main-lens focal length and
   focus distance (config or keywords), → object distance by the thin-lens equation
   (``metasensor.depth.geometry`` states the signs).

Written here by hand (no maintained Python library does plane-sweep stereo over a light-field
view grid); the pieces follow the light-field literature as cited in each module. Memory: the
used views twice (input copy, padded copy), the cost volume ``(candidates, H, W)`` float32 (twice
with semi-global matching) and a few ``(9, H, W)`` accumulators
(``(2·candidates + 2·V + 9) · H · W · 4`` bytes for V views).
Speed: ``benchmarks/bench_depth.py`` (figures in ``docs/decisions.md``).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from metasensor.backend import resolve_device, to_numpy
from metasensor.config import SystemConfig
from metasensor.depth import geometry
from metasensor.depth.aberration import resolve_shift_maps, warp_views
from metasensor.depth.cost import CostVolume
from metasensor.depth.edges import EdgeSnap, snap_edges
from metasensor.depth.filters import GuidedFilter
from metasensor.depth.learned import EdgeRefiner, refine_edges
from metasensor.depth.refine import (
    fill_low_confidence,
    gauss_newton_refine,
    peak_ratio_confidence,
    subpixel_minimum,
)
from metasensor.depth.sgm import SemiGlobal, normalise_costs, semi_global
from metasensor.depth.span import measure_span, saturation
from metasensor.depth.speckle import Speckles, remove_speckles

__all__ = ["DepthResult", "estimate_depth"]


MAX_CANDIDATES = 1024  # plane-sweep disparities, at most
MIN_CANDIDATES = 64  # the automatic candidate count, at least
OUTER_STEP = 0.5  # automatic candidate spacing: the outermost view moves this many view px
COARSE_SATURATED = 0.01  # the same for the coarse search
AGREE_PX = 2.0  # window and semi-global estimates agree: outermost views within this [view px]
# weight of the centre view in the variance cost (metasensor.depth.cost), divided by scan²: it
# decides the pixels whose one-view-pixel footprint straddles an occluding edge (scan 1); where
# the lenslet footprint spans `scan` view pixels (the meta-imaging sensor) it would only add
# the centre view's noise
CENTRE_WEIGHT = 0.25
SATURATED = 0.001  # share of confident pixels on an end of the span that widens or warns


@dataclass(frozen=True)
class DepthResult:
    """Result of :func:`estimate_depth`; every map is ``(H, W)`` on the view grid.

    disparity : float32, view pixels per view step; view (u, v) content at
        ``p + disparity · (u − c, v − c)`` equals the centre view's at ``p``.
    confidence : float32 in [0, 1] (peak ratio of the cost curve that decided the pixel:
        window-aggregated or semi-global).
    image_depth : float32 metres, image-side depth ``z = disparity · d · mla_focal`` (``z > 0``:
        focused in front of the MLA, towards the main lens; d = nnum // scan).
    object_distance : float32 metres from the main lens (thin lens), or ``None`` without
        ``focal_length`` and ``focus_distance``; NaN where no real object maps there.
    depth : the metric depth of the public contract: ``object_distance`` when the main-lens
        geometry is known, else ``None`` (``image_depth`` is there either way);
        ``depth_kind`` says which metric maps exist (``"object"`` or ``"image"`` only).
    candidates : the candidate disparities of the plane sweep (view px per view step).
    valid : bool, pixels whose estimate the data support (confidence at least the fill
        threshold and not on an end of the span); elsewhere ``disparity`` is filled from the
        confident neighbours or kept as the sweep found it, and is a guess.
    span_source : ``"measured"`` (coarse wide search, :mod:`metasensor.depth.span`) or
        ``"given"``.
    saturated : shares (low end, high end) of the pixels whose cost still falls at an end of the
        final span (:func:`metasensor.depth.span.saturation`: the true disparity may lie
        beyond); for a given span, at least the shares of the coarse wide search's confident
        estimates below and above it.
    config : the system configuration used.
    """

    disparity: np.ndarray
    confidence: np.ndarray
    image_depth: np.ndarray
    object_distance: np.ndarray | None
    depth: np.ndarray | None
    depth_kind: str
    candidates: np.ndarray
    config: SystemConfig
    valid: np.ndarray | None = None
    span_source: str = "given"
    saturated: tuple[float, float] = (0.0, 0.0)

    def __repr__(self) -> str:  # the maps by shape and dtype, not their values
        from metasensor.summary import short_repr

        return short_repr(self)


def _check_views(views, cfg: SystemConfig) -> np.ndarray:
    if hasattr(views, "views") and not isinstance(views, np.ndarray):  # a Capture
        views = views.views
    arr = np.asarray(views)
    if arr.ndim != 4 or arr.shape[0] != arr.shape[1]:
        raise ValueError(f"views must have shape (nnum, nnum, H, W), got {arr.shape}")
    if arr.shape[0] != cfg.nnum:
        raise ValueError(f"views have {arr.shape[0]} x {arr.shape[1]} views but cfg.nnum is "
                         f"{cfg.nnum}")
    if min(arr.shape[2:]) < 4:
        raise ValueError(f"views are too small for depth estimation: {arr.shape[2:]}")
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise TypeError(f"views must be real numbers, got dtype {arr.dtype}")
    return arr


def _check_settings(cfg, arr, candidates, radius, refine_iterations, refine_radius, fill_radius,
                    eps, disparity_range, view_mask, smoothing=None, edges=None,
                    refiner=None, speckles=None) -> np.ndarray:
    """Validate the settings (one-line errors); returns the boolean view mask."""
    for name, value, kind in (("smoothing", smoothing, SemiGlobal), ("edges", edges, EdgeSnap),
                              ("refiner", refiner, EdgeRefiner),
                              ("speckles", speckles, Speckles)):
        if value is not None and not isinstance(value, kind):
            article = "an" if kind.__name__[0] in "AEIOU" else "a"
            raise TypeError(f"{name} must be {article} {kind.__name__} or None, got "
                            f"{type(value).__name__}")
    n, c = cfg.nnum, cfg.center
    side = max(arr.shape[2:])
    # upper bounds: windows beyond the view, and sweeps finer than 1/1000 of the range (a cost
    # volume of candidates x H x W floats) are mistakes, not settings
    checks = [("radius", radius, 1, side), ("refine_iterations", refine_iterations, 0, 100),
              ("fill_radius", fill_radius, 1, side)]
    if candidates is not None:
        checks.append(("candidates", candidates, 3, MAX_CANDIDATES))
    if refine_radius is not None:
        checks.append(("refine_radius", refine_radius, 1, side))
    for name, value, low, high in checks:
        if not (isinstance(value, int | np.integer) and low <= value <= high):
            raise ValueError(f"{name} must be an integer in [{low}, {high}], got {value!r}")
    if not (isinstance(eps, int | float) and math.isfinite(eps) and eps > 0):
        raise ValueError(f"eps must be a positive number, got {eps!r}")
    if disparity_range is not None and (np.shape(disparity_range) != (2,)
                                        or not np.isfinite(disparity_range).all()
                                        or disparity_range[0] >= disparity_range[1]):
        raise ValueError(f"disparity_range must be (low, high) with low < high, "
                         f"got {disparity_range!r}")
    h, w = arr.shape[2:]
    if disparity_range is not None and max(map(abs, disparity_range)) * c > max(h, w):
        raise ValueError(f"disparity_range {tuple(disparity_range)} shifts the outer views by "
                         f"more than the {h}x{w} views (at most ±{max(h, w) / max(c, 1):.3g})")
    mask = cfg.view_mask() if view_mask is None else np.asarray(view_mask, dtype=bool)
    if mask.shape != (n, n):
        raise ValueError(f"view_mask must have shape {(n, n)}, got {mask.shape}")
    if not mask[c, c] or mask.sum() < 2:
        raise ValueError("view_mask must contain the centre view and at least one other view")
    return mask


def _prepared_stack(arr, uu, vv, shift_maps, normalize: bool, dev) -> torch.Tensor:
    """The used views as one float32 tensor: a copy, warped and normalised by their means."""
    # fancy indexing copies: the caller's array is never touched, and torch shares this copy
    sel = np.ascontiguousarray(arr[uu, vv], dtype=np.float32)
    if not np.isfinite(sel).all():
        raise ValueError("views contain NaN or infinite values")
    stack = torch.from_numpy(sel).to(dev)
    if shift_maps is not None:
        stack = warp_views(stack, torch.tensor(shift_maps[uu, vv], device=dev))
    if normalize:
        means = stack.mean(dim=(1, 2), keepdim=True)
        if bool((means <= 0).any()):
            raise ValueError("a view inside the pupil has a non-positive mean; "
                             "pass normalize=False or a smaller view_mask")
        stack.div_(means).mul_(means.mean())
    return stack


def _candidates(span, candidates: int | None, amax: float) -> np.ndarray:
    if candidates is None:  # the outermost view moves OUTER_STEP view px per candidate
        width = float(span[1] - span[0])
        candidates = int(min(MAX_CANDIDATES, max(MIN_CANDIDATES,
                                                 math.ceil(width * amax / OUTER_STEP) + 1)))
    return geometry.disparity_candidates(span, candidates)


def _sweep(stack, au, av, centre, cands, gf, cost, occlusion, penalties, progress,
           centre_weight: float = 0.0):
    """Plane sweep + winner-take-all: ``(disparity, winner index, confidence, saturation
    (low, high), sweep)``; without ``penalties`` from the window-aggregated costs (guided filter
    ``gf``), with them as :func:`_decide` says."""
    sweep = CostVolume(stack, au, av, centre, float(np.abs(cands).max()), cost=cost,
                       occlusion=occlusion, centre_weight=centre_weight)
    # saturation is judged over the disparity change that moves the outermost view by a pixel
    amax = float(max(np.abs(au).max(), np.abs(av).max()))
    steps = int(min(len(cands) // 4, max(3, math.ceil(1.0 / (amax * (cands[1] - cands[0]))))))
    if penalties is None:
        vol = sweep.volume(cands, aggregate=gf, progress=progress)
        disp, idx = subpixel_minimum(vol, cands)
        return (disp, idx, peak_ratio_confidence(vol, idx), saturation(vol, idx, steps=steps),
                sweep)
    return (*_decide(sweep.volume(cands, progress=progress), cands, gf, penalties, amax, steps),
            sweep)


def _decide(vol, cands, gf, penalties: SemiGlobal, amax: float, steps: int):
    """Window aggregation and semi-global matching of the per-pixel costs ``vol`` (overwritten):
    ``(disparity, winner index, confidence, saturation)``.

    Where the semi-global estimate moves the outermost view by at most ``AGREE_PX`` view px (or
    one candidate) from the window's, the window's (smoother, sub-candidate) estimate is kept;
    elsewhere (depth edges, thin structures: the window's estimate spreads the background over
    them) the semi-global one. The confidence is the peak ratio of the curve that decided."""
    scale = normalise_costs(vol, noise=penalties.noise)
    total = semi_global(vol, penalties)
    d_sgm, i_sgm = subpixel_minimum(total, cands)
    c_sgm = peak_ratio_confidence(total, i_sgm)
    sat_sgm = saturation(total, i_sgm, steps=steps)
    del total
    vol.mul_(scale)  # back to the plain costs
    for k in range(vol.shape[0]):
        vol[k] = gf(vol[k])
    disp, idx = subpixel_minimum(vol, cands)
    sat = tuple(max(a, b) for a, b in zip(saturation(vol, idx, steps=steps), sat_sgm,
                                           strict=True))
    agree = (disp - d_sgm).abs() <= max(AGREE_PX / amax, float(cands[1] - cands[0]))
    conf = torch.where(agree, peak_ratio_confidence(vol, idx), c_sgm)
    return torch.where(agree, disp, d_sgm), torch.where(agree, idx, i_sgm), conf, sat


def _widened(span, limit, low: float, high: float):
    """The span grown by half its width on each saturated side, within ``limit``."""
    lo, hi = span
    half = 0.5 * (hi - lo)
    if low > SATURATED:
        lo = max(lo - half, limit[0])
    if high > SATURATED:
        hi = min(hi + half, limit[1])
    return (lo, hi)


def estimate_depth(views, cfg: SystemConfig, calibration=None, *, candidates: int | None = None,
                   disparity_range: tuple[float, float] | None = None,
                   view_mask: np.ndarray | None = None, cost: str = "variance",
                   occlusion: bool = True, radius: int = 4, eps: float = 0.01,
                   refine_iterations: int = 2, refine_radius: int | None = None,
                   fill: bool = True, fill_threshold: float = 0.1,
                   fill_radius: int | None = None, normalize: bool = True,
                   smoothing: SemiGlobal | None = SemiGlobal(),
                   edges: EdgeSnap | None = EdgeSnap(),
                   refiner: EdgeRefiner | None = EdgeRefiner(),
                   speckles: Speckles | None = Speckles(),
                   focal_length: float | None = None, focus_distance: float | None = None,
                   device=None, progress: bool = False) -> DepthResult:
    """Disparity, confidence and depth from views ``(nnum, nnum, H, W)`` (or a ``Capture``).

    calibration : per-view aberration shift maps (``metasensor.depth.aberration``): an array
        ``(nnum, nnum, 2, H, W)`` in view pixels (dy, dx), an object with ``.shift_maps(shape)``,
        or a path to a system-aberration file. The views are warped by them first.
    disparity_range : span of the plane-sweep disparities in view pixels per view step. Default
        (None): measured from the views by a coarse wide search
        (:func:`metasensor.depth.span.measure_span`, covering at least
        :func:`geometry.default_disparity_range`), and widened where the estimate saturates an
        end; a given span is kept, with a warning when the estimate saturates it.
    candidates : number of plane-sweep disparities; None: the outermost view moves
        ``OUTER_STEP`` view px per candidate (at least ``MIN_CANDIDATES``).
    view_mask : boolean ``(nnum, nnum)`` of the views to use (default ``cfg.view_mask()``); it must
        contain the centre view. ``cost``: ``"variance"`` (with the centre term of step 2) or
        ``"sad"``; ``occlusion``: half-pupil occlusion handling. ``radius`` [view px] and
        ``eps`` (relative to the guide's variance) of the guided cost aggregation.
        ``refine_iterations``: Gauss–Newton steps (0 = parabola fit only), aggregated over
        ``refine_radius`` (None: ``radius``). ``fill``: replace pixels
        with confidence below ``fill_threshold`` by an edge-aware, confidence-weighted average
        of the confident ones within ``fill_radius`` view px (None: 16, or the views' larger
        side where they are smaller) (``DepthResult.valid`` marks the others).
    smoothing : :class:`metasensor.depth.sgm.SemiGlobal` penalties of the semi-global matching
        that decides at depth edges and thin structures (default), or None: the window
        aggregation alone.
    edges : :class:`metasensor.depth.edges.EdgeSnap` settings of the re-decision of depth-edge
        pixels by the front layer's measured coverage (default), or None: none.
    refiner : :class:`metasensor.depth.learned.EdgeRefiner` settings of the learned choice of
        each depth-edge pixel's layer (after ``edges``; default), or None: none. Applied to
        plain light-field views (``cfg.scan == 1``), the kind it was trained on, only.
    speckles : :class:`metasensor.depth.speckle.Speckles` settings of the removal of small
        isolated segments (last; default), or None: none. Plain light-field views only (where
        it was measured).
    focal_length, focus_distance : main-lens geometry [m] overriding the config's.
    """
    if not isinstance(cfg, SystemConfig):
        raise TypeError(f"cfg must be a SystemConfig, got {type(cfg).__name__}")
    arr = _check_views(views, cfg)
    if fill_radius is None:
        fill_radius = min(16, max(arr.shape[2:]))
    mask = _check_settings(cfg, arr, candidates, radius, refine_iterations, refine_radius,
                           fill_radius, eps, disparity_range, view_mask, smoothing, edges,
                           refiner, speckles)
    n, c = cfg.nnum, cfg.center
    lens = geometry.main_lens_geometry(cfg, focal_length, focus_distance)
    shift_maps = resolve_shift_maps(calibration, n, arr.shape[2:])
    dev = resolve_device(device)
    uu, vv = np.nonzero(mask)
    au, av = (uu - c).astype(np.float64), (vv - c).astype(np.float64)
    amax = float(max(np.abs(au).max(), np.abs(av).max()))
    with torch.no_grad():
        stack = _prepared_stack(arr, uu, vv, shift_maps, normalize, dev)
        centre = int(np.nonzero((uu == c) & (vv == c))[0][0])
        guide = stack[centre].clone()
        gf = GuidedFilter(guide, radius=radius, eps=eps)
        span, limit, found = _initial_span(stack, au, av, centre, cfg, occlusion,
                                           disparity_range)
        weight = CENTRE_WEIGHT / cfg.scan**2 if cost == "variance" else 0.0
        while True:
            cands = _candidates(span, candidates, amax)
            disp, idx, conf, sat, sweep = _sweep(stack, au, av, centre, cands, gf, cost, occlusion,
                                                 smoothing, progress, weight)
            # the (mean-subtracted, padded) copy inside the sweep serves for the views from here
            del stack
            stack = sweep.views
            del sweep
            wider = None if limit is None else _widened(span, limit, *sat)
            if wider is None or wider == span:
                break
            span = wider
        if limit is None:  # a given span: the coarse search says whether it holds the scene
            sat = _check_given_span(span, sat, found.beyond)
        ends = (idx == 0) | (idx == len(cands) - 1)
        if refine_iterations > 0:
            gfr = gf if refine_radius is None else GuidedFilter(guide, radius=refine_radius,
                                                                 eps=eps)
            disp = _refined(stack, au, av, disp, gfr, cands, refine_iterations, occlusion)
        if fill:
            disp = fill_low_confidence(disp, conf, guide, radius=fill_radius,
                                       threshold=fill_threshold, eps=eps)
        if edges is not None:
            disp = snap_edges(stack, au, av, disp, edges)
        if refiner is not None and cfg.scan == 1:
            disp = refine_edges(stack, au, av, disp, conf, refiner)
        if speckles is not None and cfg.scan == 1:
            disp = remove_speckles(disp, amax, speckles)
        valid = to_numpy((conf >= fill_threshold) & ~ends).astype(bool)
        disparity = to_numpy(disp).astype(np.float32)
        confidence = to_numpy(conf).astype(np.float32)
    return _result(disparity, confidence, valid, cands, cfg, lens,
                   "given" if limit is None else "measured", sat)


def _refined(stack, au, av, disp, gf, cands, iterations, occlusion):
    """Gauss–Newton refinement of the sweep's disparities, each step at most one candidate
    step, clamped to the swept span."""
    disp = gauss_newton_refine(stack, au, av, disp, gf, iterations=iterations,
                               max_change=float(cands[1] - cands[0]), occlusion=occlusion)
    return torch.clamp(disp, float(cands[0]), float(cands[-1]))


def _result(disparity, confidence, valid, cands, cfg, lens, span_source, sat) -> DepthResult:
    """The :class:`DepthResult` of the disparities: image-side depth, and the object distance
    where the main lens's geometry is known."""
    z = geometry.disparity_to_image_depth(disparity, cfg).astype(np.float32)
    obj = None
    if lens is not None:
        obj = geometry.image_depth_to_object_distance(z, *lens).astype(np.float32)
    return DepthResult(
        disparity=disparity, confidence=confidence, image_depth=z, object_distance=obj,
        depth=obj, depth_kind="object" if obj is not None else "image",
        candidates=cands, config=cfg, valid=valid, span_source=span_source, saturated=sat,
    )


def _initial_span(stack, au, av, centre, cfg, occlusion, disparity_range):
    """(span, widest searched span or None for a given one, the coarse search's result) for
    :func:`estimate_depth`; warns once when the coarse estimates saturate the widest search."""
    given = None if disparity_range is None else (float(disparity_range[0]),
                                                  float(disparity_range[1]))
    found = measure_span(stack, au, av, centre, geometry.default_disparity_range(cfg),
                         occlusion=occlusion, given=given)
    if given is not None:
        return given, None, found
    limit = found.searched
    if found.saturated > COARSE_SATURATED:
        warnings.warn(f"{100 * found.saturated:.1f} % of the coarse estimates saturate an end "
                      f"of the widest search {limit[0]:+.2f} .. {limit[1]:+.2f} view px per "
                      "view step: larger disparities are not found", RuntimeWarning,
                      stacklevel=3)
    return found.span, limit, found


def _check_given_span(span, sat, beyond) -> tuple[float, float]:
    """The saturated shares below / above a given span (the sweep's, or the coarse wide
    search's where larger); warns once when either exceeds ``SATURATED``."""
    sat = tuple(max(a, b) for a, b in zip(sat, beyond, strict=True))
    if max(sat) > SATURATED:
        warnings.warn(f"{100 * sat[0]:.1f} % / {100 * sat[1]:.1f} % of the scene lies "
                      f"below / above disparity_range {span} (coarse wide search): "
                      "widen it (or leave it to the default, measured)",
                      RuntimeWarning, stacklevel=3)
    return sat
