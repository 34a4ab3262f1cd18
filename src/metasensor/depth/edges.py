"""Re-deciding the pixels at occlusion edges by the front layer's measured coverage.

At a depth edge the plane-sweep costs (:mod:`metasensor.depth.cost`) compare "the pixel is the
front layer" with "the pixel is the background" over all views, but only the views along the
edge see the pixel's own mix of the two; the others see the background clear or the front over
a moving background. Pixels whose lenslet footprint a front layer covers by a share ``f`` near
one half are then given to either layer almost at random, while the truth (the layer at the
pixel centre) is the front exactly when ``f > 1/2`` (for a straight edge through the footprint).

The coverage is measured instead (two-layer "over" model, geometric optics). With the front at
disparity ``dF``, the background at ``dB`` (``Δ = dF − dB``) and ``a`` a view offset along the
edge (so that shifting by ``dF · a`` keeps the pixel's coverage ``f``), the front-aligned
samples are

    V_a(p + dF · a) = F_f(p) + (1 − f) · B(p + Δ · a),

linear in the background ``B`` with slope ``1 − f``. ``B`` at those points is read where no
front covers it: the mean of the views whose offset moves the front away from the point by at
least ``margin`` view pixels (the background-aligned samples ``V_a'(q + dB · a')``). The slope
is the least-squares one of the samples of all pixels within ``length`` pixels along the edge
(same edge orientation and layers), which for a straight or gently curved edge share ``f``.
The pixel is then given the front's disparity (the lowest in its 3 x 3 neighbourhood) where the
coverage exceeds one half, and the background's (the highest) where it falls below.

Sign convention (:mod:`metasensor.depth.geometry`): a larger disparity is farther, so the front
layer of an edge is the lower disparity. Edges are handled along four orientations (the rows,
columns and diagonals of the view grid, along which the views lie exactly); the edge normal is
taken from the disparity map's gradient.

Written here by hand: no library estimates sub-pixel occlusion coverage from light-field views.
It is a local two-layer matting model (cf. the "over" compositing of Porter & Duff 1984 and the
layered light-field models of Wanner & Goldluecke, CVPR 2012), not a global optimisation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from metasensor.depth.filters import sample_at

__all__ = ["EdgeSnap", "edge_coverage", "snap_edges"]

# tangent directions (dy, dx) of the four edge orientations; the edge normal is perpendicular
_TANGENTS = ((1, 0), (0, 1), (1, -1), (1, 1))
GAP = 3  # a run along an edge survives this many pixels in a row that do not match


@dataclass(frozen=True)
class EdgeSnap:
    """Settings of :func:`snap_edges`.

    jump : smallest depth edge handled: the two layers' disparities must move the outermost
        view by at least this many view px apart (smaller steps leave no clear background).
    margin : the background is read in the views that move the front at least this far from
        the point [view px] (the footprint's radius plus the pixel's own distance to the edge).
    length : half-length [px] of the stretch along the edge whose samples share one slope.
    certainty : the measured coverage must differ from one half by at least this many of its
        standard errors (least squares), or the pixel is left as is.
    long_length : half-length of a second, longer stretch, used where its coverage agrees
        with the short one's within one standard error (long straight edges).
    iterations : passes (a pixel given to the other layer makes its neighbour an edge pixel).
    """

    jump: float = 1.5
    margin: float = 2.0
    length: int = 4
    certainty: float = 2.0
    long_length: int = 32
    iterations: int = 4

    def __post_init__(self) -> None:
        for name in ("jump", "margin", "certainty"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and 0 < value < float("inf")):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        for name, low in (("length", 0), ("long_length", 0), ("iterations", 1)):
            value = getattr(self, name)
            if not (isinstance(value, int) and low <= value <= 64):
                raise ValueError(f"{name} must be an integer in [{low}, 64], got {value!r}")


def _sample(img: torch.Tensor, y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Cubic-convolution samples (a = −0.75, torch's bicubic) of ``img (H, W)`` at the points
    ``(y, x)`` (any equal shapes), edges replicated."""
    return sample_at(img, y, x, mode="bicubic")


