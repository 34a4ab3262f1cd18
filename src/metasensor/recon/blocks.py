"""Multisite blocks: split the field into overlapping blocks and stitch them without seams.

The field (H, W) output pixels is partitioned into ``by x bx`` *cores* whose borders lie on the
view sampling (multiples of d = nnum // scan, so every block keeps the conventions' sampling
phase). Each block reconstructs its *region*: the core extended by ``ext`` pixels on every side
that has a neighbour (``ext`` = half the overlap, rounded up to a multiple of d; the actual overlap
between neighbours is ``2·ext >= overlap``). The block's data *window* adds ``margin`` more pixels
of views around the region (observed data that constrain the region's edge pixels; not stitched).
Stitching weights are raised-cosine ramps across each overlap: the two ramps of a border sum to one
(a partition of unity), so stitched images have no seams.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Block", "split_blocks", "block_weights", "block_centre_normalised", "Stitcher",
           "block_zernikes"]


@dataclass(frozen=True)
class Block:
    """One block; all boxes are (y0, y1, x0, x1) in output pixels of the full field."""

    index: tuple[int, int]
    core: tuple[int, int, int, int]
    region: tuple[int, int, int, int]
    window: tuple[int, int, int, int]
    ext: int

    def window_samples(self, d: int) -> tuple[slice, slice]:
        """Slices of the view stack's sample axes that hold this block's window."""
        y0, y1, x0, x1 = self.window
        return slice(y0 // d, y1 // d), slice(x0 // d, x1 // d)

    def region_in_window(self) -> tuple[slice, slice]:
        y0, y1, x0, x1 = self.region
        wy, _, wx, _ = self.window
        return slice(y0 - wy, y1 - wy), slice(x0 - wx, x1 - wx)

    def region_samples(self, d: int) -> tuple[slice, slice]:
        """The region inside the window in view samples (scan step ``d`` [px])."""
        ry, rx = self.region_in_window()
        return slice(ry.start // d, ry.stop // d), slice(rx.start // d, rx.stop // d)


def _edges(n_samples: int, parts: int) -> list[int]:
    return [round(i * n_samples / parts) for i in range(parts + 1)]


def split_blocks(shape: tuple[int, int], blocks: tuple[int, int], d: int, overlap: int = 20,
                 margin: int = 0) -> list[Block]:
    """Blocks of a field of ``shape`` (H, W) output pixels (multiples of d), row-major order."""
    h, w = (int(shape[0]), int(shape[1]))
    by, bx = (int(blocks[0]), int(blocks[1]))
    if by < 1 or bx < 1:
        raise ValueError(f"blocks must be two positive integers, got {blocks}")
    if h % d or w % d:
        raise ValueError(f"field {h}x{w} is not a whole number of view samples (d = {d})")
    if overlap < 0 or margin < 0:
        raise ValueError(f"overlap and margin must be >= 0, got {overlap}, {margin}")
    ext = math.ceil(overlap / (2 * d)) * d
    margin = math.ceil(margin / d) * d
    ye = [e * d for e in _edges(h // d, by)]
    xe = [e * d for e in _edges(w // d, bx)]
    smallest = min(min(np.diff(ye)), min(np.diff(xe)))
    if smallest < 1 or (max(by, bx) > 1 and smallest < 2 * ext):
        raise ValueError(f"blocks {by}x{bx} are too small ({smallest} px) for an overlap of "
                         f"{2 * ext} px; use fewer blocks or a smaller overlap")
    out = []
    for iy in range(by):
        for ix in range(bx):
            core = (ye[iy], ye[iy + 1], xe[ix], xe[ix + 1])
            region = (max(core[0] - ext, 0), min(core[1] + ext, h),
                      max(core[2] - ext, 0), min(core[3] + ext, w))
            window = (max(region[0] - margin, 0), min(region[1] + margin, h),
                      max(region[2] - margin, 0), min(region[3] + margin, w))
            out.append(Block((iy, ix), core, region, window, ext))
    return out


def block_centre_normalised(block: Block, shape: tuple[int, int]) -> tuple[float, float]:
    """Normalised coordinates (yn, xn) of a block core's centre: yn = 2 (y + 0.5) / H − 1."""
    y0, y1, x0, x1 = block.core
    yc, xc = (y0 + y1 - 1) / 2.0, (x0 + x1 - 1) / 2.0
    return 2.0 * (yc + 0.5) / shape[0] - 1.0, 2.0 * (xc + 0.5) / shape[1] - 1.0


