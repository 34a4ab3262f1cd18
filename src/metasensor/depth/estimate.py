"""Dense disparity, confidence and metric depth from a view stack (multi-view stereo).

Pipeline (the paper's Fig. 6 and Methods, "Depth estimation"):

1. Views inside the pupil (``cfg.view_mask()``, or every lit view where the data show a wider
   pupil: :mod:`metasensor.depth.pupil`), each divided by its mean (vignetting and the
   coded aperture dim the outer views); optionally warped by the system aberration's per-view
   shift maps (``calibration``) so that only the parallax is left.
2. Plane sweep: a cost volume over ``candidates`` disparities (variance of the aligned views
   resampled by cubic convolution, plus ``CENTRE_WEIGHT / scan²`` times the squared distance of
   their mean to the centre view, which gives a pixel straddling an occluding edge the layer at
   its centre; or SAD to the centre view; optional half-pupil occlusion handling,
   ``metasensor.depth.cost``), each slice aggregated by a
   guided filter steered by the centre view (edge-aware cost-volume filtering, Hosni et al. 2013;
   for plain light-field views only weakly edge-aware, ``EPS_PLAIN``) and, by default, the
   per-pixel costs also regularised by semi-global matching
   (``metasensor.depth.sgm``, Hirschmüller 2008), which decides at depth edges and thin
   structures (where the two disagree by more than ``AGREE_PX`` at the outermost view).
3. Winner-take-all with a parabola fit, a peak-ratio confidence, then Gauss–Newton refinement of
   the disparity on the views themselves (continuous, no candidate grid).
4. Optional confidence-weighted, edge-aware filling of low-confidence pixels; for plain
   light-field views, by default, background pixels given a nearer layer re-decided with the
   views that see the farther one (``metasensor.depth.visibility``); then, by
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

import numpy as np
import torch

from metasensor.backend import resolve_device
from metasensor.config import SystemConfig
from metasensor.depth import geometry
from metasensor.depth.aberration import resolve_shift_maps, warp_views
from metasensor.depth.checks import check_settings, check_views
from metasensor.depth.cost import CostVolume
from metasensor.depth.edges import EdgeSnap, snap_edges
from metasensor.depth.filters import GuidedFilter
from metasensor.depth.learned import EdgeRefiner, refine_edges
from metasensor.depth.pupil import default_view_mask
from metasensor.depth.refine import (
    fill_low_confidence,
    gauss_newton_refine,
    peak_ratio_confidence,
    subpixel_minimum,
)
from metasensor.depth.result import DepthResult, depth_result
from metasensor.depth.sgm import SemiGlobal, normalise_costs, semi_global

# the span's constants stay importable from here
from metasensor.depth.span import (  # noqa: F401
    COARSE_SATURATED,
    MAX_CANDIDATES,
    MIN_CANDIDATES,
    OUTER_STEP,
    SATURATED,
    check_given_span,
    initial_span,
    saturation,
    sweep_candidates,
    widened,
)
from metasensor.depth.speckle import Speckles, remove_speckles
from metasensor.depth.visibility import Visibility, reveal_background

__all__ = ["DepthResult", "estimate_depth"]


AGREE_PX = 2.0  # window and semi-global estimates agree: outermost views within this [view px]
# default regularisation of the guided cost aggregation (units of the guide's variance): plain
# light-field views (scan 1) pool the cost across the texture's own edges (a small eps makes
# every texture edge a segment border, leaving flat patches between them with a flat cost;
# depth edges are decided by the semi-global matching), scanned views keep it edge-aware
EPS_PLAIN = 1.0
EPS_SCANNED = 0.01
# weight of the centre view in the variance cost (metasensor.depth.cost), divided by scan²: it
# decides the pixels whose one-view-pixel footprint straddles an occluding edge (scan 1); where
# the lenslet footprint spans `scan` view pixels (the meta-imaging sensor) it would only add
# the centre view's noise
CENTRE_WEIGHT = 0.25


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


def _sweep(stack, au, av, centre, cands, gf, cost, occlusion, penalties, progress,
           centre_weight: float = 0.0):
    """Plane sweep + winner-take-all: ``(disparity, winner index, confidence, saturation
    (low, high), the sweep's mean-subtracted padded views)``; without ``penalties`` from the
    window-aggregated costs (guided filter ``gf``), with them as :func:`_decide` says."""
    sweep = CostVolume(stack, au, av, centre, float(np.abs(cands).max()), cost=cost,
                       occlusion=occlusion, centre_weight=centre_weight)
    # saturation is judged over the disparity change that moves the outermost view by a pixel
    amax = float(max(np.abs(au).max(), np.abs(av).max()))
    steps = int(min(len(cands) // 4, max(3, math.ceil(1.0 / (amax * (cands[1] - cands[0]))))))
    if penalties is None:
        vol = sweep.volume(cands, aggregate=gf, progress=progress)
        disp, idx = subpixel_minimum(vol, cands)
        return (disp, idx, peak_ratio_confidence(vol, idx), saturation(vol, idx, steps=steps),
                sweep.views)
    return (*_decide(sweep.volume(cands, progress=progress), cands, gf, penalties, amax, steps),
            sweep.views)


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


def estimate_depth(views, cfg: SystemConfig, calibration=None, *, candidates: int | None = None,
                   disparity_range: tuple[float, float] | None = None,
                   view_mask: np.ndarray | None = None, cost: str = "variance",
                   occlusion: bool = True, radius: int = 4, eps: float | None = None,
                   refine_iterations: int = 2, refine_radius: int | None = None,
                   fill: bool = True, fill_threshold: float = 0.1,
                   fill_radius: int | None = None, normalize: bool = True,
                   smoothing: SemiGlobal | None = SemiGlobal(),
                   edges: EdgeSnap | None = EdgeSnap(),
                   refiner: EdgeRefiner | None = EdgeRefiner(),
                   speckles: Speckles | None = Speckles(),
                   visibility: Visibility | None = Visibility(),
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
    view_mask : boolean ``(nnum, nnum)`` of the views to use (default ``cfg.view_mask()``, with
        every lit view where views beyond the configured pupil are lit, warned:
        :func:`metasensor.depth.pupil.default_view_mask`); it must contain the centre view.
        ``cost``: ``"variance"`` (with the centre term of step 2) or ``"sad"``; ``occlusion``:
        half-pupil occlusion handling. ``radius`` [view px] and ``eps`` (relative to the
        guide's variance) of the guided cost aggregation (also of the refinement's aggregation
        and the fill; None: ``EPS_PLAIN`` for plain light-field views, ``cfg.scan == 1``, else
        ``EPS_SCANNED``).
        ``refine_iterations``: Gauss–Newton steps (0 = parabola fit only), aggregated over
        ``refine_radius`` (None: ``radius``). ``fill``: replace pixels
        with confidence below ``fill_threshold`` by an edge-aware, confidence-weighted average
        of the confident ones within ``fill_radius`` view px (None: 16, or the views' larger
        side where they are smaller) (``DepthResult.valid`` marks the others).
    smoothing : :class:`metasensor.depth.sgm.SemiGlobal` penalties of the semi-global matching
        that decides at depth edges and thin structures (default), or None: the window
        aggregation alone.
    visibility : :class:`metasensor.depth.visibility.Visibility` settings of the re-decision of
        pixels given a nearer layer than their neighbourhood's farthest, with the views that
        see that farther layer (after the fill; default), or None: none. Plain light-field
        views only.
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
    arr = check_views(views, cfg)
    view_mask = default_view_mask(arr, cfg) if view_mask is None else view_mask
    if eps is None:
        eps = EPS_PLAIN if cfg.scan == 1 else EPS_SCANNED
    mask, fill_radius = check_settings(cfg, arr, candidates, radius, refine_iterations,
                                       refine_radius, fill_radius, eps, disparity_range,
                                       view_mask, smoothing, edges, refiner, speckles,
                                       visibility)
    lens = geometry.main_lens_geometry(cfg, focal_length, focus_distance)
    shift_maps = resolve_shift_maps(calibration, cfg.nnum, arr.shape[2:])
    dev = resolve_device(device)
    with torch.no_grad():
        stack, au, av, centre, amax = _used_views(arr, mask, cfg, shift_maps, normalize, dev)
        guide = stack[centre].clone()
        gf = GuidedFilter(guide, radius=radius, eps=eps)
        span, limit, found = initial_span(stack, au, av, centre, cfg, occlusion, disparity_range)
        weight = CENTRE_WEIGHT / cfg.scan**2 if cost == "variance" else 0.0
        # the sweep's (mean-subtracted, padded) copy serves for the views from here
        disp, idx, conf, sat, stack, cands = _swept_until_covered(
            stack, au, av, centre, span, limit, candidates, amax, gf, cost, occlusion,
            smoothing, progress, weight)
        if limit is None:  # a given span: the coarse search says whether it holds the scene
            sat = check_given_span(span, sat, found.beyond)  # swept once, not widened
        if refine_iterations > 0:
            gfr = gf if refine_radius is None else GuidedFilter(guide, refine_radius, eps)
            disp = _refined(stack, au, av, disp, gfr, cands, refine_iterations, occlusion)
        if fill:
            disp = fill_low_confidence(disp, conf, guide, radius=fill_radius,
                                       threshold=fill_threshold, eps=eps)
        disp = _layers_decided(stack, au, av, centre, disp, conf, amax, cfg, visibility, edges,
                               refiner, speckles)
    return depth_result(disp, conf, idx, fill_threshold, cands, cfg, lens,
                        "given" if limit is None else "measured", sat, mask)


def _swept_until_covered(stack, au, av, centre, span, limit, candidates, amax, gf, cost,
                         occlusion, smoothing, progress, weight):
    """The plane sweep over ``span``, widened (up to ``limit``; None: a given span, swept
    once) and swept again while the estimate saturates an end (:func:`widened`).

    Returns
    -------
    disp, idx, conf, sat, stack, cands : :func:`_sweep`'s results and the last candidates.
    """
    while True:
        cands = sweep_candidates(span, candidates, amax)
        disp, idx, conf, sat, stack = _sweep(stack, au, av, centre, cands, gf, cost,
                                             occlusion, smoothing, progress, weight)
        wider = None if limit is None else widened(span, limit, *sat)
        if wider is None or wider == span:
            return disp, idx, conf, sat, stack, cands
        span = wider


def _used_views(arr, mask, cfg: SystemConfig, shift_maps, normalize: bool, dev):
    """The views inside the pupil mask, prepared for the sweep.

    Parameters
    ----------
    arr : numpy.ndarray
        The checked views ``(nnum, nnum, H, W)`` (not modified).
    mask : numpy.ndarray
        Boolean ``(nnum, nnum)`` of the views to use (it holds the centre view).
    cfg : SystemConfig
        The system (its centre view).
    shift_maps : numpy.ndarray or None
        Per-view aberration shift maps ``(nnum, nnum, 2, H, W)`` [view px], or None.
    normalize : bool
        Divide each view by its mean (times the mean of the means).
    dev : torch.device
        Where the stack lives.

    Returns
    -------
    stack : torch.Tensor
        The used views ``(V, H, W)`` float32 (:func:`_prepared_stack`).
    au, av : numpy.ndarray
        Their offsets from the centre view [view steps], float64.
    centre : int
        The centre view's index in ``stack``.
    amax : float
        The largest offset [view steps].
    """
    c = cfg.center
    uu, vv = np.nonzero(mask)
    au, av = (uu - c).astype(np.float64), (vv - c).astype(np.float64)
    amax = float(max(np.abs(au).max(), np.abs(av).max()))
    stack = _prepared_stack(arr, uu, vv, shift_maps, normalize, dev)
    centre = int(np.nonzero((uu == c) & (vv == c))[0][0])
    return stack, au, av, centre, amax


def _layers_decided(stack, au, av, centre: int, disp, conf, amax: float, cfg: SystemConfig,
                    visibility, edges, refiner, speckles) -> torch.Tensor:
    """The disparities after the optional layer steps, in order: for plain light-field views
    (``cfg.scan == 1``) the re-decision of pixels given a nearer layer with the views that see
    the farther one (:func:`metasensor.depth.visibility.reveal_background`); the coverage
    re-decision of depth-edge pixels (:func:`metasensor.depth.edges.snap_edges`); then, for
    plain light-field views only, the learned choice of their layer
    (:func:`metasensor.depth.learned.refine_edges`) and the removal of speckles
    (:func:`metasensor.depth.speckle.remove_speckles`).

    Parameters
    ----------
    stack : torch.Tensor
        The views ``(V, H, W)`` as the sweep left them.
    au, av : numpy.ndarray
        Their offsets from the centre view [view steps].
    centre : int
        The centre view's index in ``stack``.
    disp, conf : torch.Tensor
        Disparities [view px per view step] and confidences ``(H, W)``.
    amax : float
        The largest view offset [view steps].
    cfg : SystemConfig
        The system (``scan``).
    visibility, edges, refiner, speckles : Visibility, EdgeSnap, EdgeRefiner, Speckles or None
        Each step's settings, or None: skipped.

    Returns
    -------
    torch.Tensor
        The disparities ``(H, W)``.
    """
    if visibility is not None and cfg.scan == 1:
        disp = reveal_background(stack, au, av, centre, disp, conf, visibility)
    if edges is not None:
        disp = snap_edges(stack, au, av, disp, edges)
    if refiner is not None and cfg.scan == 1:
        disp = refine_edges(stack, au, av, disp, conf, refiner)
    if speckles is not None and cfg.scan == 1:
        disp = remove_speckles(disp, amax, speckles, conf)
    return disp


def _refined(stack, au, av, disp, gf, cands, iterations, occlusion):
    """Gauss–Newton refinement of the sweep's disparities, each step at most one candidate
    step, clamped to the swept span."""
    disp = gauss_newton_refine(stack, au, av, disp, gf, iterations=iterations,
                               max_change=float(cands[1] - cands[0]), occlusion=occlusion)
    return torch.clamp(disp, float(cands[0]), float(cands[-1]))
