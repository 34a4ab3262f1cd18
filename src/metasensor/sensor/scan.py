"""Scan orders: the sequence of (row, col) scan phases in acquisition order (interface.md)."""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["scan_order", "check_scan_order", "period_of"]


def scan_order(period: int, kind: str = "row-major") -> list[tuple[int, int]]:
    """Preset scan orders: ``"row-major"`` (default) or ``"serpentine"`` (boustrophedon rows)."""
    if not isinstance(period, int) or period < 1:
        raise ValueError(f"scan period must be a positive integer, got {period!r}")
    if kind in ("row-major", "rowmajor", "raster"):
        return [(r, c) for r in range(period) for c in range(period)]
    if kind in ("serpentine", "snake", "boustrophedon"):
        return [(r, c if r % 2 == 0 else period - 1 - c) for r in range(period)
                for c in range(period)]
    raise ValueError(f"unknown scan order {kind!r}; use 'row-major' or 'serpentine'")


def period_of(order: Sequence[Sequence[int]]) -> int:
    """Scan period implied by an order: int(sqrt(len(order)))."""
    if not hasattr(order, "__len__") or isinstance(order, str | bytes):
        raise TypeError(f"scan_order must be a list of (row, col) pairs, got {order!r:.60}")
    p = math.isqrt(len(order))
    if p * p != len(order) or p == 0:
        raise ValueError(f"scan order has {len(order)} phases, not a square number")
    return p


def check_scan_order(order: Sequence[Sequence[int]] | str | None, period: int
                     ) -> list[tuple[int, int]]:
    """Normalise ``order`` (None, a preset name or a list) and check it covers every phase once."""
    if order is None:
        return scan_order(period)
    if isinstance(order, str):
        return scan_order(period, order)
    try:
        phases = [(int(r), int(c)) for r, c in order]
    except (TypeError, ValueError):
        raise ValueError("scan_order must be a list of (row, col) pairs") from None
    if len(phases) != period * period:
        raise ValueError(
            f"scan_order has {len(phases)} phases but the scan period {period} needs {period**2}"
        )
    expected = {(r, c) for r in range(period) for c in range(period)}
    if set(phases) != expected:
        bad = sorted(set(phases) - expected) or sorted(expected - set(phases))
        raise ValueError(
            f"scan_order must contain every phase (row, col) in 0..{period - 1} exactly once; "
            f"problem at {bad[0]}"
        )
    return phases