def _slopes(views, au, av, ys, xs, lo, hi, normal, tangent, margin, nearest, farthest):
    """Per edge pixel (index arrays ``ys, xs``): the sums ``Σ (B − B̄)(V − V̄)``, ``Σ (B − B̄)²``
    of the front-aligned samples ``V`` against the clear background ``B`` along the views on
    the line ``tangent`` through the centre."""
    ty, tx = tangent
    on_line = [i for i in range(au.size) if au[i] * tx == av[i] * ty]
    dfront, dback = lo, hi
    delta = dfront - dback                                         # < 0
    y0, x0 = ys.float(), xs.float()
    vs, qs = [], []
    for i in on_line:
        # the front-aligned sample (the front point p, its coverage unchanged) and the
        # background point it sees
        vs.append(_sample(views[i], y0 + dfront * float(au[i]), x0 + dfront * float(av[i])))
        qs.append((y0 + delta * float(au[i]), x0 + delta * float(av[i])))
    vs = torch.stack(vs)                                           # (K, M)
    qy = torch.stack([q[0] for q in qs])                           # (K, M)
    qx = torch.stack([q[1] for q in qs])
    h, w = nearest.shape
    # the background's own disparity near each point (a slanted background), and the point
    # that view sample sees with it: Q + d_B(Q) a = p + dF a
    aus = torch.tensor([float(au[i]) for i in on_line], dtype=vs.dtype, device=vs.device)[:, None]
    avs = torch.tensor([float(av[i]) for i in on_line], dtype=vs.dtype, device=vs.device)[:, None]
    dq = farthest[torch.round(qy).long().clamp(0, h - 1), torch.round(qx).long().clamp(0, w - 1)]
    dq = torch.where((dq - dback).abs() <= 0.25 * (dback - dfront), dq, dback.expand_as(dq))
    qy = y0[None] + (dfront[None] - dq) * aus
    qx = x0[None] + (dfront[None] - dq) * avs
    delta = dfront[None] - dq                                      # (K, M), < 0
    bsum = torch.zeros_like(vs)
    count = torch.zeros_like(vs)
    ny, nx = normal                                                # towards the background
    mid = 0.5 * (dfront + dback)
    for j in range(au.size):
        # the front covering background point q in view j lies at q − Δ a_j: clear when that
        # is at least `margin` px further towards the background side, and when no pixel of
        # the map within one pixel of that point is nearer than halfway to the front
        away = -delta * (float(au[j]) * ny[None] + float(av[j]) * nx[None]) >= margin
        if not bool(away.any()):
            continue
        cy = torch.round(qy - delta * float(au[j])).long().clamp(0, h - 1)
        cx = torch.round(qx - delta * float(av[j])).long().clamp(0, w - 1)
        clear = (away & (nearest[cy, cx] > mid[None])).to(vs.dtype)
        count += clear
        bsum += clear * _sample(views[j], qy + dq * float(au[j]), qx + dq * float(av[j]))
    # every sample needs its background read at least once
    ok = (count > 0).all(0)
    b = bsum / count.clamp(min=1)
    b = b - b.mean(0, keepdim=True)
    v = vs - vs.mean(0, keepdim=True)
    zero = torch.zeros_like(dfront)
    sxy = torch.where(ok, (b * v).sum(0), zero)
    sxx = torch.where(ok, (b * b).sum(0), zero)
    syy = torch.where(ok, (v * v).sum(0), zero)
    return sxy, sxx, syy, len(on_line)


def _along(values: torch.Tensor, key: torch.Tensor, ys, xs, shape, tangent, length: int,
           tol: torch.Tensor) -> torch.Tensor:
    """Moments ``Σ_j j^m · values(p + j · tangent)`` (m = 0, 1, 2; ``(3, C, M)``) at the M
    pixels ``(ys, xs)`` with ``values (C, M)``, over the run ``|j| <= length`` of those pixels
    whose ``key (C', M)`` matches that of ``p`` within ``tol (M,)``, from ``p`` on each side
    until more than ``GAP`` pixels in a row do not match (or the image ends)."""
    ty, tx = tangent
    h, w = shape
    index = torch.full((h, w), -1, dtype=torch.long, device=values.device)
    index[ys, xs] = torch.arange(ys.numel(), device=values.device)
    total = torch.zeros((3, *values.shape), dtype=values.dtype, device=values.device)
    total[0] = values
    for sign in (1, -1):
        misses = torch.zeros(ys.shape, dtype=torch.int32, device=values.device)
        for s in range(1, length + 1):
            qy, qx = ys + sign * s * ty, xs + sign * s * tx
            inside = (qy >= 0) & (qy < h) & (qx >= 0) & (qx < w)
            j_idx = torch.where(inside, index[qy.clamp(0, h - 1), qx.clamp(0, w - 1)], -1)
            other = j_idx.clamp(min=0)
            match = (j_idx >= 0) & ((key[:, other] - key).abs().amax(0) <= tol)
            alive = misses <= GAP
            run = match & alive
            misses = torch.where(match, torch.zeros_like(misses), misses + 1)
            misses = torch.where(alive, misses, torch.full_like(misses, GAP + 1))
            if not bool(alive.any()):
                break
            other_v = values[:, other] * run[None]
            j = float(sign * s)
            total[0] += other_v
            total[1] += j * other_v
            total[2] += j * j * other_v
    return total


