"""Where a window of view samples sits in the padded domain of the phase-space estimate
(:class:`Geometry`, :func:`make_geometry`), fast FFT sizes (:func:`smooth_size`), and the
shapes every operator on a geometry shares (:class:`GridShapes`).

Geometry. The estimate lives on a padded *domain* of ``(Ny, Nx) = (My·d, Mx·d)`` pixels whose
view samples sit exactly at multiples of d (sample (m, n) at domain pixel (m·d, n·d)); this makes
the folding phase-free. A data window of ``(Sy, Sx)`` view samples starts at sample ``m0``; the
window's local pixel ``(Y·d + d//2)`` (its sample Y, conventions.md) is domain pixel
``(m0 + Y)·d``, so window pixel (0, 0) is domain pixel ``offset = m0·d − d//2``. The domain is
padded by at least the PSF radius beyond the outermost samples, so the FFT's circular convolution
equals the linear one on every observed sample (no wrap-around): the estimate outside the window is
reconstructed too (from the light it spreads into the window), which removes edge ringing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

__all__ = ["Geometry", "GridShapes", "make_geometry", "smooth_size"]


def _is_smooth(n: int, primes=(2, 3, 5, 7)) -> bool:
    for p in primes:
        while n % p == 0:
            n //= p
    return n == 1


def smooth_size(n: int, d: int = 1) -> int:
    """Smallest m >= n such that m and m·d are 7-smooth (fast FFT sizes); m alone if d is not."""
    m = max(int(n), 1)
    need_d = _is_smooth(d)
    while not (_is_smooth(m) and (not need_d or _is_smooth(m * d))):
        m += 1
    return m


@dataclass(frozen=True)
class Geometry:
    """Where a window of view samples sits in the padded estimate domain (all in pixels/samples).

    window : (Sy, Sx) view samples of data; the window covers (Sy·d, Sx·d) image pixels.
    d : view sample spacing in pixels.
    m0 : (my, mx) domain sample index of window sample (0, 0).
    grid : (My, Mx) samples of the whole domain; the domain is (My·d, Mx·d) pixels.
    """

    window: tuple[int, int]
    d: int
    m0: tuple[int, int]
    grid: tuple[int, int]

    @property
    def domain(self) -> tuple[int, int]:
        return (self.grid[0] * self.d, self.grid[1] * self.d)

    @property
    def offset(self) -> tuple[int, int]:
        """Domain pixel of window pixel (0, 0) (negative: circular wrap, unpadded domain)."""
        s = self.d // 2
        return (self.m0[0] * self.d - s, self.m0[1] * self.d - s)

    @property
    def pixels(self) -> tuple[int, int]:
        return (self.window[0] * self.d, self.window[1] * self.d)

    def sample_slices(self) -> tuple[slice, slice]:
        """Slices of the domain's sample grid that hold the window's samples."""
        return (slice(self.m0[0], self.m0[0] + self.window[0]),
                slice(self.m0[1], self.m0[1] + self.window[1]))

    def embed(self, samples: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(V, Sy, Sx) window samples → (V, My, Mx) float32 data on the domain's sample grid
        (zero where unobserved) and the (My, Mx) bool mask of the observed samples."""
        if tuple(samples.shape[-2:]) != tuple(self.window):
            raise ValueError(f"samples must have the window's shape {self.window}, "
                             f"got {tuple(samples.shape[-2:])}")
        data = torch.zeros((samples.shape[0], *self.grid), dtype=torch.float32,
                           device=samples.device)
        mask = torch.zeros(self.grid, dtype=torch.bool, device=samples.device)
        sy, sx = self.sample_slices()
        data[:, sy, sx] = samples.to(torch.float32)
        mask[sy, sx] = True
        return data, mask

    def crop(self, image: torch.Tensor) -> torch.Tensor:
        """The window's (Sy·d, Sx·d) pixels out of a domain image (..., Ny, Nx)."""
        oy, ox = self.offset
        hy, hx = self.pixels
        if oy < 0 or ox < 0:  # unpadded, circular domain
            image = torch.roll(image, shifts=(-oy, -ox), dims=(-2, -1))
            oy, ox = 0, 0
        return image[..., oy:oy + hy, ox:ox + hx]


def make_geometry(window: tuple[int, int], d: int, radius: int, pad: bool = True) -> Geometry:
    """The estimate's domain for a window of view samples.

    Parameters
    ----------
    window : (int, int)
        ``(Sy, Sx)`` view samples of data.
    d : int
        View sample spacing, pixels (``cfg.scan_step_px``).
    radius : int
        PSF radius, pixels (K = 2·radius + 1).
    pad : bool
        True: margins of at least ``radius`` pixels beyond the outermost samples (linear
        convolution on the observed samples), rounded up to a fast FFT size; False: the domain
        is the window itself (circular convolution, wraps around at the edges; for comparison).

    Returns
    -------
    Geometry
    """
    sy, sx = (int(window[0]), int(window[1]))
    if sy < 1 or sx < 1:
        raise ValueError(f"window must hold at least one view sample per axis, got {window}")
    if d < 1:
        raise ValueError(f"sample spacing d must be >= 1, got {d}")
    if not pad:
        return Geometry((sy, sx), d, (0, 0), (sy, sx))
    lead = math.ceil(radius / d)
    trail = math.ceil((radius + 1) / d)
    my = smooth_size(sy + lead + trail, d)
    mx = smooth_size(sx + lead + trail, d)
    return Geometry((sy, sx), d, (lead, lead), (my, mx))


class GridShapes:
    """``domain_shape`` and ``range_shape`` of a phase-space operator from its ``geometry`` and
    ``n_views`` (shared by every operator on a :class:`Geometry`)."""

    @property
    def domain_shape(self) -> tuple[int, int]:
        """Shape ``(Ny, Nx)`` of the images A applies to."""
        return self.geometry.domain

    @property
    def range_shape(self) -> tuple[int, int, int]:
        """Shape ``(V, My, Mx)`` of the view samples A returns."""
        return (self.n_views, *self.geometry.grid)
