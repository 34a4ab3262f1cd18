"""Where the tiles of a mosaic sit: one lens, the sensor moved laterally to a grid of positions.

Extended Data Fig. 7 of the paper: the lens stays fixed, the sensor is shifted to cover a field
larger than itself, and the captures are stitched with small overlaps. Tile (i, j) covers the
mosaic pixels ``origin + [0, tile_h) × [0, tile_w)`` with nominal origins
``(i · (tile_h − overlap), j · (tile_w − overlap))``; the mosaic (the lens's image field) has
normalised coordinates ``(yn, xn) ∈ [−1, 1]²`` over its whole extent, so one calibration of the
lens (a field aberration ``f(yn, xn) -> Noll vector``) serves every tile
(:meth:`MosaicLayout.tile_field_zernike`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MosaicLayout"]


@dataclass(frozen=True)
class MosaicLayout:
    """tile_shape : (h, w) pixels of one tile; grid : (rows, columns) of tiles;
    overlap : nominal overlap of neighbours in pixels (>= 8, less than half a tile)."""

    tile_shape: tuple[int, int]
    grid: tuple[int, int] = (2, 2)
    overlap: int = 64

    def __post_init__(self) -> None:
        th, tw = (int(v) for v in self.tile_shape)
        gy, gx = (int(v) for v in self.grid)
        if th < 16 or tw < 16:
            raise ValueError(f"tile_shape must be at least 16 x 16, got {self.tile_shape}")
        if gy < 1 or gx < 1:
            raise ValueError(f"grid must be positive, got {self.grid}")
        ok = isinstance(self.overlap, int | np.integer)
        if not (ok and 8 <= self.overlap < min(th, tw) // 2):
            raise ValueError(f"overlap must be an integer in [8, {min(th, tw) // 2}), "
                             f"got {self.overlap!r}")
        object.__setattr__(self, "tile_shape", (th, tw))
        object.__setattr__(self, "grid", (gy, gx))

    @property
    def step(self) -> tuple[int, int]:
        return self.tile_shape[0] - self.overlap, self.tile_shape[1] - self.overlap

    @property
    def shape(self) -> tuple[int, int]:
        """(H, W) of the mosaic at the nominal positions."""
        (sy, sx), (th, tw) = self.step, self.tile_shape
        return (self.grid[0] - 1) * sy + th, (self.grid[1] - 1) * sx + tw

    @property
    def indices(self) -> list[tuple[int, int]]:
        return [(i, j) for i in range(self.grid[0]) for j in range(self.grid[1])]

    def origin(self, index: tuple[int, int]) -> tuple[int, int]:
        """Nominal mosaic pixel of the tile's pixel (0, 0)."""
        i, j = index
        return i * self.step[0], j * self.step[1]

    def neighbours(self) -> list[tuple[tuple[int, int], tuple[int, int]]]:
        """Pairs of tiles that overlap (right and lower neighbours)."""
        pairs = []
        for i, j in self.indices:
            if j + 1 < self.grid[1]:
                pairs.append(((i, j), (i, j + 1)))
            if i + 1 < self.grid[0]:
                pairs.append(((i, j), (i + 1, j)))
        return pairs

    def covered(self, positions: dict) -> tuple[int, int, int, int]:
        """The largest pixel rectangle ``(y0, x0, y1, x1)`` (end exclusive) inside the samples of
        the outer tiles at their (registered, sub-pixel) ``positions`` (index -> (y, x) of the
        tile's pixel (0, 0)): where tiles moved inwards the nominal mosaic's rim has no data.
        The interior is covered when neighbours overlap, which the layout's overlap ensures for
        position errors below a quarter of it."""
        (gy, gx), (th, tw) = self.grid, self.tile_shape
        for k in self.indices:
            if k not in positions:
                raise ValueError(f"positions lack tile {k}")
        y0 = max(int(np.ceil(positions[(0, j)][0] - 1e-6)) for j in range(gx))
        x0 = max(int(np.ceil(positions[(i, 0)][1] - 1e-6)) for i in range(gy))
        y1 = min(int(np.floor(positions[(gy - 1, j)][0] + th - 1 + 1e-6)) + 1 for j in range(gx))
        x1 = min(int(np.floor(positions[(i, gx - 1)][1] + tw - 1 + 1e-6)) + 1 for i in range(gy))
        if y1 <= y0 or x1 <= x0:
            raise ValueError(f"the tiles at {positions} cover no common rectangle")
        return y0, x0, y1, x1

    def tile_field_zernike(self, fz_lens, index: tuple[int, int],
                           tile_shape: tuple[int, int] | None = None,
                           offset: float | tuple[float, float] = 0.0):
        """The lens's field aberration ``fz_lens(yn, xn)`` (mosaic-normalised coordinates)
        re-expressed in the normalised coordinates of one tile's image of ``tile_shape``
        (default the tile), whose pixel (y, x) is tile pixel (y + offset_y, x + offset_x)."""
        h, w = self.shape
        oy, ox = self.origin(index)
        ih, iw = tile_shape or self.tile_shape
        dy, dx = (offset, offset) if np.isscalar(offset) else (float(v) for v in offset)

        def fz(yn, xn):
            y = (np.asarray(yn, float) + 1.0) * ih / 2.0 - 0.5 + dy + oy
            x = (np.asarray(xn, float) + 1.0) * iw / 2.0 - 0.5 + dx + ox
            return fz_lens(2.0 * (y + 0.5) / h - 1.0, 2.0 * (x + 0.5) / w - 1.0)

        return fz
