"""Fringes at block borders: error power next to the multisite blocks' borders against elsewhere.

A reconstruction in blocks (:mod:`metasensor.recon.blocks`) models each block with one PSF bank;
where the aberration changes inside a block, the bank is wrong towards the block's borders and
the deconvolution leaves comb-like fringes along edges there. The *fringe ratio* measures it
against the truth x for an estimate x̂:

    ratio = mean_{B} (x̂ − x)²  /  mean_{not B} (x̂ − x)²,

B the pixels within ``width`` pixels (8 by default) of an interior block border (a core edge
shared by two blocks). 1 means the borders are no worse than the rest of the field; the issue's
bound for "no comb fringes" is 1.2. The error includes its mean (a block whose level is off is
a seam). The ratio also depends on what the chart puts next to the borders (edges err more than
flat areas), so it compares reconstructions of one capture, not different scenes.

Hand-written: a masked mean square (no library measures block-border error).
"""

from __future__ import annotations

import numpy as np

__all__ = ["border_mask", "fringe_ratio", "block_borders", "FRINGE_WIDTH"]

#: Pixels either side of a border that count as "at the border".
FRINGE_WIDTH = 8


def block_borders(shape: tuple[int, int], blocks: tuple[int, int], d: int
                  ) -> tuple[list[int], list[int]]:
    """Interior core borders (pixel rows, pixel columns; the first pixel after the border) of
    :func:`metasensor.recon.blocks.split_blocks` for a field of ``shape`` output pixels."""
    from metasensor.recon.blocks import split_blocks

    h, w = (int(shape[0]) // d * d, int(shape[1]) // d * d)
    found = split_blocks((h, w), blocks, d, overlap=0)
    ys = sorted({b.core[0] for b in found if b.core[0] > 0})
    xs = sorted({b.core[2] for b in found if b.core[2] > 0})
    return ys, xs


def border_mask(shape: tuple[int, int], rows, cols, width: int = FRINGE_WIDTH) -> np.ndarray:
    """Bool (H, W): True on pixels within ``width`` px of a border (pixel i with
    ``b − width <= i < b + width`` for a border before pixel b) of ``rows`` or ``cols``."""
    h, w = (int(shape[0]), int(shape[1]))
    if isinstance(width, bool) or not isinstance(width, int | np.integer) or width < 1:
        raise ValueError(f"width must be a positive whole number of pixels, got {width!r}")
    near_y = np.zeros(h, bool)
    near_x = np.zeros(w, bool)
    for b in rows:
        near_y[max(int(b) - width, 0):max(int(b) + width, 0)] = True
    for b in cols:
        near_x[max(int(b) - width, 0):max(int(b) + width, 0)] = True
    return near_y[:, None] | near_x[None, :]


def fringe_ratio(*, truth, image, rows, cols, width: int = FRINGE_WIDTH) -> float:
    """Error power within ``width`` px of the block borders over the error power elsewhere.

    Parameters
    ----------
    truth, image : array_like
        2-D, same shape, same (linear) units; not modified.
    rows, cols : sequence of int
        Interior block borders: the first pixel row / column after each border
        (:func:`block_borders`).
    width : int
        Pixels either side of a border that count as at the border.

    Returns
    -------
    float
        The ratio of the two mean squared errors (module docstring); NaN when either region is
        empty or the error elsewhere is zero.
    """
    a, b = np.asarray(image), np.asarray(truth)
    for arr, name in ((a, "image"), (b, "truth")):
        if arr.ndim != 2 or not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
            raise ValueError(f"{name} must be a real 2-D image, got shape {arr.shape}, "
                             f"dtype {arr.dtype}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{name} contains NaN or infinite values")
    if a.shape != b.shape:
        raise ValueError(f"image shape {a.shape} differs from truth shape {b.shape}")
    near = border_mask(b.shape, rows, cols, width)
    err2 = (a.astype(np.float64) - b.astype(np.float64)) ** 2
    if not near.any() or near.all():
        return float("nan")
    inside, outside = float(err2[near].mean()), float(err2[~near].mean())
    return inside / outside if outside > 0 else float("nan")
