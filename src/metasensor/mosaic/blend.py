"""Blend registered tiles into one OME-Zarr image with a multiscale pyramid, block-parallel.

Every output chunk is computed on its own (``dask.array.map_blocks``): the tiles that cover it
are read from their Zarr arrays (only the window the chunk needs plus ``MARGIN`` pixels),
resampled onto the mosaic grid at their sub-pixel positions (cubic splines,
``scipy.ndimage.shift``; the margin makes the spline prefilter of a window equal that of the
whole tile to ~1e-7), weighted by a feathering ramp that rises linearly over ``ramp`` pixels
from every tile border (``1 / (ramp + 1)`` on the outermost sample, zero outside the tile), and
normalised by the sum of the weights: identical tiles blend to themselves exactly, every mosaic
pixel inside a tile's samples is covered (the mosaic's own outermost pixels included), and
pixels that no tile reaches are 0 (:meth:`~metasensor.mosaic.layout.MosaicLayout.covered` gives
the rectangle that every registered layout covers). Memory is bounded by a few chunks per
worker, whatever the mosaic's size.

The pyramid halves the resolution per level by 2 × 2 means (``dask.array.coarsen``), each level
read back from the one written before. The store is OME-NGFF 0.4 (Zarr v2 format, axes y, x in
micrometres, one ``scale`` transformation per level; Moore et al., Nat. Methods 18, 1496 (2021))
and is written under a temporary name and put in place when complete; an existing folder is
replaced only if it is an earlier mosaic of this function.

``scheduler``: None or "threads" (dask's local threads), "sync", an address
"tcp://host:port" (a ``dask.distributed.Client`` is connected) or a Client / cluster object.
"""

from __future__ import annotations

import math
import uuid
from pathlib import Path

import numpy as np

from metasensor.io.atomic import discard_tree, replace_tree

__all__ = ["blend_tiles", "feather", "MARGIN", "open_mosaic"]

MARGIN = 16


def _ramp(t: np.ndarray, n: int, ramp: int) -> np.ndarray:
    """Feathering weight at (fractional) tile coordinates ``t`` of a side of ``n`` pixels: 0
    outside the samples ``[0, n - 1]``, ``(k + 1) / (ramp + 1)`` at distance ``k`` inside,
    at most 1."""
    k = np.minimum(t, n - 1 - t)
    return np.where(k >= -1e-6, np.clip((k + 1.0) / (max(ramp, 1) + 1.0), 0.0, 1.0), 0.0)


def feather(shape: tuple[int, int], ramp: int) -> np.ndarray:
    """(h, w) float64 weights: a separable linear ramp over ``ramp`` pixels from each border
    (pixel k from the border weighs ``min((k + 1) / (ramp + 1), 1)``, so the outermost pixel
    has a small weight and a tile alone covers its whole extent)."""
    h, w = shape
    return np.outer(_ramp(np.arange(h, dtype=float), h, ramp),
                    _ramp(np.arange(w, dtype=float), w, ramp))


def _chunk(block_info=None, *, tiles, positions, ramp, out_dtype):
    """One output chunk: weighted mean of the resampled tiles that cover it."""
    import zarr  # in a worker thread: the loop is started by blend_tiles
    from scipy import ndimage

    (y0, y1), (x0, x1) = block_info[None]["array-location"]
    acc = np.zeros((y1 - y0, x1 - x0))
    wsum = np.zeros_like(acc)
    for (path, comp), (py, px) in zip(tiles, positions, strict=True):
        arr = zarr.open_array(path, mode="r", path=comp) if comp else zarr.open_array(path,
                                                                                       mode="r")
        th, tw = arr.shape
        iy, ix = math.floor(py), math.floor(px)
        fy, fx = py - iy, px - ix
        # chunk in tile coordinates, plus the margin the spline needs
        ty0, ty1 = y0 - iy - MARGIN, y1 - iy + MARGIN
        tx0, tx1 = x0 - ix - MARGIN, x1 - ix + MARGIN
        if ty1 <= 0 or tx1 <= 0 or ty0 >= th or tx0 >= tw:
            continue
        cy0, cy1, cx0, cx1 = max(ty0, 0), min(ty1, th), max(tx0, 0), min(tx1, tw)
        win = np.asarray(arr[cy0:cy1, cx0:cx1], dtype=np.float64)
        if fy or fx:  # window row r now holds the tile at coordinate cy0 + r − fy
            win = ndimage.shift(win, (fy, fx), order=3, mode="nearest")
        wts = np.outer(_ramp(np.arange(cy0, cy1) - fy, th, ramp),
                       _ramp(np.arange(cx0, cx1) - fx, tw, ramp))
        # mosaic pixel Y sits at window row Y − iy − cy0
        oy, ox = iy + cy0, ix + cx0
        sy0, sy1 = max(y0, oy), min(y1, oy + win.shape[0])
        sx0, sx1 = max(x0, ox), min(x1, ox + win.shape[1])
        if sy1 <= sy0 or sx1 <= sx0:
            continue
        w = np.clip(wts[sy0 - oy:sy1 - oy, sx0 - ox:sx1 - ox], 0.0, None)
        acc[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] += w * win[sy0 - oy:sy1 - oy, sx0 - ox:sx1 - ox]
        wsum[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] += w
    out = np.divide(acc, wsum, out=np.zeros_like(acc), where=wsum > 0)
    return out.astype(out_dtype)