def _common_slope(mom: torch.Tensor, k: int):
    """Slope at ``j = 0`` of the samples along the edge, the slope varying linearly with the
    position ``j`` along it (a tilted or curved edge changes the coverage), and its standard
    error; ``mom`` from :func:`_along` of the channels ``(sxy, sxx, syy, 1)``."""
    (sxy0, sxx0, syy0, n0), (sxy1, sxx1, _, _), (_, sxx2, _, _) = mom[:, :4]
    det = sxx0 * sxx2 - sxx1 * sxx1
    lone = det <= 1e-12 * sxx0 * sxx0.clamp(min=1e-30) + 1e-30   # one pixel: constant slope
    a_lin = (sxy0 * sxx2 - sxy1 * sxx1) / det.clamp(min=1e-30)
    b_lin = (sxx0 * sxy1 - sxx1 * sxy0) / det.clamp(min=1e-30)
    a_one = sxy0 / sxx0.clamp(min=1e-30)
    a = torch.where(lone, a_one, a_lin)
    rss = torch.where(lone, syy0 - a_one * sxy0, syy0 - a_lin * sxy0 - b_lin * sxy1)
    var_a = torch.where(lone, 1 / sxx0.clamp(min=1e-30), sxx2 / det.clamp(min=1e-30))
    dof = (n0 * (k - 1) - torch.where(lone, 1.0, 2.0)).clamp(min=1)
    return a, (rss.clamp(min=0) / dof * var_a).sqrt()


def _coverage(part, prof, tangent, length: int, tol, k: int, ys, xs, shape):
    """The front coverage at the pixels ``(ys, xs)`` from their sums ``part (6, M)`` of
    :func:`_one_pass` over their runs along ``tangent``: ``(f, standard error, defined)``."""
    mom = _along(part, prof, ys, xs, shape, tangent, length, tol)
    slope, se = _common_slope(mom, k)
    # the background's own slope against its estimate (1 but for the estimate's blur)
    rxy, rxx = mom[0, 4], mom[0, 5]
    gain = torch.where(rxx > 0, rxy / rxx.clamp(min=1e-30), torch.ones_like(rxx))
    gain = gain.clamp(0.8, 1.5)
    ok = (mom[0, 1] > 0) & (mom[0, 3] * k > 2)
    return 1 - slope / gain, se / gain, ok


def two_layer_pixels(disp: torch.Tensor, jump: float, amax: float):
    """Depth-edge pixels between two layers: ``(edge, lo, hi, padded)`` with ``lo`` / ``hi``
    the lowest / highest disparity of each pixel's 3 x 3 neighbourhood (``(H, W)`` each),
    ``edge`` where they move the outermost view (offset ``amax``) by at least ``jump`` view px
    apart, every value of the 3 x 3 lies within a quarter of their gap of one of them and the
    pixel itself on one of them (not a third layer between), and ``padded`` the map
    replicate-padded by one pixel ``(1, 1, H + 2, W + 2)``."""
    pad = F.pad(disp[None, None], (1, 1, 1, 1), mode="replicate")
    lo = -F.max_pool2d(-pad, 3, stride=1)[0, 0]
    hi = F.max_pool2d(pad, 3, stride=1)[0, 0]
    edge = (hi - lo) * amax >= jump
    near = F.unfold(pad, 3)[0].reshape(9, *disp.shape)
    gap = 0.25 * (hi - lo)
    edge &= (torch.minimum((near - lo).abs(), (near - hi).abs()) <= gap).all(0)
    own = torch.minimum((disp - lo).abs(), (disp - hi).abs())
    edge &= own <= torch.clamp(gap, max=0.5 * jump / amax)
    return edge, lo, hi, pad


