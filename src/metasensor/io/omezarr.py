"""OME-Zarr (OME-NGFF) output through the ``ome-zarr`` package, for viewers (napari, Fiji's
n5/zarr readers, the OME-NGFF validator).

A view stack ``(nnum, nnum, H, W)`` is written as one multiscale image of axes ``(c, y, x)``:
channel ``c = u·nnum + v`` is view (u, v) (the TIFF page order; NGFF allows one non-space,
non-time axis), y and x in micrometres with the scale ``mla_pitch / scan`` (the spacing of a
view's samples on the image plane); an image ``(H, W)`` as ``(y, x)`` with its grid pitch, with
a 2× mean pyramid for viewing. The package's own metadata (the configuration and extras, as in
a TIFF's description) goes into the group's attributes under ``"metasensor"``. The store is
written under a temporary name and renamed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["write_ome_zarr", "read_ome_zarr", "is_ome_zarr"]


def is_ome_zarr(path: str | Path) -> bool:
    """Paths ending in ``.ome.zarr`` are written and read as OME-Zarr."""
    return str(path).lower().rstrip("/").endswith(".ome.zarr")


def write_ome_zarr(path: str | Path, array: np.ndarray, pixel_m: float | None, meta: dict,
                   levels: int | None = None) -> Path:
    """Write ``array`` (views (n, n, H, W) or an image (H, W)) as OME-Zarr at ``path``.

    ``pixel_m``: the y/x sample spacing [m] (None: unit-less scale 1); ``meta``: JSON-able
    metadata stored under ``"metasensor"``; ``levels``: pyramid levels (default: 2× steps
    while the smaller side stays >= 64 px; 1 for view stacks).
    """
    from ome_zarr.io import parse_url
    from ome_zarr.scale import Methods
    from ome_zarr.writer import write_image

    from metasensor.io.interrupt import quiet_zarr

    zarr = quiet_zarr()  # Ctrl-C reaches the main thread

    path = Path(path)
    array = np.asarray(array)
    if array.ndim == 4:
        data = array.reshape(-1, *array.shape[2:])
        axes = ["c", "y", "x"]
        levels = 1
    elif array.ndim == 2:
        data = array
        axes = ["y", "x"]
        if levels is None:
            levels = 1
            while min(data.shape) // 2 ** levels >= 64:
                levels += 1
    else:
        raise ValueError(f"OME-Zarr output takes views (n, n, H, W) or an image (H, W), got "
                         f"shape {array.shape}")
    um = 1.0 if pixel_m is None else pixel_m * 1e6
    units = {} if pixel_m is None else {"y": "micrometer", "x": "micrometer"}
    from metasensor.io.atomic import staged_zarr

    with staged_zarr(path) as tmp:
        root = zarr.group(store=parse_url(str(tmp), mode="w").store, overwrite=True)
        scale = {"c": 1.0, "y": um, "x": um} if data.ndim == 3 else {"y": um, "x": um}
        write_image(data, root, axes=axes, scale=scale, axes_units=units or None,
                    scale_factors=[2**k for k in range(1, levels)],
                    method=Methods.LOCAL_MEAN, name=str(meta.get("kind", "image")),
                    storage_options={"chunks": (*[1] * (data.ndim - 2),
                                                min(1024, data.shape[-2]),
                                                min(1024, data.shape[-1]))})
        root.attrs["metasensor"] = meta
    return path


def read_ome_zarr(path: str | Path):
    """(full-resolution array, the ``"metasensor"`` metadata) of a store written by
    :func:`write_ome_zarr`; view stacks come back as a lazy dask array (n, n, H, W)."""
    import dask.array as da

    from metasensor.io.interrupt import quiet_zarr

    zarr = quiet_zarr()  # Ctrl-C reaches the main thread

    path = Path(path)
    try:
        root = zarr.open_group(str(path), mode="r")
        ome = root.attrs.get("ome", root.attrs)
        arr = root[ome["multiscales"][0]["datasets"][0]["path"]]
    except Exception as exc:  # noqa: BLE001 - zarr raises several kinds for a foreign store
        raise ValueError(f"{path}: not an OME-Zarr image ({type(exc).__name__})") from None
    meta = dict(root.attrs.get("metasensor", {}))
    if arr.ndim == 3:
        n = int(round(arr.shape[0] ** 0.5))
        if n * n != arr.shape[0]:
            raise ValueError(f"{path}: {arr.shape[0]} channels is not nnum²")
        return da.from_zarr(arr).reshape(n, n, *arr.shape[1:]), meta
    return arr, meta
