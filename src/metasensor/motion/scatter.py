"""Scattered-data interpolation of motion-corrected samples onto the dense view grid.

The paper interpolates the scattered samples with a cubic scattered interpolation; this is
scipy's Clough–Tocher interpolant (``griddata(method="cubic")``) on one Delaunay triangulation,
built once and reused for every value set (every view, when one flow serves all views: the
samples sit at the same positions in all views). ``method="linear"`` is the barycentric
interpolant on the same triangulation, held as a sparse matrix (much faster for many views).
"""

from __future__ import annotations

import numpy as np

__all__ = ["ScatterInterpolator"]


def _barycentric_transform(points: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """scipy's ``Delaunay.transform`` layout ``(nsimplex, 3, 2)``, computed vectorised.

    (scipy computes it simplex by simplex, which took tens of seconds for 10⁵ triangles here.)
    ``T[s, :2] @ (x − T[s, 2])`` are the first two barycentric coordinates; degenerate
    triangles get NaN, as in scipy.
    """
    v = points[simplices]  # (n, 3, 2)
    a = v[:, 0] - v[:, 2]
    b = v[:, 1] - v[:, 2]
    det = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.empty((len(v), 2, 2))
        inv[:, 0, 0] = b[:, 1] / det
        inv[:, 0, 1] = -b[:, 0] / det
        inv[:, 1, 0] = -a[:, 1] / det
        inv[:, 1, 1] = a[:, 0] / det
    bad = np.abs(det) < 1e-12 * np.maximum(np.abs(a).sum(1) * np.abs(b).sum(1), 1e-300)
    inv[bad] = np.nan
    out = np.empty((len(v), 3, 2))
    out[:, :2] = inv
    out[:, 2] = v[:, 2]
    return out


class ScatterInterpolator:
    """Interpolate values known at ``points (N, 2)`` (y, x) onto query pixels ``queries (M, 2)``.

    Build once (triangulation), call many times: ``interp(values)`` with values ``(N,)`` or
    ``(N, C)`` → ``(M,)`` or ``(M, C)`` float32; NaN outside the convex hull of the points.
    """

    def __init__(self, points: np.ndarray, queries: np.ndarray, method: str = "cubic"):
        from scipy.spatial import Delaunay

        if method not in ("cubic", "linear"):
            raise ValueError(f"scatter method must be 'cubic' or 'linear', got {method!r}")
        self.points = np.asarray(points, np.float64)
        self.queries = np.asarray(queries, np.float64)
        self.method = method
        self.tri = Delaunay(self.points)
        if hasattr(self.tri, "_transform"):  # precompute scipy's lazy (slow) transform
            self.tri._transform = _barycentric_transform(self.tri.points, self.tri.simplices)
        if method == "linear":
            self._matrix = self._barycentric_matrix()

    def _barycentric_matrix(self):
        from scipy.sparse import csr_matrix

        simplex = self.tri.find_simplex(self.queries)
        inside = simplex >= 0
        s = simplex[inside]
        trans = self.tri.transform[s]  # (m, 3, 2)
        delta = self.queries[inside] - trans[:, 2]
        bary = np.einsum("mij,mj->mi", trans[:, :2], delta)
        weights = np.column_stack([bary, 1 - bary.sum(axis=1)])
        rows = np.repeat(np.nonzero(inside)[0], 3)
        cols = self.tri.simplices[s].ravel()
        mat = csr_matrix((weights.ravel(), (rows, cols)),
                         shape=(len(self.queries), len(self.points)))
        self._outside = ~inside
        return mat

    def __call__(self, values: np.ndarray) -> np.ndarray:
        values = np.asarray(values)
        if values.shape[0] != len(self.points):
            raise ValueError(f"values must have {len(self.points)} rows, got {values.shape}")
        if self.method == "linear":
            out = self._matrix @ values.astype(np.float64)
            out[self._outside] = np.nan
            return out.astype(np.float32)
        from scipy.interpolate import CloughTocher2DInterpolator

        interp = CloughTocher2DInterpolator(self.tri, values.astype(np.float64))
        return interp(self.queries).astype(np.float32)
