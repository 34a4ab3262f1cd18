"""The disparity span of a light field, measured from the views (coarse wide plane sweep), and
the saturation test of an estimate against its span.

A plane sweep only finds disparities inside its candidate span; an estimate outside it is
clipped to the nearest end, which looks like a valid answer. So the span is found first: the
views are box-downsampled by ``f`` <= 4 (coarse side about 96 px or more); a plane sweep covers
every disparity the views can show (the outermost view moves by at most a quarter of the view
side, and by at most :data:`MAX_SPAN` view px per view step), with candidates half a coarse
pixel apart at the outermost view; the span is what the confident coarse estimates cover
(0.2-99.8 percentiles) plus a margin of two coarse candidate steps and 5 % of that width.
After the fine sweep, :func:`saturation` says how much of the estimate still falls at an end
of the span (then the span is widened, or, when it was given, a warning says so).

Hand-written (no library finds the disparity span of a light field).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from metasensor.depth.cost import CostVolume
from metasensor.depth.refine import peak_ratio_confidence, subpixel_minimum
from metasensor.depth.sgm import normalise_costs, semi_global

__all__ = ["MAX_SPAN", "SpanEstimate", "measure_span", "saturation"]

MAX_SPAN = 16.0  # view px per view step: the widest coarse search
COARSE_SIDE = 96  # coarse views at least this many px on their short side (thin structures)
CONFIDENT = 0.05  # peak-ratio confidence above which a coarse estimate counts


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
    disp, idx, conf = (t[b:-b, b:-b] for t in (disp, idx, conf))
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
        lo, hi = np.percentile(vals, [0.2, 99.8])
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
