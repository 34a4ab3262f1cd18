"""The disparity span of a light field, measured from the views (coarse wide plane sweep), and
the saturation test of an estimate against its span.

A plane sweep only finds disparities inside its candidate span; an estimate outside it is
clipped to the nearest end, which looks like a valid answer. So the span is found first: the
views are box-downsampled by ``f`` <= 4 (coarse side about 96 px or more); a plane sweep covers
every disparity the views can show (the outermost view moves by at most a quarter of the view
side, and by at most :data:`MAX_SPAN` view px per view step), with candidates half a coarse
pixel apart at the outermost view; the span is what the confident coarse estimates cover
(0.2-99.8 percentiles) plus a margin of two coarse candidate steps and 5 % of that width.
Coarse speckles (segments of at most ``SPAN_SPECKLE`` coarse pixels whose disparities differ
by at most one coarse pixel at the outermost view between neighbours,
:func:`metasensor.depth.speckle.speckle_mask`) do not count: a disparity the scene holds
covers a connected region, while a periodic or weak texture gives isolated pixels a wrong
minimum anywhere in the wide search, and each would stretch the fine sweep (and the reach of
its wrong minima) to the search's ends. They are left out on a side of the span only where
they alone stretch it by more than a coarse candidate step. A structure too small to count is
found by the saturation test below.
After the fine sweep, :func:`saturation` says how much of the estimate still falls at an end
of the span (then the span is widened, :func:`widened`, or, when it was given, a warning says
so, :func:`check_given_span`). :func:`initial_span` and :func:`sweep_candidates` give
:func:`metasensor.depth.estimate_depth` its first span and the candidates of each fine sweep.

Hand-written (no library finds the disparity span of a light field).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from metasensor.depth import geometry
from metasensor.depth.cost import CostVolume
from metasensor.depth.refine import peak_ratio_confidence, subpixel_minimum
from metasensor.depth.sgm import normalise_costs, semi_global
from metasensor.depth.speckle import Speckles, speckle_mask

__all__ = ["MAX_SPAN", "SpanEstimate", "check_given_span", "initial_span", "measure_span",
           "saturation", "sweep_candidates", "widened"]

MAX_SPAN = 16.0  # view px per view step: the widest coarse search
COARSE_SIDE = 96  # coarse views at least this many px on their short side (thin structures)
CONFIDENT = 0.05  # peak-ratio confidence above which a coarse estimate counts
MAX_CANDIDATES = 1024  # plane-sweep disparities, at most
MIN_CANDIDATES = 64  # the automatic candidate count, at least
OUTER_STEP = 0.5  # automatic candidate spacing: the outermost view moves this many view px
COARSE_SATURATED = 0.01  # share of saturated coarse estimates above which a warning says so
SATURATED = 0.001  # share of confident pixels on an end of the span that widens or warns
SPAN_SPECKLE = 4  # coarse segments of at most this many pixels do not count for the span


@dataclass(frozen=True)
class SpanEstimate:
    """A measured disparity span.

    span : (low, high) view px per view step.
    searched : the coarse search span (low, high).
    saturated : share of the coarse pixels saturating an end of ``searched``
        (:func:`saturation`: the scene may hold larger disparities than any view-grid search can
        find).
    confident : share of the coarse pixels whose estimate was confident.
    beyond : shares (below, above) of the confident coarse estimates outside the span
        ``given`` to :func:`measure_span` (0 without one).
    """

    span: tuple[float, float]
    searched: tuple[float, float]
    saturated: float
    confident: float
    beyond: tuple[float, float] = (0.0, 0.0)


def _downsample(stack: torch.Tensor, f: int) -> torch.Tensor:
    if f <= 1:
        return stack
    return torch.nn.functional.avg_pool2d(stack[:, None], f, f)[:, 0]


def measure_span(stack: torch.Tensor, au, av, centre: int, minimum: tuple[float, float]
                 | None = None, occlusion: bool = True,
                 given: tuple[float, float] | None = None) -> SpanEstimate:
    """Disparity span [view px per view step] of views ``stack`` ``(N, H, W)`` (normalised),
    angular offsets ``au``, ``av`` ``(N,)`` and the centre view's index ``centre``.

    ``minimum``: a span the result always covers (e.g. a configuration's natural range), or
    None. ``given``: a span to check (``SpanEstimate.beyond``). The coarse sweep is the one of
    :class:`CostVolume` (variance, half-pupil occlusion handling), each pixel's cost curve
    normalised and regularised by :func:`metasensor.depth.sgm.semi_global`.
    """
    au = np.asarray(au, dtype=np.float64)
    av = np.asarray(av, dtype=np.float64)
    amax = float(max(np.abs(au).max(), np.abs(av).max(), 1.0))
    side = min(stack.shape[1:])
    f = int(max(1, min(4, side // COARSE_SIDE)))
    coarse = _downsample(stack, f)
    reach = min(MAX_SPAN, side / (4.0 * amax))
    step = 0.5 * f / amax
    k = int(np.ceil(reach / step))
    cands = np.arange(-k, k + 1, dtype=np.float64) * step
    with torch.no_grad():
        sweep = CostVolume(coarse, au, av, centre, reach / f, occlusion=occlusion)
        vol = sweep.volume(cands / f)
        normalise_costs(vol)
        vol = semi_global(vol)
        disp, idx = subpixel_minimum(vol, cands)
        conf = peak_ratio_confidence(vol, idx)
        sat = sum(saturation(vol[:, 2:-2, 2:-2], idx[2:-2, 2:-2]))
    b = 2  # the outermost coarse pixels: not counted
    speck = speckle_mask(disp, amax, Speckles(size=SPAN_SPECKLE, step=float(f)))
    if speck is None:
        speck = torch.zeros_like(disp, dtype=torch.bool)
    disp, idx, conf, speck = (t[b:-b, b:-b] for t in (disp, idx, conf, speck))
    good = conf > CONFIDENT
    share = float(good.float().mean())
    beyond = (0.0, 0.0)
    if int(good.sum()) < 16:  # nothing to go by: the whole searched span
        lo, hi = float(cands[0]), float(cands[-1])
    else:
        vals = disp[good].double().cpu().numpy()
        if given is not None:  # beyond by more than one coarse candidate step
            beyond = (float(np.mean(vals < given[0] - step)),
                      float(np.mean(vals > given[1] + step)))
        lo, hi = _covered(vals, disp[good & ~speck].double().cpu().numpy(), step)
        margin = 2 * step + 0.05 * float(hi - lo)
        lo, hi = float(lo) - margin, float(hi) + margin
        lo, hi = max(lo, float(cands[0])), min(hi, float(cands[-1]))
    if minimum is not None:
        lo, hi = min(lo, float(minimum[0])), max(hi, float(minimum[1]))
    if hi - lo < 2 * step:
        mid = 0.5 * (lo + hi)
        lo, hi = mid - step, mid + step
    return SpanEstimate(span=(lo, hi), searched=(float(cands[0]), float(cands[-1])),
                        saturated=sat, confident=share, beyond=beyond)


def _covered(vals: np.ndarray, solid: np.ndarray, step: float) -> tuple[float, float]:
    """The 0.2-99.8 percentiles of the confident coarse estimates ``vals``; a side moves to
    the percentile of the ``solid`` ones (speckles left out) where that lies inward by more
    than one coarse candidate ``step`` (where speckles alone stretch the span; elsewhere
    leaving them out only moves the percentile within its own sampling)."""
    lo, hi = (float(v) for v in np.percentile(vals, [0.2, 99.8]))
    if solid.size >= 16:
        slo, shi = (float(v) for v in np.percentile(solid, [0.2, 99.8]))
        lo = slo if slo - lo > step else lo
        hi = shi if hi - shi > step else hi
    return lo, hi


def saturation(cost: torch.Tensor, idx: torch.Tensor, steps: int = 3,
               drop: float = 0.05) -> tuple[float, float]:
    """Shares ``(low, high)`` of the pixels whose aggregated ``cost`` ``(K, H, W)`` is lowest at
    the first (last) candidate (winner ``idx``) and still falling there: at least ``drop``
    (relative) below the cost ``steps`` candidates inward. A flat cost curve (no texture) that
    happens to win at an end does not count; a minimum beyond the span does."""
    k = cost.shape[0]
    j = min(steps, k - 1)
    low = (idx == 0) & (cost[0] < (1 - drop) * cost[j])
    high = (idx == k - 1) & (cost[k - 1] < (1 - drop) * cost[k - 1 - j])
    n = float(idx.numel())
    return float(low.sum()) / n, float(high.sum()) / n


def sweep_candidates(span, candidates: int | None, amax: float) -> np.ndarray:
    """The plane-sweep disparities over ``span``.

    Parameters
    ----------
    span : (float, float)
        (low, high) view px per view step.
    candidates : int or None
        Their number; None: the outermost view moves ``OUTER_STEP`` view px per candidate
        (between ``MIN_CANDIDATES`` and ``MAX_CANDIDATES``).
    amax : float
        The largest view offset from the centre [view steps].

    Returns
    -------
    numpy.ndarray
        The candidates (:func:`metasensor.depth.geometry.disparity_candidates`).
    """
    if candidates is None:  # the outermost view moves OUTER_STEP view px per candidate
        width = float(span[1] - span[0])
        candidates = int(min(MAX_CANDIDATES, max(MIN_CANDIDATES,
                                                 math.ceil(width * amax / OUTER_STEP) + 1)))
    return geometry.disparity_candidates(span, candidates)


def widened(span, limit, low: float, high: float) -> tuple[float, float]:
    """The span grown by half its width on each saturated side, within ``limit``.

    Parameters
    ----------
    span, limit : (float, float)
        The swept span and the widest searched one, view px per view step.
    low, high : float
        Shares of the pixels saturating the low / high end (:func:`saturation`); a side grows
        where its share exceeds ``SATURATED``.

    Returns
    -------
    (float, float)
        The new span (equal to ``span`` where nothing grows).
    """
    lo, hi = span
    half = 0.5 * (hi - lo)
    if low > SATURATED:
        lo = max(lo - half, limit[0])
    if high > SATURATED:
        hi = min(hi + half, limit[1])
    return (lo, hi)


def initial_span(stack, au, av, centre, cfg, occlusion, disparity_range):
    """The span the first fine sweep of :func:`metasensor.depth.estimate_depth` covers.

    Parameters
    ----------
    stack : torch.Tensor
        The used views ``(V, H, W)``.
    au, av : numpy.ndarray
        Their offsets from the centre view [view steps].
    centre : int
        The centre view's index in ``stack``.
    cfg : SystemConfig
        The system (its default disparity range is the least the coarse search covers).
    occlusion : bool
        Half-pupil occlusion handling in the coarse search.
    disparity_range : (float, float) or None
        A given span [view px per view step], or None: measured (:func:`measure_span`).

    Returns
    -------
    span : (float, float)
        The span to sweep.
    limit : (float, float) or None
        The widest searched span (the bound of :func:`widened`), None for a given span.
    found : SpanEstimate
        The coarse search's result.

    Warns once (``RuntimeWarning``, at the caller of ``estimate_depth``) when more than
    ``COARSE_SATURATED`` of the coarse estimates saturate the widest search.
    """
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


def check_given_span(span, sat, beyond) -> tuple[float, float]:
    """The saturated shares below / above a given span.

    Parameters
    ----------
    span : (float, float)
        The given span [view px per view step].
    sat : (float, float)
        The final sweep's saturated shares (:func:`saturation`).
    beyond : (float, float)
        The coarse wide search's shares of confident estimates below / above ``span``
        (:attr:`SpanEstimate.beyond`).

    Returns
    -------
    (float, float)
        The larger of the two, per side. Warns once (``RuntimeWarning``, at the caller of
        ``estimate_depth``) when either exceeds ``SATURATED``.
    """
    sat = tuple(max(a, b) for a, b in zip(sat, beyond, strict=True))
    if max(sat) > SATURATED:
        warnings.warn(f"{100 * sat[0]:.1f} % / {100 * sat[1]:.1f} % of the scene lies "
                      f"below / above disparity_range {span} (coarse wide search): "
                      "widen it (or leave it to the default, measured)",
                      RuntimeWarning, stacklevel=3)
    return sat
