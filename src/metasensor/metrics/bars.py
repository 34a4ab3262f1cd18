"""Bar-group resolution: the finest three-bar group an image still shows, per field location.

A group counts as resolved when its profile across the bars (averaged over the middle 60 % of
the bars' length, sampled at 8 points per period by linear interpolation) has exactly three
minima of prominence at least ``min_contrast`` × the profile's mean, and the Michelson contrast
between its two gaps and its three bars, read at their known centres,
``(min(gaps) − max(bars)) / (min(gaps) + max(bars))``, is at least ``min_contrast`` (0.1 by
default: a group whose bars have merged, lost one, or reversed in phase (spurious resolution)
fails). A location's resolved period is the finest period at which that group and every coarser
one pass in both orientations (so an aliased fine group that happens to pass does not count).

The layout comes from :func:`metasensor.simulation.bars.bar_groups`; the image must be registered
to the chart (same pixel grid), as a reconstruction of a simulated capture is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GroupReading", "bar_contrast", "bar_resolution"]


@dataclass(frozen=True)
class GroupReading:
    """One group's reading: period [px], orientation, Michelson contrast, minima count, pass."""

    location: str
    period: float
    vertical: bool
    contrast: float
    minima: int
    resolved: bool


def _profile(image: np.ndarray, group) -> tuple[np.ndarray, np.ndarray]:
    """Profile across ``group``'s bars: positions [px from the group's start] and values."""
    from scipy.ndimage import map_coordinates

    p, e = group.period, group.extent
    pos = np.arange(-0.25 * p, e + 0.25 * p + 1e-9, p / 8)
    along = np.linspace(0.2 * e, 0.8 * e, max(int(0.6 * e) + 1, 3))
    a, b = np.meshgrid(pos, along, indexing="ij")
    if group.vertical:  # across = x
        ys, xs = group.y0 + b - 0.5, group.x0 + a - 0.5
    else:
        ys, xs = group.y0 + a - 0.5, group.x0 + b - 0.5
    vals = map_coordinates(image, [ys.ravel(), xs.ravel()], order=1, mode="nearest")
    return pos, vals.reshape(a.shape).mean(axis=1)


def bar_contrast(image, group, min_contrast: float = 0.1) -> GroupReading:
    """Read one :class:`~metasensor.simulation.bars.BarGroup` from ``image`` (see module).

    Parameters
    ----------
    image : array_like
        2-D image on the chart's pixel grid (any linear radiance units).
    group : BarGroup
        The group's place, period and orientation.
    min_contrast : float
        Michelson contrast a resolved group must reach, and the minima's prominence relative to
        the profile's mean.

    Returns
    -------
    GroupReading
    """
    from scipy.signal import find_peaks

    img = np.asarray(image, np.float64)
    pos, prof = _profile(img, group)
    p = group.period
    bars = np.interp([0.25 * p, 1.25 * p, 2.25 * p], pos, prof)
    gaps = np.interp([0.75 * p, 1.75 * p], pos, prof)
    hi, lo = float(gaps.min()), float(bars.max())
    contrast = (hi - lo) / (hi + lo) if hi + lo > 0 else 0.0
    peaks, _ = find_peaks(-prof, prominence=min_contrast * max(float(prof.mean()), 1e-12))
    return GroupReading(group.location, group.period, group.vertical, float(contrast),
                        int(peaks.size), bool(contrast >= min_contrast and peaks.size == 3))


def bar_resolution(image, groups, min_contrast: float = 0.1) -> dict[str, dict]:
    """The finest resolved period at every location of ``groups`` (see module).

    Parameters
    ----------
    image : array_like
        2-D image on the chart's pixel grid.
    groups : list of BarGroup
        The layout, from :func:`metasensor.simulation.bars.bar_groups` of the image's size.
    min_contrast : float
        See :func:`bar_contrast`.

    Returns
    -------
    dict
        ``{location: {"period_px": p or None, "frequency": 1/p [cycles/px] or 0.0,
        "coarsest_px": the location's coarsest period, "readings": [GroupReading, ...]}}``;
        ``period_px`` is None when even the coarsest group fails.
    """
    img = np.asarray(image)
    if img.ndim != 2 or not np.issubdtype(img.dtype, np.number):
        raise ValueError(f"image must be a 2-D numeric array, got shape {img.shape}, "
                         f"dtype {img.dtype}")
    if not np.isfinite(img).all():
        raise ValueError("image contains NaN or infinite values")
    out: dict[str, dict] = {}
    for g in groups:
        out.setdefault(g.location, {"readings": []})["readings"].append(
            bar_contrast(img, g, min_contrast))
    for loc in out.values():
        ok: dict[float, bool] = {}
        for r in loc["readings"]:
            ok[r.period] = ok.get(r.period, True) and r.resolved
        finest = None
        for period in sorted(ok, reverse=True):  # coarse to fine: stop at the first failure
            if not ok[period]:
                break
            finest = period
        loc.update(period_px=finest, frequency=0.0 if finest is None else 1.0 / finest,
                   coarsest_px=max(ok))
    return out
