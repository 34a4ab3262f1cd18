"""A bar-group resolution chart: three-bar groups over a range of periods at nine field places.

The groups follow the USAF 1951 pattern (three dark bars of width p/2 separated by light gaps of
p/2, bar length 2.5 p, so each group fills a 2.5 p square), in both orientations, at the centre,
the four edge midpoints and the four corners of the field, so resolution can be read where the
field's aberrations differ. Bars are anti-aliased by exact area coverage along their width (the
bars are axis-aligned, so a pixel's coverage is a product of 1-D overlaps).

Two layouts of a location's box (:data:`LAYOUTS`): ``"rows"`` (scene ``"bars"``) packs the
pairs finest first in rows from the box's top-left corner; ``"field"`` (scene ``"bars-field"``)
packs them coarsest first (first-fit by decreasing height, so coarser groups fit a box of the
same size), centres the packed rows in the box and orients every location's box the same way
relative to the field centre: finer rows away from the axis, coarser rows towards it, the left
and right edge midpoints transposed from the top one and the lower half mirrored from the upper
half. A lens symmetric about its axis then reads the same at the four edge midpoints and at the
four corners, and the coarsest groups (where a blurred image's limit lies) sit nearer the axis
than the location's centre, which favours the blurrier image.

:func:`bar_groups` is the layout (what is where), :func:`bar_chart` renders it and
:func:`metasensor.metrics.bars.bar_resolution` reads it back from an image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["BarGroup", "bar_groups", "bar_chart", "LOCATIONS", "PERIODS", "LAYOUTS"]

#: Bar periods [px], finest first; a location holds those that fit its box.
PERIODS = (2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0, 16.0, 20.0, 24.0)
#: Location names and their centres as fractions of (height, width).
LOCATIONS = {
    "top-left": (0.19, 0.19), "top": (0.19, 0.5), "top-right": (0.19, 0.81),
    "left": (0.5, 0.19), "centre": (0.5, 0.5), "right": (0.5, 0.81),
    "bottom-left": (0.81, 0.19), "bottom": (0.81, 0.5), "bottom-right": (0.81, 0.81),
}
_BOX = 0.28  # side of a location's box, as a fraction of the field's smaller side
#: Layouts of a location's box (module docstring).
LAYOUTS = ("rows", "field")


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


def bar_groups(size: int = 512, shape=None, origin: float = 0.0, layout: str = "rows"
               ) -> list[BarGroup]:
    """The chart's layout: per location, pairs (vertical, horizontal bars) of every period of
    :data:`PERIODS` that fits the location's box.

    Parameters
    ----------
    size : int
        Field side [px] (or ``shape`` (H, W)); at least 64.
    origin : float
        Scene pixel that is pixel 0 of the image the layout is for [px, both axes]: a
        simulated capture's ``truth`` starts at scene pixel ``cap.offset``.
    layout : str
        ``"rows"`` (finest first in rows from the box's corner) or ``"field"`` (coarsest first,
        oriented about the field centre); module docstring.

    Returns
    -------
    list of BarGroup
        Per location, finest period first, the vertical group before the horizontal one.
    """
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    h, w = _check(size, shape)
    box = _BOX * min(h, w)
    if layout == "field":  # whole pixels, so that mirrored boxes land on whole pixels too
        box = float(math.floor(box))
    out = []
    for name, (fy, fx) in LOCATIONS.items():
        by, bx = float(round(fy * h - box / 2)), float(round(fx * w - box / 2))
        if layout == "field":  # the lower and right places mirror the upper and left ones
            by = h - round((1 - fy) * h - box / 2) - box if fy > 0.5 else by
            bx = w - round((1 - fx) * w - box / 2) - box if fx > 0.5 else bx
        place = _rows(box) if layout == "rows" else _field(box, fy, fx)
        out += [BarGroup(name, p, v, by + y - origin, bx + x - origin)
                for p, v, y, x in sorted(place, key=lambda t: (t[0], not t[1]))]
    return out


def _rows(box: float) -> list[tuple[float, bool, float, float]]:
    """(period, vertical, y, x) in the box: pairs finest first in rows from its top-left."""
    out = []
    y, x, row_h = 0.0, 0.0, 0.0
    for p in PERIODS:
        e, gap = 2.5 * p, max(p, 2.0)
        pair = 2 * e + gap
        if x > 0 and x + pair > box:  # next row
            y, x, row_h = y + math.ceil(row_h + gap), 0.0, 0.0
        if x + pair > box or y + e > box:
            break
        out.append((p, True, y, x))
        out.append((p, False, y, x + math.ceil(e + gap)))
        x += math.ceil(pair + gap)
        row_h = max(row_h, e)
    return out


def _shelves(periods, box: float) -> list[list[float]] | None:
    """First-fit decreasing-height packing of the pairs of ``periods`` (coarsest first) into
    rows of width ``box``: the rows' periods, or None when they do not fit the box's height.
    A pair is ``2.5 p + p + 2.5 p`` wide and ``2.5 p`` tall; neighbours are ``max(p, 2)``
    apart (the coarser neighbour's p between rows)."""
    rows: list[list[float]] = []
    widths: list[float] = []
    for p in sorted(periods, reverse=True):
        gap = max(p, 2.0)
        pair = math.ceil(5 * p + gap)
        for k, row in enumerate(rows):
            if widths[k] + math.ceil(gap) + pair <= box:
                row.append(p)
                widths[k] += math.ceil(gap) + pair
                break
        else:
            rows.append([p])
            widths.append(pair)
    if max(widths) > box or _height(rows) > box:
        return None
    return rows


def _height(rows: list[list[float]]) -> float:
    return sum(math.ceil(2.5 * r[0]) for r in rows) + sum(
        math.ceil(max(r[0], 2.0)) for r in rows[:-1])


def _field(box: float, fy: float, fx: float) -> list[tuple[float, bool, float, float]]:
    """(period, vertical, y, x) in the box of the location at field fractions (fy, fx): the
    coarsest periods that fit (all finer ones with them) packed by :func:`_shelves`, finer rows
    away from the field centre (module docstring)."""
    rows = None
    for n in range(len(PERIODS), 0, -1):
        rows = _shelves(PERIODS[:n], box)
        if rows is not None:
            break
    rows = rows[::-1]  # finest row first: it goes to the side away from the axis
    out = []
    y = (box - _height(rows)) / 2
    for row in rows:
        items = sorted(row)
        width = sum(math.ceil(5 * p + max(p, 2.0)) for p in items) + sum(
            math.ceil(max(p, 2.0)) for p in items[1:])
        x = math.floor((box - width) / 2)
        top = y
        for p in items:
            e, gap = 2.5 * p, max(p, 2.0)
            out.append((p, True, math.floor(top), x))
            out.append((p, False, math.floor(top), x + math.ceil(e + gap)))
            x += math.ceil(5 * p + gap) + math.ceil(gap)
        y += math.ceil(2.5 * row[0]) + math.ceil(max(row[0], 2.0))
    return [_orient(t, box, fy, fx) for t in out]


def _orient(item, box: float, fy: float, fx: float) -> tuple[float, bool, float, float]:
    """An item of the canonical box (finer rows at its top, i.e. away from the axis for a place
    above the centre) moved to the place at (fy, fx): transposed for the left and right edge
    midpoints, mirrored for places below or right of the centre."""
    p, v, y, x = item
    e = 2.5 * p
    if fy == 0.5 and fx != 0.5:  # left / right: rows become columns, bars turn by 90 degrees
        p, v, y, x = p, not v, x, y
        if fx > 0.5:
            x = box - x - e
    else:
        if fy > 0.5:
            y = box - y - e
        if fx > 0.5:
            x = box - x - e
    return p, v, y, x


def _overlap(lo: np.ndarray, hi: np.ndarray, n: int) -> np.ndarray:
    """Per pixel i in range(n): length of [i, i + 1) ∩ [lo, hi) for each interval (k, n)."""
    i = np.arange(n, dtype=np.float64)
    return np.clip(np.minimum(i + 1, hi[:, None]) - np.maximum(i, lo[:, None]), 0.0, 1.0)


def bar_chart(size: int = 512, shape=None, dark: float = 0.05, light: float = 0.95,
              layout: str = "rows") -> np.ndarray:
    """Render :func:`bar_groups` (float32, shape (H, W), dark bars on a light field).

    Parameters
    ----------
    size : int
        Field side [px] (or ``shape`` (H, W)); at least 64.
    dark, light : float
        Radiance of the bars and of the background, ``0 <= dark < light``.
    layout : str
        ``"rows"`` or ``"field"`` (:func:`bar_groups`).

    Returns
    -------
    numpy.ndarray
        float32 radiance in [dark, light].
    """
    if not (0 <= dark < light):
        raise ValueError(f"need 0 <= dark < light, got dark={dark!r}, light={light!r}")
    h, w = _check(size, shape)
    ink = np.zeros((h, w))
    for g in bar_groups(size, shape, layout=layout):
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
