"""From a cost volume to a disparity map: winner-take-all, sub-pixel refinement, confidence,
continuous (Gauss–Newton) refinement on the views, and confidence-weighted filling.

Written here by hand (no library offers these for light-field view stacks).
"""

from __future__ import annotations

import numpy as np
import torch

from metasensor.depth.cost import _half_members, _sectors
from metasensor.depth.filters import GuidedFilter, box_mean

OCCLUDED_RATIO = 0.5
"""A half-pupil refines a pixel only where its window-aggregated variance is below this share
of the full pupil's."""

__all__ = ["subpixel_minimum", "peak_ratio_confidence", "gauss_newton_refine",
           "fill_low_confidence"]


def subpixel_minimum(cost: torch.Tensor, candidates) -> tuple[torch.Tensor, torch.Tensor]:
    """Winner-take-all over ``cost (K, H, W)`` plus a parabola through the minimum and its two
    neighbours; returns ``(disparity (H, W), winner index (H, W))``.

    The parabola vertex offset ``(c₋ − c₊) / (2 (c₋ − 2c₀ + c₊))`` is clipped to ±0.5 candidate
    steps; at the ends of the range the winner is kept as is. Candidates must be equally spaced.
    """
    cands = torch.as_tensor(np.asarray(candidates, dtype=np.float32), device=cost.device)
    k = cost.shape[0]
    step = float(cands[1] - cands[0])
    idx = torch.argmin(cost, dim=0)
    lo = torch.clamp(idx - 1, min=0)
    hi = torch.clamp(idx + 1, max=k - 1)
    c0 = torch.gather(cost, 0, idx[None])[0]
    cm = torch.gather(cost, 0, lo[None])[0]
    cp = torch.gather(cost, 0, hi[None])[0]
    den = cm - 2 * c0 + cp
    off = torch.where(den > 0, (cm - cp) / (2 * den.clamp(min=1e-30)), torch.zeros_like(den))
    off = torch.clamp(off, -0.5, 0.5)
    inner = (idx > 0) & (idx < k - 1)
    off = torch.where(inner, off, torch.zeros_like(off))
    return cands[idx] + off * step, idx


def peak_ratio_confidence(cost: torch.Tensor, idx: torch.Tensor, exclude: int = 2) -> torch.Tensor:
    """Confidence in [0, 1]: ``1 − c_best / c_second``, where ``c_second`` is the lowest cost more
    than ``exclude`` candidates away from the winner (the naive peak-ratio, PKRN, of Hu & Mordohai,
    TPAMI 2012). Flat cost curves (no texture) → 0; one clear, deep minimum → 1."""
    k = cost.shape[0]
    ks = torch.arange(k, device=cost.device)[:, None, None]
    far = (ks - idx[None]).abs() > exclude
    c1 = torch.gather(cost, 0, idx[None])[0]
    c2 = torch.where(far, cost, torch.full_like(cost, float("inf"))).amin(0)
    conf = 1.0 - c1 / torch.clamp(c2, min=1e-30)
    conf = torch.where(torch.isfinite(c2), conf, torch.zeros_like(conf))
    return torch.clamp(conf, 0.0, 1.0)


def _grid(h: int, w: int, device) -> tuple[torch.Tensor, torch.Tensor]:
    ys = torch.arange(h, dtype=torch.float32, device=device)[:, None].expand(h, w)
    xs = torch.arange(w, dtype=torch.float32, device=device)[None, :].expand(h, w)
    return ys, xs


def _with_gradients(v: torch.Tensor) -> torch.Tensor:
    """Stack ``(m, 3, H, W)`` of the views and their central-difference gradients (y, x)."""
    out = torch.zeros((v.shape[0], 3, *v.shape[1:]), dtype=v.dtype, device=v.device)
    out[:, 0] = v
    out[:, 1, 1:-1] = 0.5 * (v[:, 2:] - v[:, :-2])
    out[:, 2, :, 1:-1] = 0.5 * (v[:, :, 2:] - v[:, :, :-2])
    return out


