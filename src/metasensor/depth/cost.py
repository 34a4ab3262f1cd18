"""Photo-consistency cost volume over candidate disparities (plane sweep over the views).

For a candidate disparity ``δ`` every view (u, v) is resampled at ``p + δ · (u − c, v − c)``
(separable cubic convolution, Keys 1981 with ``a = −0.75`` as in torch's bicubic, or bilinear;
both from integer slices of a padded copy: no index gathers, memory-bound), which aligns its
content with the centre view if ``δ`` is right. Bilinear resampling at a fractional shift
averages two neighbouring samples, blurring bars one or two view px wide into their background
and making the cost depend on the fractional part of each view's shift; the four-tap cubic
kernel keeps more of their contrast. The cost at ``p`` is the variance of the aligned views
(``"variance"``, the maximum-likelihood photo-consistency under Gaussian noise), optionally plus
``centre_weight`` times the squared difference between their mean and the centre view, or
their mean absolute difference to the centre view (``"sad"``); ``"anchored"`` is the variance
with ``centre_weight = 1`` (the mean squared difference to the centre view).

Why a centre term: at a pixel whose lenslet footprint straddles an occluding edge (a front
layer covering a share ``f`` of it), the half-pupil that sees the background clear matches the
background in every view except those on the central row/column, which see the pixel's mix;
the variance then gives the pixel to the background unless ``f`` is well above one half
(about 0.64 for 9 x 9 views, by the two-layer model), while the truth is the layer at the pixel
centre. The squared distance of the group mean to the centre view's own value grows at the
wrong layer (the mix differs from the background by ``f`` times the layers' contrast) and
moves that threshold towards one half, at the price of the centre view's noise in every cost.

Occlusion: the views are accumulated in nine sectors of the pupil (sign of ``u − c`` × sign of
``v − c``) so that, besides the full set, the four half-pupils (top, bottom, left, right, each
including the central row/column) cost nothing extra to evaluate. With ``occlusion=True`` the
cost is the minimum over the full pupil and the four halves: at an occluding edge one half of the
pupil sees the background unobstructed (cf. Wang, Efros & Ramamoorthi, ICCV 2015, who split the
angular patch by the edge orientation; here the split is axis-aligned).

Memory: the views (padded), 2 × 9 accumulators and the aggregated volume ``(K, H, W)`` float32;
candidates are processed one at a time.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

__all__ = ["CostVolume", "pad_views"]

_HALVES = ("top", "bottom", "left", "right")
COSTS = ("anchored", "variance", "sad")
RESAMPLING = ("cubic", "linear")
KEYS_A = -0.75  # cubic convolution parameter (torch's bicubic uses the same)


def keys_weights(t: float, a: float = KEYS_A) -> tuple[float, float, float, float]:
    """Weights of the samples at offsets −1, 0, 1, 2 for a point at fraction ``t`` in [0, 1)
    past sample 0 (cubic convolution, Keys, IEEE TASSP 1981); they sum to one."""
    def k(x: float) -> float:
        x = abs(x)
        if x <= 1.0:
            return ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0
        return ((a * x - 5.0 * a) * x + 8.0 * a) * x - 4.0 * a if x < 2.0 else 0.0

    return k(1.0 + t), k(t), k(1.0 - t), k(2.0 - t)


def pad_views(views: torch.Tensor, pad: int) -> torch.Tensor:
    """Replicate-pad a stack ``(N, H, W)`` by ``pad`` pixels on every side."""
    if pad <= 0:
        return views.clone()
    return torch.nn.functional.pad(views[:, None], (pad, pad, pad, pad), mode="replicate")[:, 0]


def _sectors(au: np.ndarray, av: np.ndarray) -> np.ndarray:
    """Sector index 0..8 of each view: 3 · (sign(u−c)+1) + (sign(v−c)+1)."""
    return (3 * (np.sign(au) + 1) + (np.sign(av) + 1)).astype(int)


def _half_members() -> dict[str, list[int]]:
    su = {s: s // 3 - 1 for s in range(9)}
    sv = {s: s % 3 - 1 for s in range(9)}
    return {
        "top": [s for s in range(9) if su[s] <= 0],
        "bottom": [s for s in range(9) if su[s] >= 0],
        "left": [s for s in range(9) if sv[s] <= 0],
        "right": [s for s in range(9) if sv[s] >= 0],
    }


class CostVolume:
    """Plane-sweep cost over candidate disparities for a set of views.

    Parameters
    ----------
    views : tensor ``(N, H, W)`` float32, the views used (already normalised/warped).
    au, av : angular offsets ``u − c`` and ``v − c`` of those views, ``(N,)``.
    centre : index into ``views`` of the centre view (reference for ``"sad"``).
    max_disparity : the largest ``|δ|`` that will be asked for [view px per view step].
    resampling : ``"cubic"`` (default) or ``"linear"`` interpolation of the shifted views.
    centre_weight : weight of the squared difference between a group's mean and the centre
        view, added to the ``"variance"`` cost (>= 0; 0 for ``"sad"``; ``"anchored"`` is 1).
    """

    def __init__(self, views: torch.Tensor, au, av, centre: int, max_disparity: float,
                 cost: str = "variance", occlusion: bool = False,
                 resampling: str = "cubic", centre_weight: float = 0.0) -> None:
        if cost not in COSTS:
            raise ValueError(f"cost must be one of {COSTS}, got {cost!r}")
        if not (isinstance(centre_weight, int | float) and 0 <= centre_weight < math.inf):
            raise ValueError(f"centre_weight must be a number >= 0, got {centre_weight!r}")
        if cost == "sad" and centre_weight:
            raise ValueError("centre_weight applies to the variance cost, not to 'sad'")
        self.centre_weight = 1.0 if cost == "anchored" else float(centre_weight)
        if resampling not in RESAMPLING:
            raise ValueError(f"resampling must be one of {RESAMPLING}, got {resampling!r}")
        self.resampling = resampling
        self.au = np.asarray(au, dtype=np.float64)
        self.av = np.asarray(av, dtype=np.float64)
        if views.ndim != 3 or views.shape[0] != self.au.size or self.av.size != self.au.size:
            raise ValueError("views must be (N, H, W) with one (u, v) offset per view")
        self.shape = tuple(views.shape[1:])
        reach = float(max_disparity) * float(max(np.abs(self.au).max(), np.abs(self.av).max()))
        self.pad = int(math.ceil(reach)) + 2
        # one constant off every view: costs unchanged, float32 sums of squares far more precise
        self.padded = pad_views(views, self.pad)
        self.padded.sub_(views.mean())
        self.centre = int(centre)
        self.cost = cost
        self.occlusion = bool(occlusion)
        self.sector = _sectors(self.au, self.av)
        self.count = np.bincount(self.sector, minlength=9).astype(np.float64)
        self.halves = _half_members()

    @property
    def views(self) -> torch.Tensor:
        """The views ``(N, H, W)`` less their common mean (a view into the padded copy)."""
        p, (h, w) = self.pad, self.shape
        return self.padded[:, p:p + h, p:p + w]

    # ----------------------------------------------------------------- resampling
    def shifted(self, i: int, dy: float, dx: float, out: torch.Tensor,
                tmp: torch.Tensor) -> torch.Tensor:
        """View ``i`` sampled at ``p + (dy, dx)`` into ``out`` ``(H, W)`` (``resampling``:
        cubic or bilinear, separable); ``tmp`` is contiguous scratch of at least
        ``H · (W + 3)`` (cubic) or ``(H + 1) · W`` (linear) elements."""
        h, w = self.shape
        iy, ix = math.floor(dy), math.floor(dx)
        fy, fx = dy - iy, dx - ix
        y0, x0 = self.pad + iy, self.pad + ix
        v = self.padded[i]
        if self.resampling == "cubic":
            return self._cubic(v, y0, x0, fy, fx, out, tmp.view(-1)[:h * (w + 3)].view(h, w + 3))
        tmp = tmp.view(-1)[:(h + 1) * w].view(h + 1, w)
        if fy == 0.0:
            return torch.lerp(v[y0:y0 + h, x0:x0 + w], v[y0:y0 + h, x0 + 1:x0 + 1 + w], fx,
                              out=out)
        torch.lerp(v[y0:y0 + h + 1, x0:x0 + w], v[y0:y0 + h + 1, x0 + 1:x0 + 1 + w], fx, out=tmp)
        return torch.lerp(tmp[:h], tmp[1:], fy, out=out)

    def _cubic(self, v, y0: int, x0: int, fy: float, fx: float, out, rows) -> torch.Tensor:
        """Separable four-tap cubic convolution: the rows ``y0 − 1 .. y0 + 2`` weighted into
        ``rows`` ``(H, W + 3)`` (columns from ``x0 − 1``), then its columns into ``out``."""
        h, w = self.shape
        if fy == 0.0:
            rows = v[y0:y0 + h, x0 - 1:x0 + w + 2]
        else:
            wy = keys_weights(fy)
            torch.mul(v[y0 - 1:y0 - 1 + h, x0 - 1:x0 + w + 2], wy[0], out=rows)
            for j in range(1, 4):
                rows.add_(v[y0 - 1 + j:y0 - 1 + j + h, x0 - 1:x0 + w + 2], alpha=wy[j])
        if fx == 0.0:
            return out.copy_(rows[:, 1:1 + w])
        wx = keys_weights(fx)
        torch.mul(rows[:, :w], wx[0], out=out)
        for j in range(1, 4):
            out.add_(rows[:, j:j + w], alpha=wx[j])
        return out

    # ----------------------------------------------------------------- one candidate
    def raw(self, disparity: float) -> torch.Tensor:
        """Per-pixel cost ``(H, W)`` of one candidate disparity, before aggregation."""
        h, w = self.shape
        dev = self.padded.device
        s1 = torch.zeros((9, h, w), dtype=torch.float32, device=dev)
        s2 = torch.zeros((9, h, w), dtype=torch.float32, device=dev) if self.cost != "sad" \
            else None
        out = torch.empty((h, w), dtype=torch.float32, device=dev)
        tmp = torch.empty((h + 1) * (w + 3), dtype=torch.float32, device=dev)
        ref = None
        if self.cost == "sad":
            ref = self.padded[self.centre, self.pad:self.pad + h, self.pad:self.pad + w]
        for i in range(self.au.size):
            self.shifted(i, disparity * self.au[i], disparity * self.av[i], out, tmp)
            g = self.sector[i]
            if self.cost != "sad":
                s1[g].add_(out)
                s2[g].addcmul_(out, out)
            else:
                out.sub_(ref).abs_()
                s1[g].add_(out)
        return self._combine(s1, s2)

    def _combine(self, s1: torch.Tensor, s2: torch.Tensor | None) -> torch.Tensor:
        """Cost of the full pupil, or (occlusion) the minimum over it and the four halves."""
        m = self.group_matrix.to(s1.device)  # (G, 9), rows normalised by the group's count
        h, w = self.shape
        mean = (m @ s1.reshape(9, -1)).reshape(-1, h, w)
        if self.cost != "sad":
            cost = torch.clamp((m @ s2.reshape(9, -1)).reshape(-1, h, w) - mean * mean, min=0.0)
            if self.centre_weight > 0:  # squared distance of the mean to the centre view
                p = self.pad
                ref = self.padded[self.centre, p:p + h, p:p + w]
                cost.add_((mean - ref).square_().mul_(self.centre_weight))
        else:
            cost = mean
        return cost[0] if cost.shape[0] == 1 else cost.amin(0)

    @property
    def group_matrix(self) -> torch.Tensor:
        """``(G, 9)`` averaging weights of the view groups: the full pupil, then (occlusion) the
        four half-pupils that hold at least two views."""
        present = [s for s in range(9) if self.count[s] > 0]
        groups = [present]
        if self.occlusion:
            for name in _HALVES:
                members = [s for s in self.halves[name] if self.count[s] > 0]
                if self.count[members].sum() >= 2:
                    groups.append(members)
        m = np.zeros((len(groups), 9), dtype=np.float32)
        for g, members in enumerate(groups):
            m[g, members] = 1.0 / self.count[members].sum()
        return torch.from_numpy(m)

    # ----------------------------------------------------------------- whole volume
    def volume(self, candidates, aggregate: Callable[[torch.Tensor], torch.Tensor] | None = None,
               progress: bool = False) -> torch.Tensor:
        """Aggregated cost volume ``(K, H, W)`` for the candidate disparities."""
        from tqdm.auto import tqdm

        cands = [float(c) for c in np.asarray(candidates, dtype=np.float64).ravel()]
        vol = torch.empty((len(cands), *self.shape), dtype=torch.float32,
                          device=self.padded.device)
        for k, c in enumerate(tqdm(cands, desc="cost volume", unit="disparity",
                                   disable=not progress)):
            raw = self.raw(c)
            vol[k] = aggregate(raw) if aggregate is not None else raw
        return vol
