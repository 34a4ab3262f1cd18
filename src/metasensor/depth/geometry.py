"""Geometry of depth from the views: disparity ↔ image-side depth ↔ object distance.

Conventions (docs/conventions.md):

- View (u, v) has the angular offset ``a = (u − c, v − c)``, ``c = nnum // 2``.
- Disparity ``δ`` is in **view pixels per view step**: view (u, v) content at position
  ``p + δ · a`` equals the centre-view content at ``p``.
- Views are sampled every ``d = nnum // scan`` image (sensor) pixels, and a point focused a
  distance ``z`` in front of the MLA moves by ``z / mla_focal`` image pixels per view step, so
  ``z = δ · d · pixel_pitch · mla_focal / pixel_pitch = δ · d · mla_focal``
  (``z`` in metres, ``z > 0``: focused before the MLA, towards the main lens).
- Main lens (thin lens, optional ``focal_length`` f and ``focus_distance`` s_o0): the MLA sits
  at the image distance ``s_i0 = 1 / (1/f − 1/s_o0)``. A point focused ``z`` in front of the MLA
  has the image distance ``s_i = s_i0 − z`` and the object distance ``s_o = 1 / (1/f − 1/s_i)``:
  ``z > 0`` ⇔ the object is farther than the focus distance. Image distances ``s_i <= f``
  have no real object (``s_o`` = +inf, returned as NaN).
"""

from __future__ import annotations

import numpy as np

from metasensor.config import SystemConfig

__all__ = [
    "view_offsets",
    "default_disparity_range",
    "disparity_candidates",
    "disparity_to_image_depth",
    "image_depth_to_disparity",
    "image_depth_to_object_distance",
    "object_distance_to_image_depth",
    "main_lens_geometry",
]


def view_offsets(nnum: int) -> tuple[np.ndarray, np.ndarray]:
    """Angular offsets ``(u − c, v − c)`` of every view, each ``(nnum, nnum)`` float64."""
    a = np.arange(nnum, dtype=np.float64) - nnum // 2
    au, av = np.meshgrid(a, a, indexing="ij")
    return au, av


def default_disparity_range(cfg: SystemConfig) -> tuple[float, float]:
    """Default search range of disparities [view px per view step]: ``±scan / 2``.

    This is ±nnum/2 image pixels per view step: up to there a view's own sub-aperture defocus
    blur (one view step of disparity, in image pixels) stays below half a lenslet pitch. It is the
    same image-side depth range, ``±nnum/2 · mla_focal``, for every scan period.
    """
    half = cfg.scan / 2.0
    return (-half, half)


def disparity_candidates(disparity_range: tuple[float, float], n: int) -> np.ndarray:
    """``n`` equally spaced candidate disparities spanning ``disparity_range`` (inclusive)."""
    lo, hi = (float(disparity_range[0]), float(disparity_range[1]))
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
        raise ValueError(f"disparity_range must be finite with lo < hi, got {disparity_range}")
    if int(n) < 3:
        raise ValueError(f"candidates must be >= 3, got {n}")
    return np.linspace(lo, hi, int(n))


def disparity_to_image_depth(disparity, cfg: SystemConfig):
    """Image-side depth ``z = δ · d · mla_focal`` [m] from disparity [view px per view step]."""
    return np.asarray(disparity, dtype=np.float64) * cfg.scan_step_px * cfg.mla_focal


def image_depth_to_disparity(z, cfg: SystemConfig):
    """Disparity [view px per view step] of a point focused ``z`` metres in front of the MLA."""
    return np.asarray(z, dtype=np.float64) / (cfg.scan_step_px * cfg.mla_focal)


def main_lens_geometry(cfg: SystemConfig, focal_length: float | None = None,
                       focus_distance: float | None = None) -> tuple[float, float] | None:
    """``(f, s_o0)`` from the arguments or the config, or ``None`` when either is unknown."""
    f = focal_length if focal_length is not None else cfg.focal_length
    s0 = focus_distance if focus_distance is not None else cfg.focus_distance
    if f is None or s0 is None:
        return None
    f, s0 = float(f), float(s0)
    if not (np.isfinite(f) and f > 0):
        raise ValueError(f"focal_length must be positive and finite, got {f!r}")
    if not (np.isfinite(s0) and s0 > f):
        raise ValueError(f"focus_distance {s0!r} must exceed focal_length {f!r} (a real image)")
    return f, s0


def _image_distance(f: float, s_o):
    return 1.0 / (1.0 / f - 1.0 / s_o)


def image_depth_to_object_distance(z, f: float, focus_distance: float):
    """Object distance [m] of a point focused ``z`` metres in front of the MLA (thin lens).

    ``s_i = s_i0 − z``, ``s_o = 1/(1/f − 1/s_i)``; NaN where ``s_i <= f`` (no real object).
    """
    z = np.asarray(z, dtype=np.float64)
    s_i = _image_distance(f, focus_distance) - z
    with np.errstate(divide="ignore", invalid="ignore"):
        s_o = 1.0 / (1.0 / f - 1.0 / s_i)
    return np.where(s_i > f, s_o, np.nan)


def object_distance_to_image_depth(s_o, f: float, focus_distance: float):
    """Inverse of :func:`image_depth_to_object_distance`: ``z = s_i0 − s_i(s_o)`` [m]."""
    s_o = np.asarray(s_o, dtype=np.float64)
    if np.any(s_o <= f):
        raise ValueError("object distances must exceed the focal length (a real image)")
    return _image_distance(f, focus_distance) - _image_distance(f, s_o)
