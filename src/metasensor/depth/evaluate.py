"""Scores of a disparity map against the truth: BadPix and mean squared error (the 4D light-field
benchmark's metrics, Honauer et al., ACCV 2016), on a chosen region."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["evaluation_mask", "score"]


def evaluation_mask(truth: np.ndarray, centre_view: np.ndarray | None = None, *,
                    edge_margin: int = 3, border: int = 3, jump: float = 0.05,
                    texture_fraction: float = 0.0, texture_radius: int = 3) -> np.ndarray:
    """Boolean mask of the pixels to score.

    Excluded: ``border`` pixels at the image edges; pixels within ``edge_margin`` of a depth
    discontinuity (a jump of the truth by more than ``jump`` between neighbours, i.e. not a smooth
    slant); and, when ``texture_fraction > 0``, untextured pixels whose local gradient energy of
    ``centre_view`` (box radius ``texture_radius``) is below ``texture_fraction`` × its median.
    """
    truth = np.asarray(truth, dtype=np.float64)
    jumps = np.zeros(truth.shape, dtype=bool)
    dy = np.abs(np.diff(truth, axis=0)) > jump
    dx = np.abs(np.diff(truth, axis=1)) > jump
    jumps[:-1] |= dy
    jumps[1:] |= dy
    jumps[:, :-1] |= dx
    jumps[:, 1:] |= dx
    mask = ~ndimage.binary_dilation(jumps, iterations=edge_margin) if edge_margin > 0 \
        else ~jumps
    if border > 0:
        mask[:border] = mask[-border:] = False
        mask[:, :border] = mask[:, -border:] = False
    if texture_fraction > 0 and centre_view is not None:
        gy, gx = np.gradient(np.asarray(centre_view, dtype=np.float64))
        energy = ndimage.uniform_filter(gy**2 + gx**2, size=2 * texture_radius + 1)
        mask &= energy >= texture_fraction * np.median(energy)
    return mask


def score(estimate: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None,
          threshold: float = 0.07) -> dict[str, float]:
    """``badpix`` (share of pixels with ``|error| > threshold``), ``mse``, ``rmse``, ``mae`` and
    ``coverage`` (share of pixels scored), in the units of the inputs."""
    est = np.asarray(estimate, dtype=np.float64)
    tru = np.asarray(truth, dtype=np.float64)
    if est.shape != tru.shape:
        raise ValueError(f"estimate shape {est.shape} != truth shape {tru.shape}")
    m = np.ones(est.shape, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if not m.any():
        raise ValueError("the evaluation mask is empty")
    err = (est - tru)[m]
    return {"badpix": float(np.mean(np.abs(err) > threshold)), "mse": float(np.mean(err**2)),
            "rmse": float(np.sqrt(np.mean(err**2))), "mae": float(np.mean(np.abs(err))),
            "coverage": float(m.mean())}
