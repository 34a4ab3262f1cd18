"""Scan orders: the sequence of (row, col) scan phases in acquisition order (docs/conventions.md).

Orders are zero-based everywhere in the API; :func:`from_one_based` converts the one-based
row/column lists of MATLAB tools, :func:`read_order_png` reads the authors' scan-pattern images.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["scan_order", "check_scan_order", "period_of", "from_one_based", "read_order_png",
           "write_order_png", "PRESETS"]

PRESETS = ("row-major", "serpentine", "spiral")


def _spiral(period: int) -> list[tuple[int, int]]:
    """Inward spiral from the bottom-left phase: up the first column, right along the top row,
    down the last column, left along the bottom, and so on to the centre (the 3 × 3 order of
    scanning light-field microscopes: one-based rows 3,2,1,1,1,2,3,3,2, columns
    1,1,1,2,3,3,3,2,2)."""
    top, bottom, left, right = 0, period - 1, 0, period - 1
    out: list[tuple[int, int]] = []
    while top <= bottom and left <= right:
        out += [(r, left) for r in range(bottom, top - 1, -1)]
        out += [(top, c) for c in range(left + 1, right + 1)]
        if right > left:
            out += [(r, right) for r in range(top + 1, bottom + 1)]
        if bottom > top:
            out += [(bottom, c) for c in range(right - 1, left, -1)]
        top, bottom, left, right = top + 1, bottom - 1, left + 1, right - 1
    return out


def scan_order(period: int, kind: str = "row-major") -> list[tuple[int, int]]:
    """Preset scan orders (zero-based): ``"row-major"`` (default), ``"serpentine"``
    (boustrophedon rows) or ``"spiral"`` (inward from the bottom-left phase, going up)."""
    if not isinstance(period, int) or period < 1:
        raise ValueError(f"scan period must be a positive integer, got {period!r}")
    if kind in ("row-major", "rowmajor", "raster"):
        return [(r, c) for r in range(period) for c in range(period)]
    if kind in ("serpentine", "snake", "boustrophedon"):
        return [(r, c if r % 2 == 0 else period - 1 - c) for r in range(period)
                for c in range(period)]
    if kind == "spiral":
        return _spiral(period)
    raise ValueError(f"unknown scan order {kind!r}; use one of {', '.join(PRESETS)}")


def from_one_based(rows: Sequence[int], cols: Sequence[int]) -> list[tuple[int, int]]:
    """Zero-based order from one-based row and column lists (MATLAB style): phase k is
    ``(rows[k] - 1, cols[k] - 1)``."""
    if len(rows) != len(cols):
        raise ValueError(f"one-based scan order: {len(rows)} rows but {len(cols)} columns")
    if any(int(v) < 1 for v in list(rows) + list(cols)):
        raise ValueError("one-based scan order holds a value below 1")
    order = [(int(r) - 1, int(c) - 1) for r, c in zip(rows, cols, strict=True)]
    return check_scan_order(order, period_of(order))


def read_order_png(path) -> list[tuple[int, int]]:
    """Scan order from a scan-pattern image (the authors' ``5x5.conf.sk.png`` format): an
    N × N grey PNG (16-bit or 8-bit) whose pixel (r, c) holds the acquisition index (0 .. N²−1)
    of scan phase (r, c); frame 0 is at the bottom-left in the authors' files and at the
    top-right in their ``rot180`` variants, both read by this same rule. Returns the zero-based
    order: ``order[k]`` = the pixel holding k."""
    import numpy as np
    from PIL import Image

    try:
        with Image.open(path) as im:
            img = np.asarray(im)
    except (OSError, ValueError) as exc:
        raise ValueError(f"scan-pattern file {path}: not a readable PNG ({exc})") from None
    if img.ndim != 2 or img.shape[0] != img.shape[1]:
        raise ValueError(f"scan-pattern file {path}: an N x N grey image expected, got shape "
                         f"{img.shape}")
    n = img.shape[0]
    flat = img.astype(np.int64).ravel()
    if sorted(flat.tolist()) != list(range(n * n)):
        raise ValueError(f"scan-pattern file {path}: the pixels must hold each acquisition index "
                         f"0..{n * n - 1} once")
    pos = np.argsort(flat)
    return [(int(k // n), int(k % n)) for k in pos]


def write_order_png(path, order: Sequence[Sequence[int]]):
    """Write ``order`` (zero-based) as a 16-bit scan-pattern PNG (see :func:`read_order_png`),
    atomically; returns the path."""
    import numpy as np
    from PIL import Image

    from metasensor.io.atomic import atomic_path

    p = period_of(order)
    phases = check_scan_order(order, p)
    img = np.zeros((p, p), np.uint16)
    for k, (r, c) in enumerate(phases):
        img[r, c] = k
    with atomic_path(path) as tmp:
        Image.fromarray(img).save(tmp, format="PNG")
    return path


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
