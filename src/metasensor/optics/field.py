"""Field-dependent aberrations: Zernike vectors that vary across the field of view.

A field-dependent aberration (``field_zernike`` everywhere in the API) is either
- an array ``(by, bx, J)``: Noll vectors (waves) at the centres of a regular ``by x bx`` grid of
  blocks over the field, interpolated bilinearly between block centres (held constant beyond the
  outermost centres); or
- a callable ``f(yn, xn) -> (..., J)`` of normalised field coordinates.

Normalised field coordinates of image pixel (y, x) in an (H, W) image are
``yn = 2 (y + 0.5) / H - 1`` and ``xn = 2 (x + 0.5) / W - 1`` (both in (-1, 1), 0 at the centre).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["evaluate_field_zernike", "normalised_field", "block_centres_normalised"]

FieldZernike = np.ndarray | Callable[[np.ndarray, np.ndarray], np.ndarray]


def normalised_field(y, x, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Normalised field coordinates of pixel positions (y, x) in an image of ``shape``."""
    h, w = shape
    yn = 2.0 * (np.asarray(y, float) + 0.5) / h - 1.0
    xn = 2.0 * (np.asarray(x, float) + 0.5) / w - 1.0
    return yn, xn


def block_centres_normalised(by: int, bx: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised coordinates (yn, xn) of the centres of a by x bx grid of equal blocks."""
    yc = 2.0 * (np.arange(by) + 0.5) / by - 1.0
    xc = 2.0 * (np.arange(bx) + 0.5) / bx - 1.0
    return np.meshgrid(yc, xc, indexing="ij")


def evaluate_field_zernike(field_zernike: FieldZernike, yn, xn) -> np.ndarray:
    """Noll vectors at normalised field points ``(yn, xn)`` (any matching shapes) → (..., J)."""
    yn = np.asarray(yn, dtype=np.float64)
    xn = np.asarray(xn, dtype=np.float64)
    if callable(field_zernike):
        out = np.asarray(field_zernike(yn, xn), dtype=np.float64)
        if out.shape[:-1] != np.broadcast_shapes(yn.shape, xn.shape):
            raise ValueError(
                f"field_zernike callable returned shape {out.shape} for points of shape {yn.shape}"
            )
        return out
    grid = np.asarray(field_zernike, dtype=np.float64)
    if grid.ndim != 3 or 0 in grid.shape:
        raise ValueError(f"field_zernike array must have shape (by, bx, J), none of them 0, "
                         f"got {grid.shape}")
    if not np.isfinite(grid).all():
        raise ValueError("field_zernike contains NaN or infinite values")
    by, bx, _ = grid.shape
    # fractional block index: centre of block i sits at yn = 2 (i + 0.5) / by - 1
    fy = np.clip((yn + 1.0) * by / 2.0 - 0.5, 0.0, by - 1.0)
    fx = np.clip((xn + 1.0) * bx / 2.0 - 0.5, 0.0, bx - 1.0)
    y0 = np.minimum(np.floor(fy).astype(int), max(by - 2, 0))
    x0 = np.minimum(np.floor(fx).astype(int), max(bx - 2, 0))
    y1 = np.minimum(y0 + 1, by - 1)
    x1 = np.minimum(x0 + 1, bx - 1)
    wy = (fy - y0)[..., None]
    wx = (fx - x0)[..., None]
    return ((1 - wy) * (1 - wx) * grid[y0, x0] + (1 - wy) * wx * grid[y0, x1]
            + wy * (1 - wx) * grid[y1, x0] + wy * wx * grid[y1, x1])
