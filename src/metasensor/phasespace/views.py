"""The order in which the views of a bank are visited, and their interleaved subsets.

View ``(u, v)`` sees the pupil point ``rho = −((v − c), (u − c)) / pupil_radius_px``
(docs/conventions.md); the orders here sort views by that pupil position. A PSF bank and its data
are stacked in one order, and ordered-subset solvers take subsets as consecutive runs of it
(:func:`subset_major`), so every subset covers the whole pupil.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["view_order", "make_subsets", "subset_major", "subset_runs", "ORDERS"]

ORDERS = ("spiral", "radius", "raster")


def view_order(mask: np.ndarray, order: str = "spiral") -> list[tuple[int, int]]:
    """The ``(u, v)`` of the views in ``mask`` in visiting order.

    Parameters
    ----------
    mask : array_like
        ``(nnum, nnum)`` bool, the views used.
    order : str
        ``"spiral"``: outermost pupil radius first, counter-clockwise within a ring (the
        authors' order, Lu et al. Opt. Express 2019); ``"radius"``: centre view first, then by
        increasing radius; ``"raster"``: row-major.

    Returns
    -------
    list of (int, int)
    """
    if order not in ORDERS:
        raise ValueError(f"order must be one of {ORDERS}, got {order!r}")
    mask = np.asarray(mask, dtype=bool)
    n = mask.shape[0]
    c = n // 2
    uv = [(int(u), int(v)) for u, v in zip(*np.nonzero(mask), strict=True)]
    if order == "raster":
        return uv

    def polar(p):
        dy, dx = p[0] - c, p[1] - c
        return math.hypot(dy, dx), math.atan2(dy, dx) % (2 * math.pi)

    if order == "spiral":
        return sorted(uv, key=lambda p: (-round(polar(p)[0], 6), polar(p)[1]))
    return sorted(uv, key=lambda p: (round(polar(p)[0], 6), polar(p)[1]))


def make_subsets(n_views: int, n_subsets: int) -> list[list[int]]:
    """Split positions ``0..n_views-1`` (already in visiting order) into ``n_subsets``
    interleaved subsets (clipped to 1..n_views)."""
    n_subsets = int(min(max(n_subsets, 1), n_views))
    return [list(range(k, n_views, n_subsets)) for k in range(n_subsets)]


def subset_major(items: list, n_subsets: int) -> list:
    """Reorder ``items`` (in visiting order) so each interleaved subset is a consecutive run
    (what :func:`metasensor.solvers.richardson_lucy.richardson_lucy` takes: contiguous OTF
    slices, no copies)."""
    return [items[i] for g in make_subsets(len(items), n_subsets) for i in g]


def subset_runs(n_views: int, n_subsets: int) -> list[slice]:
    """The consecutive runs of a :func:`subset_major` stack, as slices of its views."""
    sizes = [len(g) for g in make_subsets(n_views, n_subsets)]
    starts = np.cumsum([0] + sizes)
    return [slice(int(a), int(b)) for a, b in zip(starts[:-1], starts[1:], strict=True)]