def _own_mosaic(path: Path) -> bool:
    """An earlier mosaic of :func:`blend_tiles` (a Zarr group tagged ``metasensor``)."""
    import json

    try:
        attrs = json.loads((path / ".zattrs").read_text())
    except (OSError, ValueError):
        return False
    return (path / ".zgroup").is_file() and isinstance(attrs, dict) and \
        attrs.get("metasensor", {}).get("kind") == "mosaic"


def _compute(store_fn, scheduler):
    if scheduler is None or scheduler in ("threads", "sync"):
        return store_fn(scheduler or "threads")
    from distributed import Client

    if isinstance(scheduler, Client):
        return store_fn(scheduler)
    if isinstance(scheduler, str) and "://" not in scheduler:
        raise ValueError(f"scheduler must be 'threads', 'sync' or an address like "
                         f"'tcp://host:8786', got {scheduler!r}")
    client = Client(scheduler if hasattr(scheduler, "scheduler_address") else str(scheduler))
    try:
        return store_fn(client)
    finally:
        client.close()


def blend_tiles(tiles: dict, positions: dict, shape: tuple[int, int], out: str | Path,
                ramp: int = 32, chunk: int = 1024, levels: int | None = None,
                pixel_size_um: float = 1.0, scheduler=None, num_workers: int | None = None,
                dtype=np.float32) -> Path:
    """Blend tiles into an OME-Zarr image at ``out`` (module docstring); returns ``out``.

    Parameters
    ----------
    tiles : index -> path of a 2-D Zarr array (str, or (store path, array path) for an array
        inside a group); the tiles are never modified.
    positions : index -> (y, x) mosaic pixel of the tile's pixel (0, 0) (floats).
    shape : (H, W) of the mosaic.
    ramp : feathering width in pixels (at most the overlap).
    chunk : output chunk side (pixels); levels : pyramid levels (default: until the image is
        at most one chunk); pixel_size_um : level-0 pixel size (micrometres).
    scheduler, num_workers : where the chunks are computed (module docstring).
    """
    import dask
    import dask.array as da

    from metasensor.io.interrupt import quiet_zarr

    zarr = quiet_zarr()  # Ctrl-C reaches the main thread

    out = Path(out)
    if out.exists() and not _own_mosaic(out):
        raise ValueError(f"{out} exists and is not a mosaic written by metasensor: not replaced")
    if set(tiles) != set(positions):
        raise ValueError("tiles and positions must name the same tile indices")
    h, w = (int(v) for v in shape)
    if h < 1 or w < 1 or chunk < 16 or ramp < 1:
        raise ValueError(f"shape, chunk (>= 16) and ramp (>= 1) must be positive, got {shape}, "
                         f"{chunk}, {ramp}")
    if levels is None:
        levels = 1 + max(0, math.ceil(math.log2(max(h, w) / chunk)))
    keys = sorted(tiles)
    specs = [(str(t), None) if isinstance(t, str | Path) else (str(t[0]), str(t[1]))
             for t in (tiles[k] for k in keys)]
    pos = [tuple(float(v) for v in positions[k]) for k in keys]
    tmp = out.with_name(f".{out.name}.{uuid.uuid4().hex[:8]}.tmp")
    try:
        root = zarr.open_group(str(tmp), mode="w", zarr_format=2)
        chunks = tuple(tuple(min(chunk, n - s) for s in range(0, n, chunk)) for n in (h, w))
        base = da.map_blocks(_chunk, dtype=dtype, chunks=chunks, tiles=specs, positions=pos,
                             ramp=ramp, out_dtype=dtype, meta=np.empty((0, 0), dtype))
        shapes = []
        level = base
        for k in range(levels):
            target = root.create_array(str(k), shape=level.shape, chunks=(chunk, chunk),
                                       dtype=dtype, fill_value=0)

            def store(sched, src=level, dst=target):
                if isinstance(sched, str):
                    with dask.config.set(scheduler=sched, num_workers=num_workers):
                        return da.store(src, dst, lock=False)
                return da.store(src, dst, lock=False, scheduler=sched)

            _compute(store, scheduler)
            shapes.append(level.shape)
            if k + 1 < levels:
                saved = da.from_zarr(target)
                level = da.coarsen(np.mean, saved, {0: 2, 1: 2}, trim_excess=True).astype(dtype)
                level = level.rechunk(chunk)
        root.attrs["multiscales"] = [{
            "version": "0.4",
            "name": out.stem,
            "axes": [{"name": "y", "type": "space", "unit": "micrometer"},
                     {"name": "x", "type": "space", "unit": "micrometer"}],
            "datasets": [{"path": str(k), "coordinateTransformations": [
                {"type": "scale", "scale": [pixel_size_um * 2**k] * 2}]}
                for k in range(len(shapes))],
        }]
        root.attrs["metasensor"] = {"kind": "mosaic", "levels": len(shapes)}
        replace_tree(tmp, out)
    except BaseException:
        discard_tree(tmp)  # zarr's I/O thread may still be writing into it
        raise
    return out


def open_mosaic(path: str | Path, level: int = 0):
    """The Zarr array of one pyramid level of a mosaic written by :func:`blend_tiles`."""
    from metasensor.io.interrupt import quiet_zarr

    zarr = quiet_zarr()  # Ctrl-C reaches the main thread

    return zarr.open_array(str(Path(path)), mode="r", path=str(level))
