"""The plugin's reader (npe2 ``readers`` contribution): what metasensor writes, opened as layers.

- raw frame stacks (``simulate``'s ``frames.tif``, any TIFF whose description says
  ``"kind": "frames"``) → one image layer (t, y, x);
- view stacks (TIFF with ``nnum²`` pages, OME-TIFF, Zarr, OME-Zarr) → one 4-D layer
  (u, v, y, x): napari's dimension sliders step through the views;
- calibration TOML (``metasensor calibrate``) → a shapes layer of the lenslet grid;
- result folders (``reconstruct``, ``depth``, ``simulate``, ``evaluate`` outputs) → the image,
  depth and confidence maps, and the per-block wavefront maps (``zernike.npy``).

All layers are placed in sensor-plane micrometres (:mod:`metasensor.napari.layers`). Files are
read with the package's own readers (:mod:`metasensor.io`), never modified.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from metasensor.config import SystemConfig
from metasensor.napari import layers as L

__all__ = ["get_reader", "read_path", "read_views_file", "read_calibration", "read_result_folder"]

_TIFF = (".tif", ".tiff")
_IMAGE_KINDS = ("truth", "sensor2d", "hardware_ao", "image")
_RESULT_FILES = ("image.tif", "image.zarr", "zernike.npy", "disparity.tif", "confidence.tif",
                 "image_depth.tif", "views.tif", "frames.tif", "truth.tif", "calib.toml")


def get_reader(path):
    """npe2 reader hook: a function that reads ``path``, or ``None`` when it is not ours."""
    if isinstance(path, list | tuple):
        if len(path) != 1:
            return None
        path = path[0]
    p = Path(path)
    try:
        if _kind(p) is None:
            return None
    except (OSError, ValueError):
        return None
    return read_path


def read_path(path) -> list[tuple]:
    """Layer data tuples for one path (see the module docstring)."""
    if isinstance(path, list | tuple):
        return [t for p in path for t in read_path(p)]
    p = Path(path)
    kind = _kind(p)
    if kind == "views":
        return [read_views_file(p)]
    if kind == "frames":
        return [_read_frames(p)]
    if kind == "image":
        return [_read_image_file(p)]
    if kind == "calibration":
        return [read_calibration(p)]
    if kind == "folder":
        return read_result_folder(p)
    raise ValueError(f"{p}: not a metasensor file (frames, views, image, calibration or a "
                     "result folder)")


# ----------------------------------------------------------------------------- what is it
def _kind(p: Path) -> str | None:
    suffix = p.suffix.lower()
    if suffix == ".toml":
        return "calibration" if p.is_file() and "[calibration]" in p.read_text(
            errors="replace") else None
    if suffix == ".zarr" and p.is_dir():
        arr, _, _ = _zarr_array(p)
        return {4: "views", 2: "image"}.get(arr.ndim) if arr is not None else None
    if suffix in _TIFF and p.is_file():
        return _tiff_kind(p)
    if p.is_dir() and any((p / n).exists() for n in _RESULT_FILES):
        return "folder"
    return None


def _tiff_kind(p: Path) -> str | None:
    import tifffile

    with tifffile.TiffFile(p) as tif:
        n = len(tif.pages)
        first = tif.pages.first
        if first.ndim != 2 and not (first.ndim == 3 and tif.is_ome):
            return None
        stored = _json_kind(first.description)
    if stored == "frames":
        return "frames"
    if stored in ("views", "views_clean"):
        return "views"
    if stored is not None and n == 1:
        return "image"
    if n > 1 and math.isqrt(n) ** 2 == n:
        return "views"  # nnum² pages: the authors' "meta image" layout
    if n > 1:
        return "frames"
    return "image"


def _json_kind(description: str) -> str | None:
    try:
        meta = json.loads(description)
    except (json.JSONDecodeError, TypeError):
        return None
    inner = meta.get("metasensor") if isinstance(meta, dict) else None
    return inner.get("kind") if isinstance(inner, dict) else None


# ----------------------------------------------------------------------------- configuration
def _config_and_extras(p: Path) -> tuple[SystemConfig | None, dict]:
    """The configuration and extras stored in a TIFF/Zarr of this package (else None, {})."""
    from metasensor.io.views import read_config_from_views, stored_extras

    try:
        cfg = read_config_from_views(p, strict=False)
    except (OSError, ValueError):
        cfg = None
    return cfg, stored_extras(p)


def _sibling_config(folder: Path) -> SystemConfig | None:
    """A configuration for files that store none: ``config.toml`` beside them, else the one
    stored in a view stack or image there, else None."""
    toml = folder / "config.toml"
    if toml.is_file():
        try:
            return SystemConfig.from_toml(toml)
        except (OSError, ValueError):
            pass
    for name in ("image.tif", "views.tif", "frames.tif", "truth.tif"):
        if (folder / name).is_file():
            cfg, _ = _config_and_extras(folder / name)
            if cfg is not None:
                return cfg
    return None


# ----------------------------------------------------------------------------- OME
def _zarr_array(p: Path):
    """(array, physical (y, x) spacing in µm or None, attrs) of a Zarr store: a plain array,
    or an OME-Zarr group (its first multiscale level and that level's scale)."""
    import zarr

    try:
        node = zarr.open(str(p), mode="r")
    except Exception:  # noqa: BLE001 - not a store zarr can open
        return None, None, {}
    if hasattr(node, "shape"):
        return node, None, dict(node.attrs)
    attrs = dict(node.attrs)
    ome = attrs.get("ome", attrs)
    scales = ome.get("multiscales") if isinstance(ome, dict) else None
    if not scales:
        return None, None, attrs
    level = scales[0]["datasets"][0]
    arr = node[level["path"]]
    spacing = None
    for t in level.get("coordinateTransformations", []):
        if t.get("type") == "scale":
            axes = [a.get("name") if isinstance(a, dict) else a for a in scales[0].get("axes", [])]
            unit = _ome_zarr_unit(scales[0].get("axes", []))
            s = list(t["scale"])
            if axes[-2:] == ["y", "x"] or not axes:
                spacing = float(s[-2]) * unit
    return arr, spacing, attrs


def _ome_zarr_unit(axes) -> float:
    """Factor from an OME-Zarr axis unit to µm (1 when unknown)."""
    units = {"micrometer": 1.0, "nanometer": 1e-3, "millimeter": 1e3, "meter": 1e6}
    for a in axes:
        if isinstance(a, dict) and a.get("name") == "x":
            return units.get(a.get("unit"), 1.0)
    return 1.0


def _ome_tiff_spacing(p: Path) -> float | None:
    """PhysicalSizeY of an OME-TIFF, in µm (None when it has none)."""
    import xml.etree.ElementTree as ET

    import tifffile

    with tifffile.TiffFile(p) as tif:
        if not tif.is_ome:
            return None
        root = ET.fromstring(tif.ome_metadata)
    for el in root.iter():
        if el.tag.endswith("Pixels") and "PhysicalSizeY" in el.attrib:
            unit = el.attrib.get("PhysicalSizeYUnit", "µm")
            factor = {"µm": 1.0, "um": 1.0, "nm": 1e-3, "mm": 1e3, "m": 1e6}.get(unit, 1.0)
            return float(el.attrib["PhysicalSizeY"]) * factor
    return None


# ----------------------------------------------------------------------------- readers
def read_views_file(p) -> tuple:
    """A view stack (TIFF, OME-TIFF, Zarr or OME-Zarr) as a 4-D (u, v, y, x) layer tuple."""
    from metasensor.io.views import read_views

    p = Path(p)
    cfg, extras = _config_and_extras(p)
    spacing = None
    if p.suffix.lower() == ".zarr":
        arr, spacing, attrs = _zarr_array(p)
        if arr is None or arr.ndim != 4:
            raise ValueError(f"{p}: not a (nnum, nnum, H, W) view store")
        views = arr
    else:
        spacing = _ome_tiff_spacing(p)
        views = read_views(p, nnum=None if cfg is None else cfg.nnum,
                           mmap=p.stat().st_size > 2**28)
    name = p.stem
    if cfg is None:  # a foreign stack: nnum from its shape, the prototype's optics otherwise
        nnum = int(views.shape[0])
        cfg = SystemConfig(nnum=nnum, mla_pitch=SystemConfig().pixel_pitch * nnum,
                           scan=_guess_scan(nnum))
        if spacing is None and cfg.scan > 1:  # the guess sets the samples' spacing: say so
            name = f"{p.stem} (scan {cfg.scan} x {cfg.scan} assumed)"
    return L.views_layer(views, cfg, origin=extras.get("origin"), name=name, source=p,
                         scale_um=spacing)


def _guess_scan(nnum: int) -> int:
    """A scan period that divides nnum (5 for the prototype's 15, else 1)."""
    return 5 if nnum % 5 == 0 and SystemConfig().nnum == nnum else 1


def _read_frames(p: Path) -> tuple:
    from metasensor.io.tiff import read_tiff

    cfg, _ = _config_and_extras(p)
    frames = read_tiff(p, mmap=p.stat().st_size > 2**28)
    return L.frames_layer(frames, cfg, name=p.stem, source=p)


def _read_image_file(p: Path, cfg: SystemConfig | None = None, origin=None) -> tuple:
    """A 2-D TIFF/Zarr: a reconstruction, truth or 2-D sensor image (pixel grid) or a depth
    map (the views' grid: ``disparity``, ``confidence``, ``image_depth``, ``object_distance``)."""
    from metasensor.io.tiff import read_tiff

    stored, extras = _config_and_extras(p)
    cfg = stored or cfg or _sibling_config(p.parent)
    origin = extras.get("origin", origin)
    if p.suffix.lower() == ".zarr":
        arr, _, _ = _zarr_array(p)
    else:
        arr = np.squeeze(read_tiff(p))
    if arr is None or arr.ndim != 2:
        raise ValueError(f"{p}: expected one 2-D image")
    kind = extras.get("kind", "image")
    on_views = kind in ("disparity", "confidence", "image_depth", "object_distance")
    cmap = {"disparity": "turbo", "image_depth": "turbo", "object_distance": "turbo",
            "confidence": "magma"}.get(kind, "gray")
    unit = extras.get("unit")
    return L.image_layer(arr, cfg, origin=origin, name=p.stem, on_views=on_views, kind=kind,
                         source=p, colormap=cmap, **({"unit": unit} if unit else {}))


def read_calibration(p, pixel_pitch: float | None = None) -> tuple:
    """A calibration TOML as the lenslet-grid shapes layer, in the raw frame's micrometres: the
    pixel pitch is ``pixel_pitch`` [m], else that of ``config.toml`` beside it, else the
    prototype's pitch for the calibration's ``nnum``."""
    from metasensor.sensor.calibration import Calibration

    p = Path(p)
    calib = Calibration.from_toml(p)
    if pixel_pitch is None:
        cfg = _sibling_config(p.parent)
        pixel_pitch = (cfg.pixel_pitch if cfg is not None
                       else SystemConfig().mla_pitch / calib.nnum)
    return L.grid_layer(calib, pixel_pitch, name=f"{p.stem} grid", source=p)


def read_result_folder(p) -> list[tuple]:
    """Every layer a result folder holds: raw frames, views, truth, the reconstruction, depth
    maps, the per-block wavefront maps, and the lenslet grid of a calibration in it."""
    p = Path(p)
    cfg = _sibling_config(p)
    out: list[tuple] = []
    if (p / "frames.tif").is_file():
        out.append(_read_frames(p / "frames.tif"))
    if (p / "calib.toml").is_file():
        out.append(read_calibration(p / "calib.toml",
                                    None if cfg is None else cfg.pixel_pitch))
    if (p / "views.tif").is_file():
        out.append(read_views_file(p / "views.tif"))
    origin = None
    for name in ("truth.tif", "image.tif"):
        if (p / name).is_file():
            out.append(_read_image_file(p / name, cfg))
            origin = out[-1][1]["metadata"]["metasensor"].get("origin")
    if not (p / "image.tif").is_file() and (p / "image.zarr").is_dir():
        out.append(_read_image_file(p / "image.zarr", cfg))
    for name in ("image_depth", "disparity", "confidence"):
        if (p / f"{name}.tif").is_file():
            out.append(_read_image_file(p / f"{name}.tif", cfg or _depth_config(p), origin))
            out[-1][1]["visible"] = name == "image_depth"
    if (p / "zernike.npy").is_file():
        image = next((t for t in out if t[1]["metadata"]["metasensor"]["kind"] == "image"),
                     None)
        if image is not None:
            z = np.load(p / "zernike.npy", allow_pickle=False)
            out.append(L.wavefront_layer(z, cfg, image[0].shape, origin=origin,
                                         source=p / "zernike.npy"))
    return out


def _depth_config(p: Path) -> SystemConfig | None:
    """The configuration of the views a depth folder came from (``depth.json``'s ``views``)."""
    try:
        views = Path(json.loads((p / "depth.json").read_text())["views"])
    except (OSError, ValueError, KeyError, TypeError):
        return None
    cfg, _ = _config_and_extras(views) if views.exists() else (None, {})
    return cfg
