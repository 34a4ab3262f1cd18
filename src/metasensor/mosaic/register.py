"""Sub-pixel registration of mosaic tiles on their overlaps, and a global least-squares layout.

Each neighbouring pair is registered on the strip both tiles cover at their nominal positions
(phase correlation with matrix-multiply DFT up-sampling, Guizar-Sicairos et al., Opt. Lett. 33,
156 (2008): ``skimage.registration.phase_cross_correlation``, strips Hann-windowed so their
borders do not correlate). The pairwise offsets over-determine the tile positions; tile (0, 0)
stays at its nominal origin and the rest follow by least squares over all pairs (hand-written:
a few lines of linear algebra).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metasensor.mosaic.layout import MosaicLayout

__all__ = ["PairOffset", "register_pair", "register_tiles", "solve_positions"]


@dataclass(frozen=True)
class PairOffset:
    """a, b : tile indices; offset : measured (dy, dx) of b relative to its nominal position
    with respect to a (pixels); error : phase-correlation error (0 best, 1 worst)."""

    a: tuple[int, int]
    b: tuple[int, int]
    offset: tuple[float, float]
    error: float


def _strips(tile_a: np.ndarray, tile_b: np.ndarray, offset: tuple[int, int]):
    """The parts of a and b that overlap when b's origin sits at a's plus ``offset``."""
    h, w = tile_a.shape
    oy, ox = offset
    a = tile_a[max(oy, 0):min(h, h + oy), max(ox, 0):min(w, w + ox)]
    b = tile_b[max(-oy, 0):min(h, h - oy), max(-ox, 0):min(w, w - ox)]
    return a, b


def register_pair(tile_a, tile_b, nominal: tuple[int, int], upsample: int = 100,
                  margin: int = 4, rounds: int = 3) -> tuple[tuple[float, float], float]:
    """Offset (dy, dx) of tile b from its nominal position ``nominal`` (b's origin minus a's, in
    pixels) relative to tile a, and the correlation error.

    The overlap strip is cropped by ``margin`` pixels on every side (tile borders often carry
    reconstruction edge effects) and Hann-windowed. The window pulls a plain estimate towards
    zero shift, so ``rounds`` estimates are chained: each crops b's strip at the integer part of
    the offset so far and shifts it by the fractional part (cubic splines), and measures what is
    left.
    """
    from scipy import ndimage
    from skimage.filters import window
    from skimage.registration import phase_cross_correlation

    a, b = tile_a, tile_b  # NumPy or Zarr arrays: only the overlap strips are read
    if len(a.shape) != 2 or tuple(a.shape) != tuple(b.shape):
        raise ValueError(f"tiles must be 2-D arrays of one shape, got {a.shape} and {b.shape}")
    total = np.zeros(2)
    error = 1.0
    for _ in range(max(int(rounds), 1)):
        whole = np.floor(total + 0.5).astype(int)
        frac = total - whole
        # b shifted by its offset so far: b's pixel p then shows what a shows at nominal + p
        nominal_now = (int(nominal[0]) + int(whole[0]), int(nominal[1]) + int(whole[1]))
        sa, sb = (np.asarray(x, dtype=np.float64) for x in _strips(a, b, nominal_now))
        if min(sa.shape) <= 2 * margin + 8:
            raise ValueError(f"overlap {sa.shape} too small to register (margin {margin})")
        if frac.any():
            sb = ndimage.shift(sb, frac, order=3, mode="nearest")
        m = slice(margin, -margin) if margin else slice(None)
        sa, sb = sa[m, m], sb[m, m]
        win = window("hann", sa.shape)
        sa = (sa - sa.mean()) * win
        sb = (sb - sb.mean()) * win
        shift, error, _ = phase_cross_correlation(sa, sb, upsample_factor=upsample,
                                                  normalization=None)
        total = total + np.asarray(shift, dtype=np.float64)
        if np.abs(shift).max() < 1.0 / upsample:
            break
    return (float(total[0]), float(total[1])), float(error)


def register_tiles(tiles, layout: MosaicLayout, upsample: int = 100) -> list[PairOffset]:
    """Register every overlapping pair of ``tiles`` (mapping index -> (h, w) array)."""
    out = []
    for a, b in layout.neighbours():
        (ay, ax), (by, bx) = layout.origin(a), layout.origin(b)
        off, err = register_pair(tiles[a], tiles[b], (by - ay, bx - ax), upsample)
        out.append(PairOffset(a, b, off, err))
    return out


def solve_positions(pairs: list[PairOffset], layout: MosaicLayout) -> dict:
    """Tile origins (index -> (y, x) float mosaic pixels) that best fit the pairwise offsets
    (least squares; tile (0, 0) fixed at its nominal origin)."""
    idx = layout.indices
    pos = {k: n for n, k in enumerate(idx)}
    rows = len(pairs) + 1
    mat = np.zeros((rows, len(idx)))
    rhs = np.zeros((rows, 2))
    for r, p in enumerate(pairs):
        mat[r, pos[p.b]], mat[r, pos[p.a]] = 1.0, -1.0
        (ay, ax), (by, bx) = layout.origin(p.a), layout.origin(p.b)
        rhs[r] = (by - ay + p.offset[0], bx - ax + p.offset[1])
    mat[-1, 0] = 1.0
    rhs[-1] = layout.origin(idx[0])
    sol, *_ = np.linalg.lstsq(mat, rhs, rcond=None)
    return {k: (float(sol[n, 0]), float(sol[n, 1])) for n, k in enumerate(idx)}
