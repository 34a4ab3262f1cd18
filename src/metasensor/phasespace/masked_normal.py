"""AᵀMA for a window observed in one rectangle of the sample grid, without the full operator.

Hand-written (no library has the phase-space operator). A padded window
(:func:`metasensor.phasespace.operator.make_geometry`) observes the samples of a rectangle
``[y0, y1) x [x0, x1)`` of the domain's sample grid; the rest (the margins) are unobserved, so the
normal operator of the masked data term is not circular:

    AᵀMA v = AᵀA v − Aᵀ(1 − M)A v.

The first term is circular and costs two full-size FFTs and a batched d² x d² product through
:class:`metasensor.phasespace.normal.FoldedNormal`. The second involves only the unobserved samples,
which lie in two bands: the sample rows outside [y0, y1) (all columns; one band, since the domain
is circular) and the sample columns outside [x0, x1) within rows [y0, y1). A sample depends on
pixels within the PSF radius of it, so each band's part is exact on a *band domain*: the band's
samples plus ``ceil(radius / d)`` samples of image either side across the band, circular along it.
There a :class:`~metasensor.phasespace.operator.PhaseSpaceOperator` of the same bank applies A,
the band
mask and Aᵀ, and the result is added back (index_add: the extraction's transpose).

Cost: the band operators transform ``V`` views on the bands' area instead of the domain's
(``benchmarks/bench_isa.py``; figures in ``docs/decisions.md``). Where the bands would cover more
than :data:`MAX_BAND_FRACTION` of the domain (small windows) or the mask is not one rectangle,
:func:`masked_normal` returns the direct product instead.
"""

from __future__ import annotations

import math

import torch

from metasensor.phasespace.geometry import Geometry, smooth_size
from metasensor.phasespace.normal import FoldedNormal
from metasensor.phasespace.operator import PhaseSpaceOperator

__all__ = ["BandNormal", "masked_normal", "MAX_BAND_FRACTION"]

# bands beyond this share of the domain's area: the direct product is as fast (docs/decisions.md)
MAX_BAND_FRACTION = 0.7


def _observed_rectangle(mask: torch.Tensor) -> tuple[int, int, int, int] | None:
    """(y0, y1, x0, x1) if ``mask`` (My, Mx) is True exactly on one rectangle, else None."""
    rows = torch.nonzero(mask.any(dim=1)).flatten()
    cols = torch.nonzero(mask.any(dim=0)).flatten()
    if rows.numel() == 0:
        return None
    y0, y1 = int(rows[0]), int(rows[-1]) + 1
    x0, x1 = int(cols[0]), int(cols[-1]) + 1
    if int(mask.sum()) != (y1 - y0) * (x1 - x0) or not bool(mask[y0:y1, x0:x1].all()):
        return None
    return y0, y1, x0, x1


class _Band:
    """The unobserved samples ``[start, start + length)`` (circular) along ``axis`` of the sample
    grid, restricted to ``keep`` (bool, the other axis's samples), on a band domain."""

    def __init__(self, op: PhaseSpaceOperator, psf: torch.Tensor, axis: int, start: int,
                 length: int, keep: torch.Tensor) -> None:
        g = op.geometry
        d, r = g.d, op.radius
        n_samples = g.grid[axis]
        lead = math.ceil(r / d)
        trail = math.ceil((r + 1) / d)
        width = smooth_size(length + lead + trail, d)  # band samples across, fast FFT size
        first = start - lead  # domain sample of band sample 0 (circular)
        pixels = torch.arange(width * d, device=op.device) + first * d
        self.axis = axis
        self.index = torch.remainder(pixels, n_samples * d)  # domain pixel of each band pixel
        grid = (width, g.grid[1]) if axis == 0 else (g.grid[0], width)
        self.op = PhaseSpaceOperator(psf, Geometry(grid, d, (0, 0), grid), op.device, op.chunk)
        across = torch.zeros(width, dtype=torch.float32, device=op.device)
        across[lead:lead + length] = 1.0
        keep = keep.to(torch.float32)
        self.mask = across[:, None] * keep[None, :] if axis == 0 else keep[:, None] * across[None]
        self.area = self.op.geometry.domain[0] * self.op.geometry.domain[1]

    def apply(self, v: torch.Tensor, out: torch.Tensor, alpha: float = 1.0) -> None:
        """out += alpha·Eᵀ A_bᵀ M_b A_b E v (E: the band's pixels out of the domain image)."""
        patch = torch.index_select(v, self.axis, self.index)
        back = self.op.adjoint(self.op.forward(patch) * self.mask)
        out.index_add_(self.axis, self.index, back, alpha=alpha)


class BandNormal:
    """v -> AᵀMA v for a mask observing one rectangle: the folded circular AᵀA minus the two
    unobserved bands' AᵀA (module docstring). Holds the band operators; calls never change it."""

    def __init__(self, op: PhaseSpaceOperator, normal: FoldedNormal,
                 rectangle: tuple[int, int, int, int]) -> None:
        if normal.op is not op:
            raise ValueError("normal must be the folded normal operator of op")
        psf_t = op.psf
        self.device = op.device
        my, mx = op.geometry.grid
        y0, y1, x0, x1 = rectangle
        self.normal = normal
        self.bands = []
        if y1 - y0 < my:  # rows outside [y0, y1), every column
            keep = torch.ones(mx, dtype=torch.bool, device=op.device)
            self.bands.append(_Band(op, psf_t, 0, y1, my - (y1 - y0), keep))
        if x1 - x0 < mx:  # columns outside [x0, x1), rows [y0, y1)
            keep = torch.zeros(my, dtype=torch.bool, device=op.device)
            keep[y0:y1] = True
            self.bands.append(_Band(op, psf_t, 1, x1, mx - (x1 - x0), keep))
        ny, nx = op.geometry.domain
        self.fraction = sum(b.area for b in self.bands) / float(ny * nx)

    def __call__(self, v: torch.Tensor) -> torch.Tensor:
        v = torch.as_tensor(v, dtype=torch.float32, device=self.device)
        out = self.normal.apply(v)
        for band in self.bands:
            band.apply(v, out, alpha=-1.0)
        return out


def masked_normal(op: PhaseSpaceOperator, normal: FoldedNormal, mask: torch.Tensor,
                  max_fraction: float = MAX_BAND_FRACTION):
    """A callable v -> AᵀMA v (``mask`` (My, Mx) bool, True where observed): the
    :class:`BandNormal` where the mask is one rectangle and its bands cover at most
    ``max_fraction`` of the domain, else the direct ``op.adjoint(op.forward(v) * mask)``."""
    m = mask.to(device=op.device, dtype=torch.bool)
    mf = m.to(torch.float32)

    def direct(v: torch.Tensor) -> torch.Tensor:
        return op.adjoint(op.forward(v) * mf)

    if bool(m.all()):
        return normal.apply
    rect = _observed_rectangle(m)
    if rect is None:
        return direct
    band = BandNormal(op, normal, rect)
    return band if band.fraction <= max_fraction else direct