def _one_pass(views, au, av, disp, opts: EdgeSnap, amax: float, allowed=None):
    """One pass of :func:`snap_edges`: the new disparity, the number of pixels changed, the
    measured front coverage and its standard error (NaN off the edges and where undefined)."""
    edge, lo, hi, pad = two_layer_pixels(disp, opts.jump, amax)
    if allowed is not None:
        edge &= allowed
    gap = 0.25 * (hi - lo)
    if not bool(edge.any()):
        return disp, 0, torch.full_like(disp, float("nan")), torch.full_like(disp, float("nan"))
    # Sobel gradient (a pixel touching the other layer only at a corner still gets a normal)
    sob = torch.tensor([[1.0, 2.0, 1.0]], dtype=disp.dtype, device=disp.device)
    dif = torch.tensor([[-1.0, 0.0, 1.0]], dtype=disp.dtype, device=disp.device)
    gy = F.conv2d(pad, (dif.T @ sob)[None, None])[0, 0]
    gx = F.conv2d(pad, (sob.T @ dif)[None, None])[0, 0]
    edge &= (gy.abs() + gx.abs()) > 0  # a 3 x 3 spanning two layers without a gradient: kept
    ang = torch.atan2(gy, gx)                    # direction of increasing disparity
    sector = torch.remainder(torch.round(ang / (np.pi / 4)), 4).long()  # 0: x, 1: diag, 2: y
    # sector of the normal -> index of the tangent in _TANGENTS and the normal's unit vector
    normal_of = {0: (0.0, 1.0), 1: (2 ** -0.5, 2 ** -0.5), 2: (1.0, 0.0),
                 3: (2 ** -0.5, -(2 ** -0.5))}
    tangent_of = {0: _TANGENTS[0], 1: _TANGENTS[2], 2: _TANGENTS[1], 3: _TANGENTS[3]}
    h, w = disp.shape
    frac = torch.full((h, w), float("nan"), dtype=disp.dtype, device=disp.device)
    cover, error = frac.clone(), frac.clone()
    tol = gap
    to_val = torch.stack([lo, hi])
    for s in range(4):
        sel = edge & (sector == s)
        if not bool(sel.any()):
            continue
        ys, xs = torch.nonzero(sel, as_tuple=True)
        # the sign of the normal: towards the background (increasing disparity)
        ny, nx = normal_of[s]
        sgn = torch.sign(gy[ys, xs] * ny + gx[ys, xs] * nx)  # not 0: sector from (gy, gx)
        normal = (ny * sgn, nx * sgn)
        iy, ix = torch.round(normal[0]).long(), torch.round(normal[1]).long()
        ry, rx = (ys + iy).clamp(0, h - 1), (xs + ix).clamp(0, w - 1)
        # the front's own disparity: the next pixel into the front where it is labelled so
        dn = disp[(ys - iy).clamp(0, h - 1), (xs - ix).clamp(0, w - 1)]
        front = torch.where((dn - lo[ys, xs]).abs() < (dn - hi[ys, xs]).abs(), dn, lo[ys, xs])
        args = (front, hi[ys, xs], normal, tangent_of[s], opts.margin, lo, hi)
        # the reference: the next pixel towards the background, read against the same layers
        ref_ok = ((disp[ry, rx] - hi[ys, xs]).abs() < (disp[ry, rx] - lo[ys, xs]).abs()).float()
        # the values a re-decided pixel takes: its neighbours' across the edge where labelled so
        to_val[0, ys, xs] = front
        to_val[1, ys, xs] = torch.where(ref_ok > 0, disp[ry, rx], hi[ys, xs])
        part = torch.zeros((6, ys.numel()), dtype=disp.dtype, device=disp.device)
        part[0], part[1], part[2], k = _slopes(views, au, av, ys, xs, *args)
        part[3] = 1.0
        rxy, rxx, _, _ = _slopes(views, au, av, ry, rx, *args)
        part[4], part[5] = rxy * ref_ok, rxx * ref_ok
        # runs along the edge: the same layers (to a quarter of their gap) and the same labels
        # on either side of the edge (a straight stretch)
        lo_p, hi_p = lo[ys, xs], hi[ys, xs]
        prof = torch.stack([lo_p, hi_p, lo_p, lo_p])
        for c, side in ((2, -1), (3, 1)):
            dq = disp[(ys + side * iy).clamp(0, h - 1), (xs + side * ix).clamp(0, w - 1)]
            prof[c] = ((dq - lo_p).abs() < (dq - hi_p).abs()).to(disp.dtype) * 1e6
        run = (part, prof, tangent_of[s])
        f, se, ok = _coverage(*run, opts.length, tol[ys, xs], k, ys, xs, (h, w))
        if opts.long_length > opts.length:  # a long straight stretch, where it agrees
            f2, se2, ok2 = _coverage(*run, opts.long_length, tol[ys, xs], k, ys, xs, (h, w))
            use = ok2 & (~ok | ((f2 - f).abs() <= se))
            f, se, ok = torch.where(use, f2, f), torch.where(use, se2, se), ok | ok2
        sure = ok & ((f - 0.5).abs() >= opts.certainty * se)
        nan = torch.full_like(f, float("nan"))
        frac[ys, xs] = torch.where(sure, f, nan)
        cover[ys, xs], error[ys, xs] = torch.where(ok, f, nan), torch.where(ok, se, nan)
    front_now = (disp - lo).abs() <= (hi - disp).abs()
    to_front = edge & ~front_now & (frac > 0.5)
    to_back = edge & front_now & (frac < 0.5)
    out = torch.where(to_front, to_val[0], torch.where(to_back, to_val[1], disp))
    return out, int(to_front.sum() + to_back.sum()), cover, error