def gauss_newton_refine(views: torch.Tensor, au, av, disparity: torch.Tensor,
                        aggregate, iterations: int = 2, max_change: float = 0.1,
                        occlusion: bool = False, chunk: int = 8) -> torch.Tensor:
    """Refine a disparity map continuously by Gauss–Newton on the aggregated view variance.

    With ``W_i(δ) = V_i(p + δ a_i)`` (bilinear) and ``g_i = ∇V_i(p + δ a_i) · a_i = ∂W_i/∂δ``, one
    step is ``Δδ = − A[Σ_i (g_i − ḡ)(W_i − W̄)] / A[Σ_i (g_i − ḡ)²]`` (sums over the views of a
    group, divided by their number), ``A`` the aggregation (the same guided filter as the cost
    volume). This removes the plane sweep's sampling of ``δ``. Bilinear, not bicubic: linear
    interpolation errs only in amplitude, symmetrically in the fractional shift, so the errors of
    the views at ``±a`` cancel in the normal equations; torch's bicubic (Keys, a = −0.75) is only
    first-order accurate in position, a bias the normal equations keep.
    With ``occlusion`` a pixel uses one of the four half-pupils only where the views disagree
    across the full pupil: the half whose aggregated variance is the least, if that is below
    ``OCCLUDED_RATIO`` times the full pupil's (an occluder seen by the other half), else the
    full pupil; decided once, at the input disparities. A half-pupil's views all lie on one
    side of the centre, so its fit errs more (half the views; on a slanted surface it reads the
    disparity where its mean view offset looks, and its views' interpolation errors do not
    cancel in ± pairs). The total change is clipped to ``±max_change`` view px around the
    input (the plane sweep decides the basin); pixels where the normal matrix vanishes (no
    texture) keep their value.
    """
    n, h, w = views.shape
    dev = views.device
    au = np.asarray(au, dtype=np.float64)
    av = np.asarray(av, dtype=np.float64)
    au_t = torch.as_tensor(au, dtype=torch.float32, device=dev)
    av_t = torch.as_tensor(av, dtype=torch.float32, device=dev)
    sector = torch.as_tensor(_sectors(au, av), device=dev)
    count = np.bincount(_sectors(au, av), minlength=9).astype(np.float64)
    groups = [[s for s in range(9) if count[s] > 0]]
    if occlusion:
        for members in _half_members().values():
            members = [s for s in members if count[s] > 0]
            if count[members].sum() >= 2:
                groups.append(members)
    ys, xs = _grid(h, w, dev)
    d0 = disparity.clone().to(torch.float32)
    d = d0.clone()
    choice = None
    for _ in range(int(iterations)):
        # per-sector sums of W, g, W², gW, g²: (5, 9, H, W)
        sums = torch.zeros((5, 9, h, w), dtype=torch.float32, device=dev)
        for start in range(0, n, chunk):
            sl = slice(start, min(n, start + chunk))
            py = ys[None] + d[None] * au_t[sl, None, None]
            px = xs[None] + d[None] * av_t[sl, None, None]
            grid = torch.stack([2 * px / max(w - 1, 1) - 1, 2 * py / max(h - 1, 1) - 1], dim=-1)
            stack = _with_gradients(views[sl])  # (m, 3, H, W): V, ∂V/∂y, ∂V/∂x
            smp = torch.nn.functional.grid_sample(stack, grid, mode="bilinear",
                                                  padding_mode="border", align_corners=True)
            wv = smp[:, 0]
            gv = smp[:, 1] * au_t[sl, None, None] + smp[:, 2] * av_t[sl, None, None]
            terms = torch.stack([wv, gv, wv * wv, gv * wv, gv * gv], dim=0)  # (5, m, H, W)
            sums.index_add_(1, sector[sl], terms)
        if choice is None:  # decided once, at the sweep's disparities
            choice = _pupil_choice(sums, groups, count, aggregate)
        num, den = _normal_terms(sums, groups, count, choice)
        num = aggregate(num)
        den = aggregate(den)
        ok = den > 1e-12 * torch.clamp(den.abs().max(), min=1e-30)
        step = torch.where(ok, -num / torch.where(ok, den, torch.ones_like(den)),
                           torch.zeros_like(den))
        d = torch.clamp(d + step, d0 - max_change, d0 + max_change)
    return d


