"""Built-in scenes (no downloads): a procedural ISO 12233-style resolution chart, a checkerboard,
points, a uniform field, a bar-group chart over the field (``"bars"``, and ``"bars-field"`` with
the groups oriented about the field centre: :mod:`metasensor.simulation.bars`) and the natural
images that ship with scikit-image.

All scenes are float32 radiance in [0, 1], shape (size, size) (or ``shape``). Edges are
anti-aliased analytically: a pixel's value is the clipped signed distance of its centre to the
edge, ``clip(0.5 − sd, 0, 1)`` (exact area coverage for straight edges at 0°/90°, within a few
per cent at other angles).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["resolution_chart", "checkerboard", "point_grid", "natural_image", "load_scene",
           "SCENES", "NATURAL"]

NATURAL = ("camera", "astronaut", "coins", "moon", "brick", "grass", "gravel", "text",
           "page", "coffee", "chelsea", "rocket", "cat", "horse", "clock", "immunohistochemistry")
SCENES = ("chart", "checkerboard", "points", "point", "uniform", "bars", "bars-field") + NATURAL


def _cover(sd: np.ndarray) -> np.ndarray:
    return np.clip(0.5 - sd, 0.0, 1.0)


def _size(size, shape):
    if shape is not None:
        h, w = (int(s) for s in shape)
    else:
        h = w = int(size)
    if h < 8 or w < 8:
        raise ValueError(f"scene size must be at least 8 x 8, got {h} x {w}")
    return h, w


def resolution_chart(size: int = 1024, shape=None, angle: float = 5.0, dark: float = 0.05,
                     light: float = 0.95) -> np.ndarray:
    """ISO 12233-style chart: slanted-edge squares (rotated by ``angle`` degrees) on a 4 × 4 grid
    across the field, bar groups (horizontal and vertical, periods 2–16 px) along the
    middle rows/columns, and a 36-spoke Siemens star in the centre."""
    h, w = _size(size, shape)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    ink = np.zeros((h, w))
    s = min(h, w)
    # slanted-edge squares in the 4 x 4 grid of cells (skipping the centre 2 x 2: the star)
    half = 0.09 * s
    a = math.radians(angle)
    for i in range(4):
        for j in range(4):
            if i in (1, 2) and j in (1, 2):
                continue
            cy, cx = (i + 0.5) * h / 4, (j + 0.5) * w / 4
            dy, dx = yy - cy, xx - cx
            ry = math.cos(a) * dy - math.sin(a) * dx
            rx = math.sin(a) * dy + math.cos(a) * dx
            ink = np.maximum(ink, _cover(np.maximum(np.abs(ry), np.abs(rx)) - half))
    # Siemens star: 36 spokes (18 dark)
    cy, cx = (h - 1) / 2, (w - 1) / 2
    r = np.hypot(yy - cy, xx - cx)
    theta = np.arctan2(yy - cy, xx - cx)
    spokes = 36
    phase = np.mod(theta * spokes / (2 * math.pi), 2.0)  # dark where phase in [0, 1)
    ang_dist = np.abs(np.mod(phase + 0.5, 2.0) - 1.0) - 0.5  # < 0 inside a dark spoke
    sd_spoke = ang_dist * (2 * math.pi / spokes) * np.maximum(r, 1e-9)
    star = _cover(np.maximum(sd_spoke, r - 0.2 * s)) * (r > 2)
    ink = np.maximum(ink, star)
    # bar groups: periods 2..16 px, 5 bars each, between the squares
    periods = [p for p in (2, 3, 4, 6, 8, 12, 16) if 5 * p < 0.12 * s] or [2]
    band = 0.05 * s
    x0 = 0.02 * w
    for p in periods:
        length = 5 * p
        if x0 + length > 0.98 * w:
            break
        # vertical bars in a horizontal band at y = h/2 - band... ; horizontal bars at x = w/2
        inside_x = (xx >= x0) & (xx < x0 + length - p / 2)
        bars_v = (np.mod(xx - x0, p) < p / 2) & inside_x & (np.abs(yy - h * 0.5) < band / 2)
        bars_v &= np.abs(xx - w / 2) > 0.22 * s
        ink = np.maximum(ink, bars_v.astype(float))
        inside_y = (yy >= x0 * h / w) & (yy < x0 * h / w + length - p / 2)
        bars_h = (np.mod(yy - x0 * h / w, p) < p / 2) & inside_y & (np.abs(xx - w * 0.5) < band / 2)
        bars_h &= np.abs(yy - h / 2) > 0.22 * s
        ink = np.maximum(ink, bars_h.astype(float))
        x0 += length + 2 * p
    return (light - (light - dark) * ink).astype(np.float32)


def checkerboard(size: int = 256, square: int = 16, shape=None, dark: float = 0.1,
                 light: float = 0.9) -> np.ndarray:
    """Checkerboard of ``square``-pixel squares (calibration target)."""
    h, w = _size(size, shape)
    if square < 1:
        raise ValueError(f"square must be >= 1 pixel, got {square}")
    yy, xx = np.mgrid[0:h, 0:w]
    board = ((yy // square + xx // square) % 2).astype(np.float32)
    return (dark + (light - dark) * board).astype(np.float32)


def point_grid(size: int = 256, spacing: int = 32, shape=None, value: float = 1.0) -> np.ndarray:
    """Single-pixel points every ``spacing`` pixels (first at spacing // 2) on a black field."""
    h, w = _size(size, shape)
    out = np.zeros((h, w), np.float32)
    out[spacing // 2::spacing, spacing // 2::spacing] = value
    return out


def natural_image(name: str = "camera", size: int = 512, shape=None) -> np.ndarray:
    """A scikit-image sample image (grey, centre-cropped to the aspect ratio, resized)."""
    import skimage.data
    from skimage.color import rgb2gray

    if name not in NATURAL:
        raise ValueError(f"unknown natural image {name!r}; choose from {', '.join(NATURAL)}")
    img = np.asarray(getattr(skimage.data, name)())
    if img.ndim == 3:
        img = rgb2gray(img[..., :3])
    img = img.astype(np.float64)
    img = (img - img.min()) / max(np.ptp(img), 1e-12)
    return _fit(img, _size(size, shape))


def _fit(img: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    from skimage.transform import resize

    h, w = shape
    ih, iw = img.shape
    if ih * w > iw * h:  # too tall: crop rows
        nh = max(1, round(iw * h / w))
        img = img[(ih - nh) // 2:(ih - nh) // 2 + nh]
    else:
        nw = max(1, round(ih * w / h))
        img = img[:, (iw - nw) // 2:(iw - nw) // 2 + nw]
    out = resize(img, (h, w), order=3, anti_aliasing=True, mode="reflect")
    return np.clip(out, 0, None).astype(np.float32)


def load_scene(name: str, size: int = 512, shape=None) -> np.ndarray:
    """A built-in scene by name (:data:`SCENES`) or an image file (TIFF/PNG/JPEG, made grey and
    resized, scaled to [0, 1])."""
    if name == "chart":
        return resolution_chart(size, shape)
    if name == "checkerboard":
        return checkerboard(size, max(2, int(size if shape is None else min(shape)) // 16),
                            shape)
    if name == "points":
        return point_grid(size, max(16, int(size if shape is None else min(shape)) // 8), shape)
    if name == "point":
        h, w = _size(size, shape)
        out = np.zeros((h, w), np.float32)
        out[h // 2, w // 2] = 1.0
        return out
    if name == "uniform":
        return np.full(_size(size, shape), 0.5, np.float32)
    if name in ("bars", "bars-field"):
        from metasensor.simulation.bars import bar_chart

        return bar_chart(size, shape, layout="rows" if name == "bars" else "field")
    if name in NATURAL:
        return natural_image(name, size, shape)
    path = Path(name)
    if path.suffix:
        if not path.is_file():
            raise FileNotFoundError(f"scene file not found: {path}")
        img = _read_image(path)
        return _fit(img, _size(size, shape))
    raise ValueError(f"unknown scene {name!r}; choose from {', '.join(SCENES)} or a file path")


def _read_image(path: Path) -> np.ndarray:
    """A scene image file as grey [0, 1]. A TIFF is read checked (truncated or corrupt: one
    ``ValueError`` line, :func:`metasensor.io.tiff.read_tiff`); any other file that no reader
    decodes is ``ValueError("<path>: not a readable image (...)")``, one line."""
    if path.suffix.lower() in (".tif", ".tiff"):
        from metasensor.io.tiff import read_tiff

        img = read_tiff(path)
    else:
        import skimage.io

        from metasensor.io.tiff import first_line

        try:
            img = skimage.io.imread(path)
        except Exception as exc:  # noqa: BLE001 - PIL/imageio raise many types for bad files
            detail = first_line(exc)
            if "Could not find a backend" in detail:  # imageio: no plugin decodes the bytes
                detail = f"{type(exc).__name__}: no image reader recognises its contents"
            raise ValueError(f"{path}: not a readable image ({detail})") from None
    img = np.asarray(img, dtype=np.float64)
    if img.ndim == 3 and img.shape[-1] in (3, 4):
        from skimage.color import rgb2gray

        img = rgb2gray(img[..., :3] / max(img.max(), 1e-12))
    if img.ndim != 2:
        raise ValueError(f"{path}: expected a 2D (or RGB) image, got shape {img.shape}")
    if not np.isfinite(img).all():
        raise ValueError(f"{path}: image contains NaN or infinite values")
    return (img - img.min()) / max(np.ptp(img), 1e-12)
