"""Partitions of unity over the field and over depth: the blocks and layers the simulator renders.

Field-dependent blur: PSF banks at a grid of field points (block centres) and smooth bilinear
(hat) weights ``w_k`` with ``Σ_k w_k = 1``; the image is ``Σ_k H_k ⊛ (w_k · scene)``, i.e. the
PSF is interpolated between block centres. Depth: a depth map (metres, image side) is split
into planes with hat weights between adjacent planes (one-hot masks when the map holds only the
plane values); no occlusion is modelled (each layer is rendered as if the others were absent).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metasensor.optics.field import block_centres_normalised, evaluate_field_zernike

__all__ = ["Component", "field_grid", "depth_layers", "build_components", "add_zernike"]


@dataclass(frozen=True)
class Component:
    """One rendered piece: ``weight`` (H, W) (None = 1 everywhere), the row/column box where the
    weight is non-zero (inclusive), the total Zernike vector and the depth [m] of its PSF bank."""

    weight: np.ndarray | None
    box: tuple[int, int, int, int]
    zernike: np.ndarray | None
    depth: float
    block: tuple[int, int] | None = None


def add_zernike(a, b) -> np.ndarray | None:
    """Sum of two Noll vectors of possibly different length (None = zero)."""
    if a is None and b is None:
        return None
    a = np.zeros(0) if a is None else np.asarray(a, dtype=np.float64).ravel()
    b = np.zeros(0) if b is None else np.asarray(b, dtype=np.float64).ravel()
    out = np.zeros(max(a.size, b.size))
    out[:a.size] += a
    out[:b.size] += b
    return out


def _hats(n_px: int, n_blocks: int) -> np.ndarray:
    """(n_blocks, n_px) bilinear weights of pixel centres between block centres (sum 1)."""
    centres = (np.arange(n_blocks) + 0.5) * n_px / n_blocks - 0.5
    pos = np.arange(n_px, dtype=np.float64)
    eye = np.eye(n_blocks)
    return np.stack([np.interp(pos, centres, eye[i]) for i in range(n_blocks)])


def field_grid(field_zernike, shape: tuple[int, int], blocks: tuple[int, int] = (4, 4)
               ) -> np.ndarray:
    """Noll vectors at the block centres: the array itself (by, bx, J), or a callable of
    normalised field coordinates evaluated at a ``blocks`` grid of centres."""
    if callable(field_zernike):
        by, bx = blocks
        if by < 1 or bx < 1:
            raise ValueError(f"field_blocks must be positive, got {blocks}")
        yn, xn = block_centres_normalised(by, bx)
        return evaluate_field_zernike(field_zernike, yn, xn)
    grid = np.asarray(field_zernike, dtype=np.float64)
    if grid.ndim != 3 or grid.shape[0] < 1 or grid.shape[1] < 1:
        raise ValueError(f"field_zernike must be an array (by, bx, J) or a callable, "
                         f"got shape {grid.shape}")
    if not np.isfinite(grid).all():
        raise ValueError("field_zernike contains NaN or infinite values")
    if grid.shape[0] > shape[0] or grid.shape[1] > shape[1]:
        raise ValueError(f"field_zernike grid {grid.shape[:2]} is finer than the scene {shape}")
    return grid


def depth_layers(depth, shape: tuple[int, int], max_planes: int = 8
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Planes (Z,) [m] and hat weights (Z, H, W) summing to 1 for a depth map ``depth``."""
    depth = np.asarray(depth, dtype=np.float64)
    if depth.ndim == 0:
        return depth.reshape(1), np.ones((1, *shape))
    if depth.shape != tuple(shape):
        raise ValueError(f"depth map shape {depth.shape} differs from the scene shape {shape}")
    if not np.isfinite(depth).all():
        raise ValueError("depth map contains NaN or infinite values")
    planes = np.unique(depth)
    if planes.size > max_planes:
        planes = np.linspace(depth.min(), depth.max(), max_planes)
    if planes.size == 1:
        return planes, np.ones((1, *shape))
    eye = np.eye(planes.size)
    weights = np.stack([np.interp(depth, planes, eye[i]) for i in range(planes.size)])
    return planes, weights


def _box(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    rows = np.nonzero(mask.any(axis=1))[0]
    if rows.size == 0:
        return None
    cols = np.nonzero(mask.any(axis=0))[0]
    return int(rows[0]), int(rows[-1]), int(cols[0]), int(cols[-1])


def build_components(shape: tuple[int, int], zernike=None, field=None, depth=None,
                     max_planes: int = 8) -> tuple[list[Component], np.ndarray]:
    """Components for a scene of ``shape``: field grid (by, bx, J) or None, depth map or None.

    Returns (components, planes). Weights are products of field hats and depth weights.
    """
    h, w = shape
    full = (0, h - 1, 0, w - 1)
    if depth is None:
        planes, dweights = np.zeros(1), None
    else:
        planes, dweights = depth_layers(depth, shape, max_planes)
        if planes.size == 1:
            dweights = None
    if field is None:
        blocks = [(None, None, full, zernike)]
    else:
        by, bx = field.shape[:2]
        hy, hx = _hats(h, by), _hats(w, bx)
        blocks = []
        for i in range(by):
            for j in range(bx):
                ry, rx = np.nonzero(hy[i] > 0)[0], np.nonzero(hx[j] > 0)[0]
                box = (int(ry[0]), int(ry[-1]), int(rx[0]), int(rx[-1]))
                wmap = None if by * bx == 1 else np.outer(hy[i], hx[j]).astype(np.float32)
                blocks.append(((i, j), wmap, box, add_zernike(zernike, field[i, j])))
    comps = []
    for block, wmap, box, z in blocks:
        for k, zplane in enumerate(planes):
            weight, cbox = wmap, box
            if dweights is not None:
                dw = dweights[k].astype(np.float32)
                weight = dw if weight is None else weight * dw
                sub = _box(weight > 0)
                if sub is None:
                    continue
                cbox = sub
            comps.append(Component(weight, cbox, z, float(zplane), block))
    return comps, planes
