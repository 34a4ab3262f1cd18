"""Seam visibility: the gradient across a tile border against the gradients around it.

The same statistic as for reconstruction blocks (``tests/recon/test_recon_quality.py``): the mean
absolute gradient across each border row (column) divided by the largest row (column) mean of
the gradients within ``band`` pixels on either side; a visible seam stands out above its
surroundings (ratio > 1).
"""

from __future__ import annotations

import numpy as np

__all__ = ["seam_ratio"]


def _ratio(img: np.ndarray, borders, band: int) -> float:
    grad = np.abs(np.diff(img, axis=0))
    worst = 0.0
    for y in borders:
        if y - band - 1 < 0 or y + band > grad.shape[0]:
            continue
        across = grad[y - 1].mean()
        around = np.concatenate([grad[y - band - 1:y - 1], grad[y:y + band]]).mean(axis=1)
        worst = max(worst, float(across / max(around.max(), 1e-30)))
    return worst


def seam_ratio(img, borders_y, borders_x, band: int = 15) -> float:
    """Largest ratio over the horizontal borders (rows ``borders_y``) and the vertical ones
    (columns ``borders_x``) of an image (H, W); <= 1: no border stands out."""
    a = np.asarray(img, dtype=np.float64)
    return max(_ratio(a, borders_y, band), _ratio(a.T, borders_x, band))
