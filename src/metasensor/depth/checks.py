"""Checks of the views and settings of :func:`metasensor.depth.estimate_depth`.

Each bad input raises one ``ValueError`` or ``TypeError`` whose one-line message names the
input and what is wrong with it; nothing is modified.
"""

from __future__ import annotations

import math

import numpy as np

from metasensor.config import SystemConfig
from metasensor.depth.edges import EdgeSnap
from metasensor.depth.learned import EdgeRefiner
from metasensor.depth.sgm import SemiGlobal
from metasensor.depth.span import MAX_CANDIDATES
from metasensor.depth.speckle import Speckles
from metasensor.depth.visibility import Visibility

__all__ = ["check_settings", "check_views"]


def check_views(views, cfg: SystemConfig) -> np.ndarray:
    """The views of :func:`metasensor.depth.estimate_depth` as an array, checked.

    Parameters
    ----------
    views : array_like or Capture
        ``(nnum, nnum, H, W)`` real view stack (intensity, any unit), or an object with
        ``.views`` (a ``Capture``). Not copied or modified here.
    cfg : SystemConfig
        The system whose ``nnum`` the view grid must match.

    Returns
    -------
    numpy.ndarray
        The views ``(nnum, nnum, H, W)`` (a view of the input where it is already an array).

    Raises
    ------
    ValueError
        Wrong shape, a view grid other than ``cfg.nnum``, or views smaller than 4 px.
    TypeError
        ``cfg`` not a ``SystemConfig``, or views that are not real numbers.
    """
    if not isinstance(cfg, SystemConfig):
        raise TypeError(f"cfg must be a SystemConfig, got {type(cfg).__name__}")
    if hasattr(views, "views") and not isinstance(views, np.ndarray):  # a Capture
        views = views.views
    arr = np.asarray(views)
    if arr.ndim != 4 or arr.shape[0] != arr.shape[1]:
        raise ValueError(f"views must have shape (nnum, nnum, H, W), got {arr.shape}")
    if arr.shape[0] != cfg.nnum:
        raise ValueError(f"views have {arr.shape[0]} x {arr.shape[1]} views but cfg.nnum is "
                         f"{cfg.nnum}")
    if min(arr.shape[2:]) < 4:
        raise ValueError(f"views are too small for depth estimation: {arr.shape[2:]}")
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise TypeError(f"views must be real numbers, got dtype {arr.dtype}")
    return arr


def check_settings(cfg, arr, candidates, radius, refine_iterations, refine_radius, fill_radius,
                   eps, disparity_range, view_mask, smoothing=None, edges=None,
                   refiner=None, speckles=None, visibility=None) -> np.ndarray:
    """Validate the settings of :func:`metasensor.depth.estimate_depth` (one-line errors).

    Parameters
    ----------
    cfg : SystemConfig
        The system (``nnum``, ``center``, ``view_mask()``).
    arr : numpy.ndarray
        The checked views ``(nnum, nnum, H, W)`` (:func:`check_views`).
    candidates, radius, refine_iterations, refine_radius, fill_radius, eps : int, float or None
        As :func:`metasensor.depth.estimate_depth` takes them (windows in view px).
    disparity_range, view_mask, smoothing, edges, refiner, speckles, visibility : optional
        As :func:`metasensor.depth.estimate_depth` takes them (the span in view px per view
        step).

    Returns
    -------
    mask : numpy.ndarray
        The boolean ``(nnum, nnum)`` mask of the views to use.
    fill_radius : int
        ``fill_radius``, or where None its default: 16 view px, or the views' larger side where
        they are smaller.

    Raises
    ------
    ValueError
        A setting out of its range, a span the views cannot show, or a view mask without the
        centre view and one other.
    TypeError
        A settings object of the wrong class.
    """
    if fill_radius is None:
        fill_radius = min(16, max(arr.shape[2:]))
    for name, value, kind in (("smoothing", smoothing, SemiGlobal), ("edges", edges, EdgeSnap),
                              ("refiner", refiner, EdgeRefiner),
                              ("speckles", speckles, Speckles),
                              ("visibility", visibility, Visibility)):
        if value is not None and not isinstance(value, kind):
            article = "an" if kind.__name__[0] in "AEIOU" else "a"
            raise TypeError(f"{name} must be {article} {kind.__name__} or None, got "
                            f"{type(value).__name__}")
    n, c = cfg.nnum, cfg.center
    side = max(arr.shape[2:])
    # upper bounds: windows beyond the view, and sweeps finer than 1/1000 of the range (a cost
    # volume of candidates x H x W floats) are mistakes, not settings
    checks = [("radius", radius, 1, side), ("refine_iterations", refine_iterations, 0, 100),
              ("fill_radius", fill_radius, 1, side)]
    if candidates is not None:
        checks.append(("candidates", candidates, 3, MAX_CANDIDATES))
    if refine_radius is not None:
        checks.append(("refine_radius", refine_radius, 1, side))
    for name, value, low, high in checks:
        if not (isinstance(value, int | np.integer) and low <= value <= high):
            raise ValueError(f"{name} must be an integer in [{low}, {high}], got {value!r}")
    if not (isinstance(eps, int | float) and math.isfinite(eps) and eps > 0):
        raise ValueError(f"eps must be a positive number, got {eps!r}")
    if disparity_range is not None and (np.shape(disparity_range) != (2,)
                                        or not np.isfinite(disparity_range).all()
                                        or disparity_range[0] >= disparity_range[1]):
        raise ValueError(f"disparity_range must be (low, high) with low < high, "
                         f"got {disparity_range!r}")
    h, w = arr.shape[2:]
    if disparity_range is not None and max(map(abs, disparity_range)) * c > max(h, w):
        raise ValueError(f"disparity_range {tuple(disparity_range)} shifts the outer views by "
                         f"more than the {h}x{w} views (at most ±{max(h, w) / max(c, 1):.3g})")
    mask = cfg.view_mask() if view_mask is None else np.asarray(view_mask, dtype=bool)
    if mask.shape != (n, n):
        raise ValueError(f"view_mask must have shape {(n, n)}, got {mask.shape}")
    if not mask[c, c] or mask.sum() < 2:
        raise ValueError("view_mask must contain the centre view and at least one other view")
    return mask, fill_radius
