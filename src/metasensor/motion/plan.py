"""The interpolation plan of motion correction: where every sample goes, and how to fill the
dense grid (Delaunay triangulation of the moved samples, :mod:`.scatter`), built once from a
dense motion field and applied to any number of views (one flow serves all views of a stack);
optionally with the graceful fallback of :mod:`.fallback` (the reference frame alone, where the
corrected image still shows the scan artefact)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from metasensor.motion.fallback import FallbackMap, blend
from metasensor.motion.scatter import ScatterInterpolator

__all__ = ["MotionPlan"]


class MotionPlan:
    """Where every sample goes and how to interpolate: built once from a dense motion field
    ``(2, H, W)``, applied to any number of views of that shape.

    ``affected``: pixels some moved sample influences (within ``p`` pixels of a moved sample's
    old or new position); every other pixel keeps its value. NaN motion (occluded samples) and
    ``drop`` leave samples out of the interpolation. ``fallback``: a
    :class:`~.fallback.FallbackMap` and the reference frame's scan phase ``(r, c)``; ``apply``
    then blends every corrected view towards its reference frame alone by the map's weight
    (:func:`.fallback.blend`).
    """

    def __init__(self, motion: np.ndarray, period: int, scatter: str = "linear",
                 drop: np.ndarray | None = None,
                 fallback: tuple[FallbackMap, tuple[int, int]] | None = None):
        motion = np.asarray(motion, np.float32)
        self.period = int(period)
        self.fallback = fallback
        _, h, w = motion.shape
        self.shape = (h, w)
        nan = np.isnan(motion).any(axis=0)  # occluded samples: left out
        if nan.any():
            drop = nan if drop is None else drop | nan
            motion = np.where(nan[None], 0.0, motion).astype(np.float32)
        moved = np.any(motion != 0, axis=0)
        if drop is not None:  # samples left out (their neighbourhood is re-interpolated)
            moved = moved | drop
        self.empty = not moved.any()
        if self.empty:
            return
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        qy, qx = yy + motion[0], xx + motion[1]
        margin = 2 * period
        keep = (qy > -margin) & (qy < h - 1 + margin) & (qx > -margin) & (qx < w - 1 + margin)
        moved_in = moved & keep if drop is None else moved & keep & ~drop
        landing = np.zeros((h, w), bool)
        ly = np.clip(np.rint(qy[moved_in]).astype(int), 0, h - 1)
        lx = np.clip(np.rint(qx[moved_in]).astype(int), 0, w - 1)
        landing[ly, lx] = True
        box = np.ones((2 * period + 1, 2 * period + 1), bool)
        self.affected = ndimage.binary_dilation(moved | landing, box)
        context = ndimage.binary_dilation(self.affected, box, iterations=2)
        used = moved_in | (context & ~moved)
        self.used = np.nonzero(used.ravel())[0]
        points = np.column_stack([qy.ravel()[self.used], qx.ravel()[self.used]])
        self.query = np.nonzero(self.affected.ravel())[0]
        queries = np.column_stack([yy.ravel()[self.query], xx.ravel()[self.query]])
        self.interp = ScatterInterpolator(points, queries, method=scatter)

    def apply(self, views: np.ndarray) -> np.ndarray:
        """Correct views ``(H, W)`` or ``(N, H, W)``; returns float32 of the same shape."""
        views = np.asarray(views, np.float32)
        single = views.ndim == 2
        stack = views[None] if single else views
        out = stack.copy()
        if not self.empty:
            flat = stack.reshape(len(stack), -1)
            vals = self.interp(flat[:, self.used].T)  # (M, N)
            res = out.reshape(len(stack), -1)
            cur = res[:, self.query]
            res[:, self.query] = np.where(np.isnan(vals.T), cur, vals.T)
        if self.fallback is not None:
            fmap, phase = self.fallback
            out = blend(stack, out, fmap, self.period, phase)
        return out[0] if single else out

    @property
    def identity(self) -> bool:
        """True when :meth:`apply` returns its input unchanged (nothing moved, no fallback)."""
        return self.empty and (self.fallback is None or not self.fallback[0].weight.any())

    def with_fallback(self, fmap: FallbackMap, phase: tuple[int, int]) -> MotionPlan:
        """This plan, blending towards the reference phase ``phase`` by ``fmap`` (in place)."""
        self.fallback = (fmap, tuple(phase))
        return self
