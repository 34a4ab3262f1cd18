"""Per-pixel evidence at depth edges for the learned edge refiner (:mod:`metasensor.depth.learned`).

For every pixel of a two-layer depth edge (:func:`metasensor.depth.edges.two_layer_pixels`:
the front, its 3 x 3 neighbourhood's lowest disparity ``dF``, and the background, the highest
``dB``) a ``(CHANNELS, PATCH, PATCH)`` stack of maps around it, each a scalar field so that a
rotation or mirror of the scene rotates or mirrors the stack:

0. the disparity map's label: ``(d − dF) / (dB − dF) − ½`` (clipped to ±1: −½ front, +½ back);
1. the centre view, less its mean over the patch, over its spread there;
2. - 4. the front's measured coverage of the footprint minus ½
   (:func:`metasensor.depth.edges.edge_coverage`), the same in standard errors (divided by 5,
   clipped to ±1), and where it is defined (1, else 0);
5. the estimator's confidence;
6. - 13. for each hypothesis (the front ``dF``, then the background ``dB``) the photo-consistency
   of the views aligned at it (cubic samples): their variance over the full pupil, over the
   half-pupil that sees the background clear and over the opposite one (the axis half-pupils
   nearest the edge normal, taken from the disparity map's Sobel gradient: views whose offset
   points from the front towards the background see past the front's edge), and the squared
   distance of their mean to the centre view; each divided by the mean of all eight over the
   patch, as ``log(x + 0.05)``;
14. - 15. constants: the jump ``(dB − dF)`` in outermost-view px over 8, the outermost view
    offset over 4.

Written here by hand (the model's inputs; no library computes them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from metasensor.depth.edges import EdgeSnap, edge_coverage, two_layer_pixels

__all__ = ["CHANNELS", "PATCH", "EdgeSamples", "edge_samples"]

PATCH = 7  # side of the patch around each edge pixel [view px]
CHANNELS = 16


@dataclass(frozen=True)
class EdgeSamples:
    """Edge pixels ``(ys, xs)`` (M,), their features ``(M, CHANNELS, PATCH, PATCH)``, the
    disparities they may take (``front``, ``back``: the mean of their 3 x 3 neighbours on that
    layer), the candidate layers ``lo`` / ``hi`` and whether they are on the front now."""

    ys: torch.Tensor
    xs: torch.Tensor
    features: torch.Tensor
    front: torch.Tensor
    back: torch.Tensor
    lo: torch.Tensor
    hi: torch.Tensor
    on_front: torch.Tensor


def _patch(img: torch.Tensor, ys, xs) -> torch.Tensor:
    """``(M, PATCH, PATCH)`` integer-offset patches of ``img (H, W)`` around ``(ys, xs)``,
    edges replicated."""
    h, w = img.shape
    r = torch.arange(PATCH, device=img.device) - PATCH // 2
    yy = (ys[:, None, None] + r[None, :, None]).clamp(0, h - 1)
    xx = (xs[:, None, None] + r[None, None, :]).clamp(0, w - 1)
    return img[yy, xx]


def _consistency(views, au, av, centre: int, ys, xs, d, clear) -> torch.Tensor:
    """``(4, M, PATCH, PATCH)``: variance of the views aligned at disparity ``d (M,)`` over the
    full pupil, over the half-pupil ``clear (M,)`` (0-3: top, bottom, left, right) and over the
    opposite one, squared distance of the mean to the centre view, on the patch around each
    pixel."""
    n, h, w = views.shape
    r = torch.arange(PATCH, dtype=views.dtype, device=views.device) - PATCH // 2
    py = ys.to(views.dtype)[:, None, None] + r[None, :, None]
    px = xs.to(views.dtype)[:, None, None] + r[None, None, :]
    shape = (ys.numel(), PATCH, PATCH)
    sums = torch.zeros((9, 2, *shape), dtype=views.dtype, device=views.device)
    count = torch.zeros(9, dtype=views.dtype, device=views.device)
    for i in range(n):
        sy = (py + d[:, None, None] * float(au[i])).expand(shape)
        sx = (px + d[:, None, None] * float(av[i])).expand(shape)
        grid = torch.stack([2 * sx / max(w - 1, 1) - 1, 2 * sy / max(h - 1, 1) - 1], -1)
        val = F.grid_sample(views[i][None, None], grid.reshape(1, 1, -1, 2), mode="bicubic",
                            padding_mode="border", align_corners=True).reshape(shape)
        g = int(3 * (np.sign(au[i]) + 1) + (np.sign(av[i]) + 1))
        sums[g, 0] += val
        sums[g, 1] += val * val
        count[g] += 1
    su, sv = np.divmod(np.arange(9), 3)
    groups = [np.arange(9), su <= 1, su >= 1, sv <= 1, sv >= 1]   # full, top, bottom, left, right
    var, mean = [], None
    for members in groups:
        idx = torch.as_tensor(np.nonzero(members)[0] if members.dtype == bool else members,
                              device=views.device)
        k = count[idx].sum().clamp(min=1)
        m1 = sums[idx, 0].sum(0) / k
        var.append((sums[idx, 1].sum(0) / k - m1 * m1).clamp(min=0))
        if mean is None:
            mean = m1
    halves = torch.stack(var[1:])                                  # (4, M, P, P)
    rows = torch.arange(ys.numel(), device=views.device)
    ref = _patch(views[centre], ys, xs)
    return torch.stack([var[0], halves[clear, rows], halves[clear ^ 1, rows], (mean - ref) ** 2])


def _clear_half(pad: torch.Tensor, ys, xs) -> torch.Tensor:
    """Index (0-3: top, bottom, left, right) of the axis half-pupil whose views see past the
    front at each edge pixel: the side the disparity map's Sobel gradient (towards the
    background) points to along its larger component."""
    sob = torch.tensor([[1.0, 2.0, 1.0]], dtype=pad.dtype, device=pad.device)
    dif = torch.tensor([[-1.0, 0.0, 1.0]], dtype=pad.dtype, device=pad.device)
    gy = F.conv2d(pad, (dif.T @ sob)[None, None])[0, 0][ys, xs]
    gx = F.conv2d(pad, (sob.T @ dif)[None, None])[0, 0][ys, xs]
    vertical = gy.abs() >= gx.abs()
    return torch.where(vertical, (gy > 0).long(), 2 + (gx > 0).long())


def edge_samples(views: torch.Tensor, au, av, disparity: torch.Tensor,
                 confidence: torch.Tensor, jump: float = 1.5) -> EdgeSamples | None:
    """The edge pixels of ``disparity`` whose front coverage the views measure
    (:func:`metasensor.depth.edges.edge_coverage` defined there) and their features (module
    docstring). Elsewhere (small or noisy steps of the map, pixels without a clear
    background) there is no evidence beyond the sweep's, and no sample.

    Parameters
    ----------
    views : ``(N, H, W)`` float32 tensor, the views used (normalised as for the sweep).
    au, av : view offsets ``u − c``, ``v − c`` ``(N,)``; one of them is the centre view (0, 0).
    disparity, confidence : ``(H, W)`` maps of the estimator [view px per view step; 0-1].
    jump : smallest depth edge [outermost-view px] (as :class:`metasensor.depth.EdgeSnap`).

    Returns
    -------
    EdgeSamples, or None where the map has no two-layer edge pixel.
    """
    au = np.asarray(au, dtype=np.float64)
    av = np.asarray(av, dtype=np.float64)
    amax = float(max(np.abs(au).max(), np.abs(av).max()))
    edge, lo, hi, pad = two_layer_pixels(disparity, jump, amax)
    if not bool(edge.any()):
        return None
    cover, error = edge_coverage(views, au, av, disparity, EdgeSnap(jump=jump))
    edge &= torch.isfinite(cover) & torch.isfinite(error)
    if not bool(edge.any()):
        return None
    ys, xs = torch.nonzero(edge, as_tuple=True)
    centre = int(np.nonzero((au == 0) & (av == 0))[0][0])
    lo_p, hi_p = lo[ys, xs], hi[ys, xs]
    gap = (hi_p - lo_p)[:, None, None]
    # the values a pixel may take: the mean of its 3 x 3 neighbours on that layer
    near = F.unfold(pad, 3)[0].reshape(9, *disparity.shape)[:, ys, xs]      # (9, M)
    is_front = (near - lo_p).abs() <= 0.25 * (hi_p - lo_p)
    front = (near * is_front).sum(0) / is_front.sum(0).clamp(min=1)
    back = (near * ~is_front).sum(0) / (~is_front).sum(0).clamp(min=1)
    d_own = disparity[ys, xs]
    on_front = (d_own - lo_p).abs() <= (hi_p - d_own).abs()
    feats = torch.zeros((ys.numel(), CHANNELS, PATCH, PATCH), dtype=views.dtype,
                        device=views.device)
    feats[:, 0] = ((_patch(disparity, ys, xs) - lo_p[:, None, None]) / gap - 0.5).clamp(-1, 1)
    cv = _patch(views[centre], ys, xs)
    cv = cv - cv.mean((1, 2), keepdim=True)
    spread = float(views[centre].std()) * 0.01 + 1e-12
    feats[:, 1] = cv / (cv.square().mean((1, 2), keepdim=True).sqrt() + spread)
    f, se = _patch(cover, ys, xs), _patch(error, ys, xs)
    defined = torch.isfinite(f) & torch.isfinite(se)
    zero = torch.zeros_like(f)
    feats[:, 2] = torch.where(defined, (f - 0.5).clamp(-1, 1), zero)
    z = (f - 0.5) / se.clamp(min=1e-6) / 5
    feats[:, 3] = torch.where(defined, z.clamp(-1, 1), zero)
    feats[:, 4] = defined.to(views.dtype)
    feats[:, 5] = _patch(confidence, ys, xs)
    clear = _clear_half(pad, ys, xs)
    costs = torch.cat([_consistency(views, au, av, centre, ys, xs, lo_p, clear),
                       _consistency(views, au, av, centre, ys, xs, hi_p, clear)])  # (8, M, P, P)
    scale = costs.mean((0, 2, 3), keepdim=True) + 1e-12
    feats[:, 6:14] = torch.log(costs / scale + 0.05).transpose(0, 1)
    feats[:, 14] = ((hi_p - lo_p) * amax / 8)[:, None, None]
    feats[:, 15] = amax / 4
    return EdgeSamples(ys, xs, feats, front, back, lo_p, hi_p, on_front)
