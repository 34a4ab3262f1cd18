"""Semi-global matching over a plane-sweep cost volume (Hirschmüller, "Stereo processing by
semiglobal matching and mutual information", TPAMI 2008), for the light-field cost of
:class:`metasensor.depth.cost.CostVolume`.

Every pixel's cost curve is first divided by its own mean over the candidates plus a noise
floor (:func:`normalise_costs`), so each textured pixel casts one vote whatever its contrast (a
high-contrast background must not outvote a thin foreground bar) and an untextured one almost
none. Along each scan line (left/right, up/down; optionally the four diagonals) the
path cost is

    L(p, k) = C(p, k) + min(L(p−r, k), L(p−r, k±1) + P1, min_j L(p−r, j) + P2) − min_j L(p−r, j)

and the summed path costs ``S = Σ_r L_r`` replace a window aggregation: the smoothness terms
(``P1`` for a change by one candidate, ``P2`` for a jump) act along lines through the pixel,
so a depth edge stays where the per-pixel costs put it instead of spreading by the window
radius (foreground fattening), and thin structures that the lines run along survive.

Hand-written: OpenCV's ``StereoSGBM`` computes its own two-image matching cost and cannot take a
light-field cost volume; no maintained Python library runs SGM on a given volume. Memory: the
normalised volume and the sum ``S``, each ``(K, H, W)`` float32, plus a block of ``rows`` rows
(two ``(K, W, rows)`` copies) for the horizontal lines.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from metasensor.backend import one_thread_here

__all__ = ["SemiGlobal", "normalise_costs", "semi_global"]


@dataclass(frozen=True)
class SemiGlobal:
    """Smoothness penalties of :func:`semi_global`, in units of a pixel's mean cost.

    p1 : penalty for a change of the disparity by one candidate step between neighbours.
    p2 : penalty for a larger jump (a depth edge); ``0 < p1 < p2``.
    paths : scan lines through each pixel: 4 (rows and columns, both ways) or 8 (and the
        diagonals).
    noise : the noise floor of :func:`normalise_costs` in units of the median per-pixel
        minimum cost (> 0): the larger, the less a pixel of weak texture votes against its
        neighbours.
    """

    p1: float = 0.3
    p2: float = 0.5
    paths: int = 4
    noise: float = 8.0

    def __post_init__(self) -> None:
        for name in ("p1", "p2", "noise"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and 0 < value < float("inf")):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if self.paths not in (4, 8):
            raise ValueError(f"paths must be 4 or 8, got {self.paths!r}")
        if self.p1 >= self.p2:
            raise ValueError(f"p1 must be below p2, got p1={self.p1!r}, p2={self.p2!r}")


def normalise_costs(cost: torch.Tensor, noise: float = 2.0) -> torch.Tensor:
    """Divide every pixel's cost curve ``cost[:, y, x]`` by its mean over the candidates plus a
    noise floor, in place; returns the divisor ``(1, H, W)`` (``cost.mul_(divisor)`` undoes it).

    The floor is ``noise`` × the median over the pixels of their lowest cost (what a matched
    pixel's cost is made of: noise and interpolation error), so the curve of a textured pixel
    spans about 0..2 while that of an untextured one stays near 0 and lets its neighbours
    decide."""
    mean = cost.mean(dim=0, keepdim=True)
    floor = float(noise) * float(cost.amin(dim=0).median())
    floor = max(floor, float(mean.max()) * 1e-6, 1e-30)
    mean.add_(floor)
    cost.div_(mean)
    return mean


def _shifted(prev: torch.Tensor, shift: int) -> torch.Tensor:
    """``prev[:, x - shift]`` along the last axis; zeros where that falls outside (a zero
    predecessor starts the path there: ``L = C``)."""
    out = torch.zeros_like(prev)
    if shift > 0:
        out[:, shift:] = prev[:, :-shift]
    else:
        out[:, :shift] = prev[:, -shift:]
    return out


def _scan(cost: torch.Tensor, total: torch.Tensor, dim: int, reverse: bool, p1: float,
          p2: float, shift: int = 0) -> None:
    """Add one path's costs ``L`` along ``dim`` (1: down the rows, 2: along the columns) into
    ``total``; both ``(K, H, W)``. ``shift`` (rows only): the predecessor of ``(y, x)`` is
    ``(y ∓ 1, x − shift)``, a diagonal path."""
    n = cost.shape[dim]
    order = range(n - 1, -1, -1) if reverse else range(n)
    prev = None
    for i in order:
        c = cost.select(dim, i)  # (K, W) or (K, H)
        if prev is None:
            cur = c.clone()
        else:
            if shift:
                prev = _shifted(prev, shift)
            low = prev.amin(dim=0)
            best = torch.minimum(prev, (low + p2)[None])
            torch.minimum(best[:-1], prev[1:] + p1, out=best[:-1])
            torch.minimum(best[1:], prev[:-1] + p1, out=best[1:])
            cur = best.sub_(low[None]).add_(c)
        total.select(dim, i).add_(cur)
        prev = cur


def semi_global(cost: torch.Tensor, penalties: SemiGlobal = SemiGlobal(),
                rows: int = 256) -> torch.Tensor:
    """Summed path costs ``S`` ``(K, H, W)`` of a cost volume ``(K, H, W)`` (candidates equally
    spaced, first axis) over the scan lines of ``penalties.paths``; the winner ``argmin_k S``
    is the SGM disparity.
    ``cost`` should already be normalised (:func:`normalise_costs`): the penalties are in its
    units. The horizontal lines run over blocks of ``rows`` rows, transposed so that every scan
    step reads contiguous memory."""
    if cost.ndim != 3:
        raise ValueError(f"cost must be (K, H, W), got shape {tuple(cost.shape)}")
    p1, p2 = float(penalties.p1), float(penalties.p2)
    total = torch.zeros_like(cost)
    # thousands of small steps: threads only add overhead (this thread only; no global change)
    with one_thread_here(cost.device):
        _all_lines(cost, total, p1, p2, rows, penalties.paths)
    return total


def _all_lines(cost, total, p1: float, p2: float, rows: int, paths: int) -> None:
    for reverse in (False, True):
        _scan(cost, total, 1, reverse, p1, p2)
        if paths == 8:
            for shift in (1, -1):
                _scan(cost, total, 1, reverse, p1, p2, shift=shift)
    for start in range(0, cost.shape[1], rows):
        block = cost[:, start:start + rows].transpose(1, 2).contiguous()  # (K, W, B)
        acc = torch.zeros_like(block)
        for reverse in (False, True):
            _scan(block, acc, 1, reverse, p1, p2)
        total[:, start:start + rows].add_(acc.transpose(1, 2))
