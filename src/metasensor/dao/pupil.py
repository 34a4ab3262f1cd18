"""Pupil amplitude from the views' angular intensity (paper, Methods: "Initial global aberration
estimation"): average the intensity of every view over a block, normalise by the brightest view
and binarise at a normalised threshold (0.5–0.8 all work). This captures vignetting
(non-telecentric systems, where the pupil image moves off the lenslet centre), annular pupils
(a Cassegrain telescope's central obstruction) and any other pupil shape, at the resolution of
one view. The result is an ``(nnum, nnum)`` 0/1 amplitude map in view coordinates, the form that
``view_psfs(cfg, amplitude=...)`` accepts (conventions.md: view (u, v) ↔ pupil point
``rho = −((v − c), (u − c)) / pupil_radius_px``).
"""

from __future__ import annotations

import numpy as np

from metasensor.config import SystemConfig

__all__ = ["angular_intensity", "estimate_pupil", "estimate_block_pupils"]


def _check_views(views, cfg: SystemConfig) -> np.ndarray:
    v = np.asarray(views)
    n = cfg.nnum
    if v.ndim != 4 or v.shape[:2] != (n, n):
        raise ValueError(f"views must have shape ({n}, {n}, H, W), got {v.shape}")
    if not np.isfinite(v).all():
        raise ValueError("views contain NaN or infinite values")
    return v


def angular_intensity(views, cfg: SystemConfig, background: float = 0.0) -> np.ndarray:
    """Mean intensity of every view minus ``background`` (a dark level, e.g. the sensor's
    offset), normalised so that the brightest view is 1 → (nnum, nnum) float32."""
    v = _check_views(views, cfg)
    means = v.reshape(cfg.nnum, cfg.nnum, -1).mean(axis=-1, dtype=np.float64) - background
    peak = means.max()
    if not peak > 0:
        raise ValueError("views carry no light: cannot estimate the pupil")
    return (means / peak).astype(np.float32)


def estimate_pupil(views, cfg: SystemConfig, threshold: float = 0.5) -> np.ndarray:
    """Binary pupil amplitude ``(nnum, nnum)`` float32 (1 inside, 0 outside) of one block.

    views : (nnum, nnum, H, W) the block's views; threshold : normalised level in (0, 1)
    (the paper finds 0.5–0.8 equivalent). Usable as ``view_psfs(cfg, amplitude=...)``.
    """
    if not (isinstance(threshold, (int, float)) and 0.0 < threshold < 1.0):
        raise ValueError(f"threshold must lie in (0, 1), got {threshold!r}")
    return (angular_intensity(views, cfg) >= threshold).astype(np.float32)


def estimate_block_pupils(views, cfg: SystemConfig, blocks: tuple[int, int] = (1, 1),
                          threshold: float = 0.5) -> np.ndarray:
    """Pupil amplitudes of a ``by × bx`` grid of equal blocks over the field of the views →
    ``(by, bx, nnum, nnum)`` float32 (block edges as in ``np.array_split``)."""
    v = _check_views(views, cfg)
    by, bx = (int(b) for b in blocks)
    if by < 1 or bx < 1 or by > v.shape[2] or bx > v.shape[3]:
        raise ValueError(f"blocks must be positive and at most the view size, got {blocks}")
    ys = np.array_split(np.arange(v.shape[2]), by)
    xs = np.array_split(np.arange(v.shape[3]), bx)
    out = np.empty((by, bx, cfg.nnum, cfg.nnum), np.float32)
    for i, yy in enumerate(ys):
        for j, xx in enumerate(xs):
            out[i, j] = estimate_pupil(v[:, :, yy[0]:yy[-1] + 1, xx[0]:xx[-1] + 1], cfg,
                                       threshold)
    return out
