"""A bar-group resolution chart: three-bar groups over a range of periods at nine field places.

The groups follow the USAF 1951 pattern (three dark bars of width p/2 separated by light gaps of
p/2, bar length 2.5 p, so each group fills a 2.5 p square), in both orientations, at the centre,
the four edge midpoints and the four corners of the field, so resolution can be read where the
field's aberrations differ. Bars are anti-aliased by exact area coverage along their width (the
bars are axis-aligned, so a pixel's coverage is a product of 1-D overlaps).

:func:`bar_groups` is the layout (what is where), :func:`bar_chart` renders it and
:func:`metasensor.metrics.bars.bar_resolution` reads it back from an image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["BarGroup", "bar_groups", "bar_chart", "LOCATIONS", "PERIODS"]

#: Bar periods [px], finest first; a location holds those that fit its box.
PERIODS = (2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0, 16.0, 20.0, 24.0)
#: Location names and their centres as fractions of (height, width).
LOCATIONS = {
    "top-left": (0.19, 0.19), "top": (0.19, 0.5), "top-right": (0.19, 0.81),
    "left": (0.5, 0.19), "centre": (0.5, 0.5), "right": (0.5, 0.81),
    "bottom-left": (0.81, 0.19), "bottom": (0.81, 0.5), "bottom-right": (0.81, 0.81),
}
_BOX = 0.28  # side of a location's box, as a fraction of the field's smaller side


@dataclass(frozen=True)
class BarGroup:
    """One three-bar group.

    Attributes
    ----------
    location : str
        A key of :data:`LOCATIONS`.
    period : float
        Bar period [px] (bar width = gap = period / 2).
    vertical : bool
        True: vertical bars (they resolve horizontal frequency, the profile runs along x).
    y0, x0 : float
        Top-left corner of the group's 2.5 p × 2.5 p square [px, continuous coordinates: pixel
        i covers [i, i + 1)].
    """

    location: str
    period: float
    vertical: bool
    y0: float
    x0: float

    @property
    def extent(self) -> float:
        """Side of the group's square [px]."""
        return 2.5 * self.period


def _check(size, shape) -> tuple[int, int]:
    if shape is not None:
        h, w = (int(s) for s in shape)
    else:
        h = w = int(size)
    if h < 64 or w < 64:
        raise ValueError(f"bar chart needs a field of at least 64 x 64 px, got {h} x {w}")
    return h, w


def bar_groups(size: int = 512, shape=None, origin: float = 0.0) -> list[BarGroup]:
    """The chart's layout: per location, pairs (vertical, horizontal bars) of every period of
    :data:`PERIODS` that fits the location's box, packed in rows, finest first.

    Parameters
    ----------
    size : int
        Field side [px] (or ``shape`` (H, W)); at least 64.
    origin : float
        Scene pixel that is pixel 0 of the image the layout is for [px, both axes]: a
        simulated capture's ``truth`` starts at scene pixel ``cap.offset``.

    Returns
    -------
    list of BarGroup
    """
    h, w = _check(size, shape)
    box = _BOX * min(h, w)
    out = []
    for name, (fy, fx) in LOCATIONS.items():
        by, bx = float(round(fy * h - box / 2)), float(round(fx * w - box / 2))
        y, x, row_h = 0.0, 0.0, 0.0
        for p in PERIODS:
            e, gap = 2.5 * p, max(p, 2.0)
            pair = 2 * e + gap
            if x > 0 and x + pair > box:  # next row
                y, x, row_h = y + math.ceil(row_h + gap), 0.0, 0.0
            if x + pair > box or y + e > box:
                break
            y0, x0 = by + y - origin, bx + x - origin
            out.append(BarGroup(name, p, True, y0, x0))
            out.append(BarGroup(name, p, False, y0, x0 + math.ceil(e + gap)))
            x += math.ceil(pair + gap)
            row_h = max(row_h, e)
    return out


def _overlap(lo: np.ndarray, hi: np.ndarray, n: int) -> np.ndarray:
    """Per pixel i in range(n): length of [i, i + 1) ∩ [lo, hi) for each interval (k, n)."""
    i = np.arange(n, dtype=np.float64)
    return np.clip(np.minimum(i + 1, hi[:, None]) - np.maximum(i, lo[:, None]), 0.0, 1.0)


def bar_chart(size: int = 512, shape=None, dark: float = 0.05, light: float = 0.95) -> np.ndarray:
    """Render :func:`bar_groups` (float32, shape (H, W), dark bars on a light field).

    Parameters
    ----------
    size : int
        Field side [px] (or ``shape`` (H, W)); at least 64.
    dark, light : float
        Radiance of the bars and of the background, ``0 <= dark < light``.

    Returns
    -------
    numpy.ndarray
        float32 radiance in [dark, light].
    """
    if not (0 <= dark < light):
        raise ValueError(f"need 0 <= dark < light, got dark={dark!r}, light={light!r}")
    h, w = _check(size, shape)
    ink = np.zeros((h, w))
    for g in bar_groups(size, shape):
        e, p = g.extent, g.period
        starts = np.array([0.0, p, 2 * p])
        along_lo, along_hi = np.array([0.0]), np.array([e])
        if g.vertical:  # bars split x, run along y
            cx = _overlap(g.x0 + starts, g.x0 + starts + p / 2, w).sum(0)
            cy = _overlap(g.y0 + along_lo, g.y0 + along_hi, h)[0]
        else:
            cy = _overlap(g.y0 + starts, g.y0 + starts + p / 2, h).sum(0)
            cx = _overlap(g.x0 + along_lo, g.x0 + along_hi, w)[0]
        ink = np.maximum(ink, np.outer(cy, cx))
    return (light - (light - dark) * ink).astype(np.float32)
