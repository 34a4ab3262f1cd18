"""The sub-window of a block on which DAO's probe measures whether the block's aberration
needs a per-block estimate (:func:`metasensor.recon.block.reconstruct_block`).

A view shift is measured from the image's gradients, so the probe takes the part of the block
with the most detail: of a few candidate spans (the centred one and both ends per axis), the
one whose summed views vary most between neighbouring samples.
"""

from __future__ import annotations

import numpy as np

__all__ = ["probe_window"]


def _starts(n: int, size: int) -> list[int]:
    """Start offsets of a ``size`` span in ``n``: the centred one first, then both ends."""
    return list(dict.fromkeys(((n - size) // 2, 0, n - size)))


def probe_window(window: np.ndarray, samples: int) -> np.ndarray:
    """The ``samples`` x ``samples`` sub-window (view samples; the whole axis where it is
    shorter) of a block's ``window`` ``(nnum, nnum, h, w)`` with the most detail: of the
    centred span and the two end spans per axis (9 candidates), the one whose summed views
    have the largest sum of squared differences between neighbouring samples (ties: the
    centre). A view shift is measured from the image's gradients, so a featureless part of
    the block is never chosen over a textured one."""
    h, w = window.shape[-2:]
    sy, sx = min(h, samples), min(w, samples)
    if (sy, sx) == (h, w):
        return window
    img = window.sum(axis=(0, 1), dtype=np.float64)
    gy = np.zeros((h + 1, w + 1))  # integral images of the squared differences
    gy[1:h, 1:] = np.cumsum(np.cumsum(np.diff(img, axis=0) ** 2, 0), 1)
    gx = np.zeros((h + 1, w + 1))
    gx[1:, 1:w] = np.cumsum(np.cumsum(np.diff(img, axis=1) ** 2, 0), 1)

    def box(t: np.ndarray, y0: int, y1: int, x0: int, x1: int) -> float:
        return float(t[y1, x1] - t[y0, x1] - t[y1, x0] + t[y0, x0])

    best, where = -1.0, (0, 0)
    for y0 in _starts(h, sy):
        for x0 in _starts(w, sx):
            score = box(gy, y0, y0 + sy - 1, x0, x0 + sx) + box(gx, y0, y0 + sy, x0, x0 + sx - 1)
            if score > best:
                best, where = score, (y0, x0)
    y0, x0 = where
    return window[:, :, y0:y0 + sy, x0:x0 + sx]
