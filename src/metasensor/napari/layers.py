"""napari layer data for metasensor arrays: view stacks, raw frames, images, the lenslet grid and
per-block wavefront maps, all placed on one frame of sensor-plane micrometres.

Each function returns a napari *layer data tuple* ``(data, kwargs, layer_type)`` and imports
nothing from napari, so the readers and widgets share it and it is testable without Qt.

Placement (docs/conventions.md): raw frames sit at sensor pixel (row, col) × pixel pitch.
Reconstruction pixel (i, j) is the sensor point ``origin + (i + o, j + o)`` with
``o = (nnum − d) // 2``, ``d = nnum // scan``, and view sample (Y, X) sits at reconstruction pixel
``(Y·d + d//2, X·d + d//2)``. ``origin`` is what ``realign`` stored (``[0, 0]`` when unknown).
So a view stack, its reconstruction and the raw frames it came from overlay in the viewer.
"""

from __future__ import annotations

import numpy as np

from metasensor.config import SystemConfig

__all__ = ["UM", "views_layer", "frames_layer", "image_layer", "grid_layer", "wavefront_layer",
           "wavefront_maps", "view_grid_shift"]

UM = 1e6  # metres -> micrometres (napari's scale unit here)


def _meta(kind: str, cfg: SystemConfig | None, source=None, **extra) -> dict:
    meta = {"kind": kind, "config": None if cfg is None else cfg.to_dict(), **extra}
    if source is not None:
        meta["source"] = str(source)
    return {"metasensor": meta}


def _origin(origin) -> np.ndarray:
    return np.zeros(2) if origin is None else np.asarray(origin, dtype=float).reshape(2)


def view_grid_shift(cfg: SystemConfig, origin=None) -> np.ndarray:
    """Sensor (row, col) [px] of view sample (0, 0): ``origin + o + d // 2``."""
    d = cfg.scan_step_px
    return _origin(origin) + (cfg.nnum - d) // 2 + d // 2


