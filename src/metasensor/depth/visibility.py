"""Background pixels given a nearer layer ("fattening"), re-decided with the views that see them.

Near an occluder whose disparity differs from the background's by several view pixels per
view step, a background pixel is hidden in every view whose offset points towards the
occluder; where no half-pupil of :mod:`metasensor.depth.cost` sees it clear (corners, gaps
between occluders) the plane sweep's costs favour the occluder's disparity and the window
aggregation spreads it over the background. Given the current map, which views see a point is
known: the surface at centre pixel ``p'`` with disparity ``δ'`` appears in view ``a`` at
``p' + δ' a``, and a point ``(p, δ)`` is visible in view ``a`` unless a nearer surface (lower
disparity, :mod:`metasensor.depth.geometry`) lands at ``p + δ a`` (a z-buffer of the map
forward-warped into each view, nearest sample).

Every pixel whose neighbourhood (``radius``) holds a layer farther by at least ``jump``
outermost-view pixels compares its own disparity ``δ_f`` with that farther one ``δ_b`` (the
neighbourhood's largest) on the same views, those that see ``(p, δ_b)``: the mean squared
difference of ``V_a(p + δ a)`` to the centre view ``V_0(p)`` (anchored to the centre view, which
shows the pixel's own layer: the background hypothesis is otherwise as consistent behind a true
occluder as in front of it), box-aggregated over ``window``. The pixel takes ``δ_b`` where that
costs less and enough views (``min_views``) see it; repeated ``rounds`` times with the updated
map (the visibility of pixels behind a re-decided one changes). Plain light-field views only
(where it was measured); a pixel moves only to a value of its neighbourhood, so no depth is
invented.

Written here by hand (visibility reasoning from a depth map is textbook multi-view stereo, e.g.
Kolmogorov & Zabih, ECCV 2002, and Wang, Efros & Ramamoorthi, ICCV 2015, for light fields; no
maintained library does it for a light-field view grid).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from metasensor.depth.filters import box_mean, sample_at

__all__ = ["Visibility", "reveal_background"]


@dataclass(frozen=True)
class Visibility:
    """Settings of :func:`reveal_background`.

    jump : the farther layer must move the outermost view by at least this many view px more
        than the pixel's own disparity.
    radius : half-size [px] of the square neighbourhood whose largest disparity is the
        background hypothesis.
    window : half-size [px] of the box that aggregates each hypothesis's cost.
    rounds : re-decisions, each with the visibility of the updated map.
    min_views : share of the views that must see the background hypothesis.
    tolerance : a surface occludes a point only if it is nearer by more than this many
        outermost-view px.
    margin : the background must cost less than the own disparity by this share of the
        latter (at least).
    confident : the smallest confidence of a pixel whose disparity may serve as a background
        hypothesis (the estimator's fill threshold).
    """

    jump: float = 1.5
    radius: int = 4
    window: int = 1
    rounds: int = 3
    min_views: float = 0.1
    tolerance: float = 0.5
    confident: float = 0.1
    margin: float = 0.25

    def __post_init__(self) -> None:
        if not (isinstance(self.margin, int | float) and 0 <= self.margin < 1):
            raise ValueError(f"Visibility.margin must be in [0, 1), got {self.margin!r}")
        for name in ("jump", "tolerance"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and 0 < value < np.inf):
                raise ValueError(f"Visibility.{name} must be a positive number, got {value!r}")
        for name, low in (("radius", 1), ("window", 0), ("rounds", 1)):
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= low):
                raise ValueError(f"Visibility.{name} must be an integer >= {low}, got {value!r}")
        if not (isinstance(self.confident, int | float) and 0 <= self.confident <= 1):
            raise ValueError(f"Visibility.confident must be in [0, 1], got {self.confident!r}")
        if not (isinstance(self.min_views, int | float) and 0 < self.min_views <= 1):
            raise ValueError(f"Visibility.min_views must be in (0, 1], got {self.min_views!r}")


def _nearest_seen(disp: torch.Tensor, a_u: float, a_v: float, ys, xs) -> torch.Tensor:
    """Z-buffer of the map forward-warped into view ``a``: at each view sample the lowest
    disparity landing there (nearest sample), +inf where none does."""
    h, w = disp.shape
    qy = torch.round(ys + disp * a_u).long()
    qx = torch.round(xs + disp * a_v).long()
    ok = (qy >= 0) & (qy < h) & (qx >= 0) & (qx < w)
    z = torch.full((h * w,), float("inf"), dtype=disp.dtype, device=disp.device)
    z.scatter_reduce_(0, (qy * w + qx)[ok], disp[ok], reduce="amin")
    return z.reshape(h, w)


def _costs(views, au, av, centre: int, disp, back, tol: float):
    """Anchored costs of the own (``disp``) and the background (``back``) hypotheses over the
    views that see ``(p, back)``, and how many views those are."""
    h, w = disp.shape
    ys = torch.arange(h, dtype=disp.dtype, device=disp.device)[:, None].expand(h, w)
    xs = torch.arange(w, dtype=disp.dtype, device=disp.device)[None, :].expand(h, w)
    ref = views[centre]
    own = torch.zeros_like(disp)
    bg = torch.zeros_like(disp)
    seen = torch.zeros_like(disp)
    for i in range(views.shape[0]):
        a_u, a_v = float(au[i]), float(av[i])
        by, bx = ys + back * a_u, xs + back * a_v
        if i == centre:
            vis = torch.ones_like(disp)
        else:
            z = _nearest_seen(disp, a_u, a_v, ys, xs)
            iy = torch.clamp(torch.round(by).long(), 0, h - 1)
            ix = torch.clamp(torch.round(bx).long(), 0, w - 1)
            vis = (z[iy, ix] >= back - tol).to(disp.dtype)
        bg += vis * (sample_at(views[i], by, bx) - ref) ** 2
        own += vis * (sample_at(views[i], ys + disp * a_u, xs + disp * a_v) - ref) ** 2
        seen += vis
    n = torch.clamp(seen, min=1.0)
    return own / n, bg / n, seen


def reveal_background(views: torch.Tensor, au, av, centre: int, disparity: torch.Tensor,
                      confidence: torch.Tensor, opts: Visibility = Visibility()) -> torch.Tensor:
    """Give the background back to the pixels whose visible views say so (module docstring).

    Parameters
    ----------
    views : torch.Tensor
        The views ``(N, H, W)`` (normalised, any common offset).
    au, av : numpy.ndarray
        Their offsets from the centre view ``(N,)`` [view steps].
    centre : int
        The centre view's index in ``views``.
    disparity : torch.Tensor
        The disparity map ``(H, W)`` [view px per view step] (not modified).
    confidence : torch.Tensor
        Its confidence ``(H, W)`` in [0, 1]; only pixels of at least ``opts.confident`` lend
        their value as a background hypothesis.
    opts : Visibility
        Settings.

    Returns
    -------
    torch.Tensor
        The disparities ``(H, W)``: each pixel its own value or its neighbourhood's largest.
    """
    au = np.asarray(au, dtype=np.float64)
    av = np.asarray(av, dtype=np.float64)
    amax = float(max(np.abs(au).max(), np.abs(av).max(), 1.0))
    d = disparity.to(torch.float32).clone()
    k = 2 * opts.radius + 1
    # the hypotheses come from the input map's confident pixels: a re-decided pixel lends its
    # value to no other, nor does a guess
    src = torch.where(confidence >= opts.confident, d, torch.full_like(d, -float("inf")))
    back = F.max_pool2d(F.pad(src[None, None], (opts.radius,) * 4, mode="replicate"), k,
                        stride=1)[0, 0]
    for _ in range(opts.rounds):
        cand = (back - d) * amax >= opts.jump
        if not bool(cand.any()):
            break
        own, bg, seen = _costs(views, au, av, centre, d, back, opts.tolerance / amax)
        own = box_mean(own, opts.window)
        bg = box_mean(bg, opts.window)
        take = cand & (bg < (1 - opts.margin) * own) & (seen >= opts.min_views * views.shape[0])
        if not bool(take.any()):
            break
        d = torch.where(take, back, d)
    return d