def _group_moments(sums: torch.Tensor, members: list[int], count: np.ndarray):
    """A view group's variance of the aligned views, and its normal-equation numerator and
    denominator ``(Σ(g − ḡ)(W − W̄), Σ(g − ḡ)²) / m``, from the per-sector sums."""
    m = float(count[members].sum())
    s_w, s_g, s_ww, s_gw, s_gg = sums[:, members].sum(1)
    return ((s_ww - s_w * s_w / m) / m, (s_gw - s_g * s_w / m) / m,
            (s_gg - s_g * s_g / m) / m)


def _pupil_choice(sums: torch.Tensor, groups: list, count: np.ndarray,
                  aggregate) -> torch.Tensor:
    """Per pixel, the index into ``groups`` (0: the full pupil) of the view group to refine
    with: the half-pupil of least aggregated variance where that is below ``OCCLUDED_RATIO``
    times the full pupil's, else the full pupil."""
    full = aggregate(_group_moments(sums, groups[0], count)[0])
    best = full
    choice = torch.zeros(full.shape, dtype=torch.long, device=full.device)
    for k, members in enumerate(groups[1:], start=1):
        var = aggregate(_group_moments(sums, members, count)[0])
        better = (var < best) & (var < OCCLUDED_RATIO * full)
        best = torch.where(better, var, best)
        choice = torch.where(better, torch.full_like(choice, k), choice)
    return choice


def _normal_terms(sums: torch.Tensor, groups: list, count: np.ndarray,
                  choice: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The normal equations' numerator and denominator of each pixel's chosen view group."""
    num = den = None
    for k, members in enumerate(groups):
        _, g_num, g_den = _group_moments(sums, members, count)
        if num is None:
            num, den = g_num, g_den
        else:
            num = torch.where(choice == k, g_num, num)
            den = torch.where(choice == k, g_den, den)
    return num, den


def fill_low_confidence(disparity: torch.Tensor, confidence: torch.Tensor, guide: torch.Tensor,
                        radius: int, threshold: float = 0.1, eps: float = 0.01,
                        agree: float = 0.15) -> torch.Tensor:
    """Replace weak pixels (``confidence < threshold``: no texture) by an edge-aware,
    confidence-weighted average of the confident ones around them, ``GF(w δ) / GF(w)``, with
    ``w = confidence`` on confident pixels and 0 elsewhere and ``GF`` a guided filter of the given
    radius steered by the centre view. Only where those confident neighbours agree (weighted
    standard deviation within the radius below ``agree`` view px): a weak pixel between surfaces
    at different depths (an occlusion edge) keeps its own value rather than an average that
    belongs to neither. Confident pixels are returned unchanged."""
    r = max(1, int(radius))
    gf = GuidedFilter(guide, radius=r, eps=eps)
    weak = confidence < threshold
    wgt = torch.where(weak, torch.zeros_like(confidence), confidence)
    den = gf(wgt)
    num = gf(disparity * wgt)
    reach = den > 0.05 * torch.clamp(wgt.max(), min=1e-12)
    filled = torch.where(reach, num / torch.where(reach, den, torch.ones_like(den)), disparity)
    # agreement of the confident neighbours (plain box weights: always non-negative)
    bw = torch.clamp(box_mean(wgt, r), min=1e-12)
    m1 = box_mean(wgt * disparity, r) / bw
    m2 = box_mean(wgt * disparity * disparity, r) / bw
    spread = torch.sqrt(torch.clamp(m2 - m1 * m1, min=0.0))
    return torch.where(weak & reach & (spread < agree), filled, disparity)
