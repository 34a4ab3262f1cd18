"""Pooling the learned edge refiner's evidence along long straight depth edges.

The refiner (:mod:`metasensor.depth.learned`) decides each depth-edge pixel from a 7 x 7 patch.
Along a straight edge every pixel of the column (row, diagonal) that the edge crosses has the
same share of its footprint covered by the front layer, so they all belong to the same layer;
but the local evidence of that share drifts with the textures on either side (the background's
estimate is blurred by an amount that varies along the edge, :mod:`metasensor.depth.edges`), and
the patch-wise decisions flip in runs of 10-20 pixels where the share is near one half.

Model: a *straight run* is a set of consecutive pixels along one of the four grid orientations
(tangent ``t``, normal ``n``: rows, columns, diagonals) whose neighbours across the edge,
``p − n`` and ``p + n``, lie on different layers of the pixel's 3 x 3 neighbourhood and keep
those layers along the run (the map's edge stays within one pixel of the same line, whatever
the run's own pixels are labelled), the two layers' disparities changing by at most ``step``
from one pixel of the run to the next (a slanted layer changes slowly; another object's layer
meeting the edge ends the run). Where such a run is at least ``2 L + 1`` pixels long, every
refiner sample on it takes the mean of the clipped logits of the samples within ``±2 L`` along
it instead of its own; elsewhere (curved edges, corners, short or broken runs) its own logit
is kept. The assumption is that the share is constant along the run: an edge at a small angle
``θ`` to the grid also stays in one column for up to ``1 / tan θ`` pixels while its share there
changes, and such a run is pooled too (``docs/decisions.md`` has what that costs on scenes with
edges at every angle).

Written here by hand (a run-length vote along the edge; no library does this for a disparity
map); the refiner's choice between the two layers stays the network's, now on more evidence.
"""

from __future__ import annotations

import torch

__all__ = ["pool_along_runs"]

# (normal, tangent) of the four grid orientations: columns, rows, the two diagonals
_ORIENTATIONS = (((0, 1), (1, 0)), ((1, 0), (0, 1)), ((1, 1), (1, -1)), ((1, -1), (1, 1)))


def _side(disp: torch.Tensor, ys, xs, lo, hi) -> torch.Tensor:
    """The layer of the map at ``(ys, xs)`` between ``lo`` and ``hi`` (per point): 1 front
    (within a quarter of their gap of ``lo``), 0 back (of ``hi``), −1 neither or outside the
    map."""
    h, w = disp.shape
    inside = (ys >= 0) & (ys < h) & (xs >= 0) & (xs < w)
    d = disp[ys.clamp(0, h - 1), xs.clamp(0, w - 1)]
    tol = 0.25 * (hi - lo)
    lab = torch.where((d - lo).abs() <= tol, 1, torch.where((d - hi).abs() <= tol, 0, -1))
    return torch.where(inside, lab, torch.full_like(lab, -1))


def pool_along_runs(disparity: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor,
                    ys: torch.Tensor, xs: torch.Tensor, logit: torch.Tensor, length: int,
                    step: float, clip: float = 4.0) -> torch.Tensor:
    """The refiner's logits pooled along long straight runs of the depth edge (module
    docstring).

    Parameters
    ----------
    disparity : ``(H, W)`` map the samples were taken on [view px per view step].
    lo, hi : ``(H, W)`` the lowest / highest disparity of each pixel's 3 x 3 neighbourhood
        (:func:`metasensor.depth.edges.two_layer_pixels`).
    ys, xs : ``(M,)`` long tensors, the refiner's sample pixels.
    logit : ``(M,)`` the network's logit of "the pixel is the front".
    length : ``L``: runs of at least ``2 L + 1`` pixels are pooled, over ``±2 L`` pixels;
        0 returns ``logit`` unchanged.
    step : largest change of either layer's disparity between neighbouring pixels of a run
        [view px per view step].
    clip : each logit is clipped to ``±clip`` before the mean (one confident sample must not
        outvote its run).

    Returns
    -------
    torch.Tensor ``(M,)``: the pooled logit where the sample lies on a long straight run (the
    first orientation, in the order columns, rows, diagonals, that has one), else ``logit``.
    """
    if length <= 0 or ys.numel() == 0:
        return logit
    h, w = disparity.shape
    lmap = torch.full((h, w), float("nan"), dtype=logit.dtype, device=logit.device)
    lmap[ys, xs] = logit.clamp(-clip, clip)
    out = logit.clone()
    done = torch.zeros(ys.shape, dtype=torch.bool, device=ys.device)
    for (ny, nx), (ty, tx) in _ORIENTATIONS:
        a0 = _side(disparity, ys - ny, xs - nx, lo[ys, xs], hi[ys, xs])
        b0 = _side(disparity, ys + ny, xs + nx, lo[ys, xs], hi[ys, xs])
        straddle = (a0 >= 0) & (b0 >= 0) & (a0 != b0) & ~done
        if not bool(straddle.any()):
            continue
        total = torch.where(torch.isfinite(lmap[ys, xs]), lmap[ys, xs], torch.zeros_like(logit))
        count = torch.isfinite(lmap[ys, xs]).to(logit.dtype)
        extent = torch.zeros_like(logit)
        for sign in (1, -1):
            alive = straddle.clone()
            lo_q, hi_q = lo[ys, xs], hi[ys, xs]
            for j in range(1, 2 * length + 1):
                qy, qx = ys + sign * j * ty, xs + sign * j * tx
                alive &= (qy >= 0) & (qy < h) & (qx >= 0) & (qx < w)
                qy, qx = qy.clamp(0, h - 1), qx.clamp(0, w - 1)
                lo_n, hi_n = lo[qy, qx], hi[qy, qx]
                alive &= ((lo_n - lo_q).abs() <= step) & ((hi_n - hi_q).abs() <= step)
                lo_q, hi_q = lo_n, hi_n
                alive &= ((_side(disparity, qy - ny, qx - nx, lo_n, hi_n) == a0)
                          & (_side(disparity, qy + ny, qx + nx, lo_n, hi_n) == b0))
                if not bool(alive.any()):
                    break
                v = lmap[qy, qx]
                use = alive & torch.isfinite(v)
                total += torch.where(use, v, torch.zeros_like(v))
                count += use.to(logit.dtype)
                extent += alive.to(logit.dtype)
        pooled = straddle & (extent >= 2 * length) & (count > 0)
        out = torch.where(pooled, total / count.clamp(min=1), out)
        done |= pooled
    return out