def _limits(data) -> list[float]:
    """Contrast limits from a strided sample (0.5-99.5 %), cheap for lazy arrays."""
    sub = data
    while sub.ndim > 2:
        sub = sub[sub.shape[0] // 2]
    step = max(1, int(max(sub.shape) // 512))
    arr = np.asarray(sub[::step, ::step], dtype=np.float64)
    arr = arr[np.isfinite(arr)]
    if arr.size == 0:
        return [0.0, 1.0]
    lo, hi = np.percentile(arr, [0.5, 99.5])
    return [float(lo), float(hi if hi > lo else lo + 1.0)]


def views_layer(views, cfg: SystemConfig, origin=None, name: str = "views", source=None,
                scale_um: float | None = None) -> tuple:
    """A view stack ``(nnum, nnum, H, W)`` as one 4-D image layer with axes (u, v, y, x).

    Parameters
    ----------
    views : array-like (nnum, nnum, H, W) (NumPy, memory map or zarr: read lazily by napari).
    cfg : SystemConfig of the capture (nnum, scan, pixel pitch).
    origin : sensor (row, col) [px] of the views' grid (``realign``'s stored ``origin``).
    scale_um : spacing of the view samples [µm]; default ``d · pixel_pitch`` (an OME file's
        physical size overrides it).

    Returns
    -------
    tuple : ``(views, kwargs, "image")``; (u, v) scale 1 (view index), (y, x) in µm.
    """
    if len(views.shape) != 4 or views.shape[0] != views.shape[1]:
        raise ValueError(f"views must have shape (nnum, nnum, H, W), got {tuple(views.shape)}")
    d = cfg.scan_step_px
    step = d * cfg.pixel_pitch * UM if scale_um is None else float(scale_um)
    shift = view_grid_shift(cfg, origin) * cfg.pixel_pitch * UM
    c = cfg.center
    kwargs = {"name": name, "scale": (1.0, 1.0, step, step),
              "translate": (0.0, 0.0, float(shift[0]), float(shift[1])),
              "axis_labels": ("u", "v", "y", "x"), "units": ("", "", "um", "um"),
              "contrast_limits": _limits(views[c, c]), "colormap": "gray",
              "metadata": _meta("views", cfg, source, origin=_origin(origin).tolist(),
                                scan_step_px=d)}
    return views, kwargs, "image"


def frames_layer(frames, cfg: SystemConfig | None, name: str = "frames", source=None) -> tuple:
    """Raw frames ``(T, H, W)`` (one page per scan phase) as an image layer (t, y, x) in µm."""
    if frames.ndim == 2:
        frames = frames[None]
    if frames.ndim != 3:
        raise ValueError(f"raw frames must have shape (T, H, W), got {tuple(frames.shape)}")
    p = (cfg or SystemConfig()).pixel_pitch * UM
    kwargs = {"name": name, "scale": (1.0, p, p), "axis_labels": ("t", "y", "x"),
              "units": ("", "um", "um"), "contrast_limits": _limits(frames), "colormap": "gray",
              "metadata": _meta("frames", cfg, source)}
    return frames, kwargs, "image"


def image_layer(image, cfg: SystemConfig | None, origin=None, name: str = "image",
                on_views: bool = False, kind: str = "image", source=None,
                colormap: str = "gray", **extra) -> tuple:
    """A 2-D map: on the reconstruction grid (pixel pitch) or, with ``on_views``, on the views'
    sample grid (``d`` pixels apart, e.g. depth's disparity); placed as the module says."""
    cfg0 = cfg or SystemConfig()
    p = cfg0.pixel_pitch * UM
    o = (cfg0.nnum - cfg0.scan_step_px) // 2
    if on_views:
        step, shift = cfg0.scan_step_px * p, view_grid_shift(cfg0, origin) * p
    else:
        step, shift = p, (_origin(origin) + o) * p
    kwargs = {"name": name, "scale": (step, step),
              "translate": (float(shift[0]), float(shift[1])), "axis_labels": ("y", "x"),
              "units": ("um", "um"), "contrast_limits": _limits(image), "colormap": colormap,
              "metadata": _meta(kind, cfg, source, origin=_origin(origin).tolist(), **extra)}
    return image, kwargs, "image"


def grid_layer(calib, pixel_pitch: float, name: str = "lenslet grid", source=None) -> tuple:
    """The lenslet grid of a :class:`~metasensor.sensor.calibration.Calibration` as a shapes
    layer of lines (the lenslet borders at phase (0, 0)) over the raw frame's pixels.

    The kept lenslets (i, j) have centres ``center + pitch · R(rotation) · (i, j)`` on the sensor;
    their borders are the lines at half-integer (i, j). One line per grid row and column (not one
    shape per lenslet), so a whole-sensor grid stays light.
    """
    m = np.asarray(calib.matrix) * calib.nnum  # lenslet index -> sensor px
    c = np.asarray(calib.center, dtype=float)
    ly, lx = calib.lenslets
    lines = []
    for i in np.arange(ly + 1) - 0.5:
        a, b = c + m @ (i, -0.5), c + m @ (i, lx - 0.5)
        lines.append(np.stack([a, b]))
    for j in np.arange(lx + 1) - 0.5:
        a, b = c + m @ (-0.5, j), c + m @ (ly - 0.5, j)
        lines.append(np.stack([a, b]))
    p = pixel_pitch * UM
    kwargs = {"name": name, "shape_type": "line", "edge_color": "yellow",
              "edge_width": 0.3 * p, "scale": (p, p), "axis_labels": ("y", "x"),
              "units": ("um", "um"),
              "metadata": {"metasensor": {"kind": "calibration", "pitch": calib.pitch,
                                          "rotation": calib.rotation,
                                          "center": list(calib.center),
                                          "lenslets": list(calib.lenslets),
                                          "contrast": calib.contrast,
                                          "source": None if source is None else str(source)}}}
    return lines, kwargs, "shapes"


def wavefront_maps(zernike, size: int = 33) -> np.ndarray:
    """Per-block wavefronts as maps: ``(by, bx, J)`` Noll vectors [waves] → ``(by, bx, size,
    size)`` wavefront over the unit pupil (``metasensor.optics.zernike.wavefront``), piston and
    tilts removed (they shift a block, they do not blur it), NaN outside the pupil."""
    from metasensor.optics.zernike import wavefront

    z = np.asarray(zernike, dtype=np.float64)
    if z.ndim == 1:
        z = z[None, None]
    if z.ndim != 3:
        raise ValueError(f"zernike must have shape (by, bx, J), got {z.shape}")
    t = (np.arange(size) - (size - 1) / 2) / ((size - 1) / 2)
    y, x = np.meshgrid(t, t, indexing="ij")
    inside = x * x + y * y <= 1.0
    out = np.full(z.shape[:2] + (size, size), np.nan, dtype=np.float32)
    for iy in range(z.shape[0]):
        for ix in range(z.shape[1]):
            zz = z[iy, ix].copy()
            zz[:3] = 0.0
            if zz.any():
                out[iy, ix][inside] = wavefront(zz, x[inside], y[inside])
            else:
                out[iy, ix][inside] = 0.0
    return out


def wavefront_layer(zernike, cfg: SystemConfig | None, image_shape, origin=None,
                    name: str = "wavefront (waves)", size: int = 33, source=None) -> tuple:
    """The per-block wavefront maps as one image layer: a grid of small pupil maps, one per
    block, in the block's row and column, drawn beside the image (to its right, 4 % apart), so
    each map sits level with the block it was estimated on. Colour: waves, symmetric limits."""
    maps = wavefront_maps(zernike, size)
    by, bx = maps.shape[:2]
    gap = 2
    tile = np.full((by * (size + gap), bx * (size + gap)), np.nan, np.float32)
    for iy in range(by):
        for ix in range(bx):
            y0, x0 = iy * (size + gap), ix * (size + gap)
            tile[y0:y0 + size, x0:x0 + size] = maps[iy, ix]
    cfg0 = cfg or SystemConfig()
    p = cfg0.pixel_pitch * UM
    o = (cfg0.nnum - cfg0.scan_step_px) // 2
    h, w = image_shape
    sy, sx = h * p / tile.shape[0], w * p / tile.shape[1]
    top = (_origin(origin) + o) * p
    peak = float(np.nanmax(np.abs(tile))) if np.isfinite(tile).any() else 0.0
    peak = peak if peak > 0 else 1.0
    kwargs = {"name": name, "scale": (sy, sx),
              "translate": (float(top[0]), float(top[1] + 1.04 * w * p)),
              "axis_labels": ("y", "x"), "units": ("um", "um"), "colormap": "bwr",
              "contrast_limits": [-peak, peak],
              "metadata": _meta("wavefront", cfg, source, blocks=[by, bx], map_size=size,
                                zernike=np.asarray(zernike).tolist())}
    return tile, kwargs, "image"
