"""The views a depth estimate uses by default: the configured pupil, unless the data show more.

:meth:`metasensor.config.SystemConfig.view_mask` keeps the views well inside the main lens's
pupil (0.8 of its radius ``NA · f_mla / pitch``: 113 of the meta-imaging sensor's 15 × 15). A
light field from another camera (a rendered or captured full grid of 5 × 5 or 9 × 9 views
described by ``SystemConfig(nnum=n, scan=1)``) keeps the sensor's default NA, so that mask
would leave out views that carry the scene as well as the others. Behind a real pupil the views
beyond its radius are dark (they see no light, or only its rim); so a view beyond the configured
pupil that is as bright as the views inside it says the configuration's pupil is not the
data's. Then the default is every lit view (a mean at least ``LIT_FRACTION`` of the configured
views' median), and the estimate warns once, naming the counts. Views beyond the pupil are
never used where they are dark, so captures that match their configuration (the meta-imaging
sensor's, the simulator's) keep the configured mask.
"""

from __future__ import annotations

import warnings

import numpy as np

from metasensor.config import SystemConfig

__all__ = ["LIT_FRACTION", "default_view_mask"]

LIT_FRACTION = 0.8  # a view's mean, relative to the configured views' median, to count as lit


def default_view_mask(arr: np.ndarray, cfg: SystemConfig) -> np.ndarray:
    """The default ``(nnum, nnum)`` view mask of :func:`metasensor.depth.estimate_depth`.

    Parameters
    ----------
    arr : numpy.ndarray
        The checked views ``(nnum, nnum, H, W)``, any intensity unit (not modified).
    cfg : SystemConfig
        The system: its ``view_mask()`` and ``pupil_radius_px`` [view units].

    Returns
    -------
    numpy.ndarray
        Boolean ``(nnum, nnum)``: ``cfg.view_mask()``, or, where a view beyond the configured
        pupil's radius is lit (module docstring), that mask together with every lit view. Warns
        once (``UserWarning``, at the caller of ``estimate_depth``) in the second case.
    """
    configured = cfg.view_mask()
    means = arr.mean(axis=(2, 3), dtype=np.float64)
    ref = float(np.median(means[configured]))
    if not (np.isfinite(ref) and ref > 0):
        return configured
    lit = means >= LIT_FRACTION * ref
    u = np.arange(cfg.nnum) - cfg.center
    beyond = (u[:, None] ** 2 + u[None, :] ** 2) > cfg.pupil_radius_px**2 + 1e-9
    if not (lit & beyond).any():
        return configured
    mask = configured | lit
    warnings.warn(f"{int((lit & beyond).sum())} views beyond the configured pupil (radius "
                  f"{cfg.pupil_radius_px:.3g} views, from cfg.na) are lit, so the data's pupil "
                  f"is wider: using every lit view, {int(mask.sum())} of the {cfg.nnum} x "
                  f"{cfg.nnum}, not the configuration's {int(configured.sum())}; pass view_mask "
                  "to choose", UserWarning, stacklevel=3)
    return mask
