"""Atmospheric turbulence: a time series of Kolmogorov / von Kármán phase screens over the pupil.

Frozen flow (Taylor): one large screen from ``aotools.turbulence.ft_phase_screen`` (seeded) is
blown across the pupil at ``wind`` pupil diameters per frame; frame t sees the window shifted by
``t · wind``. Lengths are in pupil diameters (D = 1): ``d_over_r0`` is D / r0 at the
configuration's wavelength, ``outer_scale`` is L0 / D (``None``: Kolmogorov, L0 = 1e4 D).
Screens are returned in **waves**, sampled on ``samples × samples`` points covering the square
``rho ∈ [−1, 1]²`` (sample k at ``rho = −1 + (k + 0.5) · 2 / samples``). Isoplanatic: one screen
per frame for the whole field; per-view aberrations arise through the views' sub-apertures.

How finely the simulator follows the screens (:func:`metasensor.simulation.capture.simulate`):
``key_every`` = k computes the PSF banks of key frames only (every k-th frame of the period and
its last) and renders a frame between two key frames with the PSFs interpolated linearly in
time (the partition of unity the simulator also uses across the field); 1 = a bank per frame.
``subsample``: sub-pixel sampling of those per-frame banks (3: the simulator's continuous scene
model, :mod:`metasensor.simulation.kernels`; 1: the pixel grid, nine times fewer point
positions; the data still differ from any reconstruction's model, which has one wavefront per
block and window, while every frame here has its own).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["Turbulence", "screen_phase"]


@dataclass(frozen=True)
class Turbulence:
    """Frozen-flow turbulence (units and the simulator's sampling ``key_every``, ``subsample``
    in the module docstring)."""

    d_over_r0: float = 2.0
    outer_scale: float | None = None
    wind: tuple[float, float] = (0.0, 0.05)
    samples: int = 64
    inner_scale: float = 0.01
    key_every: int = 1
    subsample: int = 3

    def __post_init__(self) -> None:
        for name in ("key_every", "subsample"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if self.subsample % 2 == 0:
            raise ValueError(f"subsample must be odd, got {self.subsample!r}")
        if not (self.d_over_r0 > 0 and math.isfinite(self.d_over_r0)):
            raise ValueError(f"d_over_r0 must be positive, got {self.d_over_r0!r}")
        if self.outer_scale is not None and not self.outer_scale > 0:
            raise ValueError(f"outer_scale must be positive, got {self.outer_scale!r}")
        if not (isinstance(self.samples, int) and self.samples >= 8):
            raise ValueError(f"samples must be an integer >= 8, got {self.samples!r}")
        wy, wx = (float(v) for v in self.wind)
        if not (math.isfinite(wy) and math.isfinite(wx)):
            raise ValueError(f"wind must be finite, got {self.wind!r}")
        object.__setattr__(self, "wind", (wy, wx))

    def screens(self, n_frames: int, seed: int | np.random.SeedSequence = 0) -> np.ndarray:
        """(T, samples, samples) float32 phase screens in waves, piston removed per frame."""
        from aotools.turbulence import ft_phase_screen

        if n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {n_frames}")
        s = self.samples
        travel = [abs(w) * (n_frames - 1) * s for w in self.wind]
        need = s + int(math.ceil(max(travel))) + 4
        n = 1 << max(int(math.ceil(math.log2(max(4 * s, 2 * need)))), 3)
        if isinstance(seed, np.random.SeedSequence):
            seed = int(seed.generate_state(1)[0])
        l0 = 1e4 if self.outer_scale is None else float(self.outer_scale)
        big = ft_phase_screen(1.0 / self.d_over_r0, n, 1.0 / s, l0, self.inner_scale,
                              seed=int(seed)) / (2 * math.pi)
        # start so that the whole path stays inside the screen
        y0 = (n - s) / 2 - self.wind[0] * (n_frames - 1) * s / 2
        x0 = (n - s) / 2 - self.wind[1] * (n_frames - 1) * s / 2
        k = np.arange(s, dtype=np.float64)
        out = np.empty((n_frames, s, s), dtype=np.float32)
        for t in range(n_frames):
            yy, xx = np.meshgrid(y0 + self.wind[0] * t * s + k, x0 + self.wind[1] * t * s + k,
                                 indexing="ij")
            scr = ndimage.map_coordinates(big, [yy, xx], order=3, mode="wrap")
            out[t] = scr - scr.mean()
        return out


def screen_phase(screen: np.ndarray):
    """Callable ``f(rho_x, rho_y) -> waves`` interpolating a (s, s) screen (cubic splines)."""
    screen = np.asarray(screen, dtype=np.float64)
    s = screen.shape[0]
    coeffs = ndimage.spline_filter(screen, order=3, mode="nearest")

    def phase(rho_x, rho_y):
        rx, ry = np.broadcast_arrays(np.asarray(rho_x, float), np.asarray(rho_y, float))
        ky = (ry + 1.0) * s / 2.0 - 0.5
        kx = (rx + 1.0) * s / 2.0 - 0.5
        vals = ndimage.map_coordinates(coeffs, [ky.ravel(), kx.ravel()], order=3,
                                       mode="nearest", prefilter=False)
        return vals.reshape(rx.shape)

    return phase