def snap_edges(views: torch.Tensor, au, av, disparity: torch.Tensor,
               options: EdgeSnap = EdgeSnap()) -> torch.Tensor:
    """Give each pixel at a depth edge the layer its measured coverage says (see the module).

    Parameters
    ----------
    views : ``(N, H, W)`` float32 tensor, the views used (normalised as for the sweep).
    au, av : view offsets ``u − c``, ``v − c`` ``(N,)``.
    disparity : ``(H, W)`` disparity map [view px per view step] (not modified).
    options : :class:`EdgeSnap`.

    Returns
    -------
    torch.Tensor ``(H, W)``: the disparity with edge pixels given the front's (lowest in their
    3 x 3 neighbourhood) or the background's (highest) disparity; other pixels unchanged.
    """
    au = np.asarray(au, dtype=np.float64)
    av = np.asarray(av, dtype=np.float64)
    amax = float(max(np.abs(au).max(), np.abs(av).max()))
    disp = disparity.clone()
    # later passes stay within one pixel of the edges of the given map
    pad = F.pad(disp[None, None], (1, 1, 1, 1), mode="replicate")
    step = (F.max_pool2d(pad, 3, stride=1) + F.max_pool2d(-pad, 3, stride=1))[0, 0] * amax
    allowed = F.max_pool2d((step >= options.jump).float()[None, None], 3, stride=1,
                           padding=1)[0, 0] > 0
    for _ in range(options.iterations):
        disp, changed, _, _ = _one_pass(views, au, av, disp, options, amax, allowed)
        if changed == 0:
            break
    return disp


def edge_coverage(views: torch.Tensor, au, av, disparity: torch.Tensor,
                  options: EdgeSnap = EdgeSnap()) -> tuple[torch.Tensor, torch.Tensor]:
    """The front layer's coverage of each depth-edge pixel's footprint as the views measure it
    (one pass of :func:`snap_edges`' measurement on ``disparity``, nothing re-decided).

    Parameters and units as for :func:`snap_edges`.

    Returns
    -------
    (coverage, standard_error) : two ``(H, W)`` tensors; the share of the footprint in [0, 1]
    (nominally: the least-squares estimate may leave it) covered by the lower-disparity layer of
    the pixel's 3 x 3 neighbourhood and its standard error; NaN off the depth edges and where
    the views do not define it.
    """
    au = np.asarray(au, dtype=np.float64)
    av = np.asarray(av, dtype=np.float64)
    amax = float(max(np.abs(au).max(), np.abs(av).max()))
    _, _, cover, error = _one_pass(views, au, av, disparity, options, amax)
    return cover, error