def _ramp_1d(lo: int, hi: int, core_lo: int, core_hi: int, ext: int, n: int) -> np.ndarray:
    """Weights on pixels lo..hi-1: rising across [core_lo−ext, core_lo+ext), falling likewise."""
    y = np.arange(lo, hi, dtype=np.float64)
    w = np.ones_like(y)
    if ext > 0 and core_lo > 0:
        t = np.clip((y - (core_lo - ext) + 0.5) / (2 * ext), 0.0, 1.0)
        w *= 0.5 - 0.5 * np.cos(np.pi * t)
    if ext > 0 and core_hi < n:
        t = np.clip((y - (core_hi - ext) + 0.5) / (2 * ext), 0.0, 1.0)
        w *= 0.5 + 0.5 * np.cos(np.pi * t)
    return w


def block_weights(block: Block, shape: tuple[int, int]) -> np.ndarray:
    """Raised-cosine stitching weights (region shape) of a block; they sum to 1 over blocks."""
    y0, y1, x0, x1 = block.region
    wy = _ramp_1d(y0, y1, block.core[0], block.core[1], block.ext, shape[0])
    wx = _ramp_1d(x0, x1, block.core[2], block.core[3], block.ext, shape[1])
    return (wy[:, None] * wx[None, :]).astype(np.float32)


class Stitcher:
    """Accumulates weighted block regions into an output (NumPy array or a 2-D zarr array)."""

    def __init__(self, shape: tuple[int, int], out=None):
        self.shape = (int(shape[0]), int(shape[1]))
        self.out = np.zeros(self.shape, np.float32) if out is None else out
        if tuple(self.out.shape) != self.shape:
            raise ValueError(f"output array has shape {self.out.shape}, expected {self.shape}")

    def add(self, block: Block, image: np.ndarray) -> None:
        y0, y1, x0, x1 = block.region
        image = np.asarray(image, dtype=np.float32)
        if image.shape != (y1 - y0, x1 - x0):
            raise ValueError(f"block {block.index} image has shape {image.shape}, "
                             f"expected {(y1 - y0, x1 - x0)}")
        weighted = image * block_weights(block, self.shape)
        self.out[y0:y1, x0:x1] = np.asarray(self.out[y0:y1, x0:x1]) + weighted


def block_zernikes(blocks: list[Block], shape: tuple[int, int], grid: tuple[int, int],
                   zernike=None, field_zernike=None, n_modes: int = 45) -> np.ndarray:
    """Noll vectors (by, bx, J) per block: ``zernike`` (global) + ``field_zernike`` at the block.

    ``field_zernike``: an array (by, bx, J) matching the blocks is used as is; any other grid or a
    callable is evaluated at each block core's centre (metasensor.optics.field). J >= n_modes.
    """
    from metasensor.optics.field import evaluate_field_zernike

    by, bx = grid
    parts = []
    if zernike is not None:
        z = np.asarray(zernike, dtype=np.float64)
        if z.ndim != 1 or not np.isfinite(z).all():
            raise ValueError(f"zernike must be a finite 1-D Noll vector, got shape {z.shape}")
        parts.append(np.broadcast_to(z, (by, bx, z.size)))
    if field_zernike is not None:
        arr = None if callable(field_zernike) else np.asarray(field_zernike, dtype=np.float64)
        if arr is not None and arr.ndim == 3 and arr.shape[:2] == (by, bx):
            if not np.isfinite(arr).all():
                raise ValueError("field_zernike contains NaN or infinite values")
            parts.append(arr)
        else:
            cy = np.zeros((by, bx))
            cx = np.zeros((by, bx))
            for b in blocks:
                cy[b.index], cx[b.index] = block_centre_normalised(b, shape)
            parts.append(evaluate_field_zernike(field_zernike, cy, cx))
    j = max([n_modes] + [p.shape[-1] for p in parts])
    out = np.zeros((by, bx, j))
    for p in parts:
        out[..., :p.shape[-1]] += p
    return out.astype(np.float32)
