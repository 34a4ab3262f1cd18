"""View stacks on disk: multi-page TIFF (page ``u * nnum + v`` = view (u, v)) or Zarr.

The TIFF layout is the authors' "meta image" layout (docs/conventions.md). The TIFF's
ImageDescription (and the Zarr array's attributes) is the system configuration as JSON,
``cfg.to_dict()`` at the top level (``SystemConfig.from_json(description)`` reads it back), plus
one key ``"metasensor"`` with what else the writer knows (``kind``, ``view_shape``, extras).
Readers also accept a bare configuration and the older layout, which nested it under
``["metasensor"]["config"]``.
TIFF view stacks of uint8/uint16/float32 also carry ImageJ metadata (a second ImageDescription
tag: a stack of nnum² slices labelled "view u=.. v=..", so that ``tifffile.imread`` keeps
returning the pages in order; pixel size ``mla_pitch / scan`` in µm, the spacing of a view's
samples on the image plane), so Fiji, napari and ``tifffile`` read the physical pixel size, and
the JSON description's ``"metasensor"`` key names the axes ``["u", "v", "y", "x"]``.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from metasensor.config import SystemConfig
from metasensor.io.atomic import atomic_path
from metasensor.io.tiff import TiffReadError, TiffWarnings, read_tiff, truncated, unreadable

__all__ = ["write_views", "read_views", "read_config_from_views", "description",
           "stored_extras", "check_against_stored", "view_pixel_size"]


def description(cfg: SystemConfig | None, **meta) -> dict:
    """The metadata of a TIFF or Zarr this package writes: ``cfg.to_dict()`` at the top level
    (what docs/conventions.md asks of a view stack's description) and ``meta`` under
    ``"metasensor"``."""
    out = dict(cfg.to_dict()) if cfg is not None else {}
    out["metasensor"] = dict(meta)
    return out


def _check_views(views: np.ndarray, cfg=None, extra=None) -> np.ndarray:
    views = np.asarray(views)
    if views.ndim != 4 or views.shape[0] != views.shape[1]:
        raise ValueError(f"views must have shape (nnum, nnum, H, W), got {views.shape}")
    if views.dtype.kind not in "buif":
        raise ValueError(f"views must be real numbers, got dtype {views.dtype}")
    if cfg is not None and not isinstance(cfg, SystemConfig):
        raise TypeError(f"cfg must be a SystemConfig or None, got {type(cfg).__name__}")
    if extra is not None and not isinstance(extra, dict):
        raise TypeError(f"extra must be a dict or None, got {type(extra).__name__}")
    if extra:
        bad = [k for k in extra if not isinstance(k, str)]
        if bad:
            raise TypeError(f"extra's keys must be strings, got {bad[0]!r}")
        try:
            json.dumps(extra, allow_nan=False)
        except (TypeError, ValueError) as exc:  # stored as JSON in the file's description
            raise TypeError(f"extra must hold JSON values (numbers, strings, lists, dicts): "
                            f"{exc}") from None
    return views


def write_views(path: str | Path, views: np.ndarray, cfg: SystemConfig | None = None,
                extra: dict | None = None) -> Path:
    """Write a view stack ``(nnum, nnum, H, W)`` to ``.tif``/``.tiff``, ``.zarr`` or
    ``.ome.zarr`` (OME-NGFF, :mod:`metasensor.io.omezarr`) atomically."""
    import tifffile

    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"path must be a str or Path, got {type(path).__name__}")
    views = _check_views(views, cfg, extra)
    path = Path(path)
    meta = description(cfg, **{"kind": "views", "view_shape": list(views.shape),
                                "axes": ["u", "v", "y", "x"], **(extra or {})})
    if cfg is not None:
        meta["metasensor"].setdefault("pixel_size_m", view_pixel_size(cfg))
    n = views.shape[0]
    from metasensor.io.omezarr import is_ome_zarr, write_ome_zarr

    if is_ome_zarr(path):
        return write_ome_zarr(path, views, None if cfg is None else view_pixel_size(cfg), meta)
    if path.suffix.lower() == ".zarr":
        return _write_zarr(path, views, meta)
    if path.suffix.lower() not in (".tif", ".tiff"):
        raise ValueError(f"view stack path must end in .tif, .tiff or .zarr: {path}")
    pages = views.reshape(n * n, *views.shape[2:])
    extratags, options = _imagej_tags(views, cfg, json.dumps(meta))
    with atomic_path(path) as tmp:
        tifffile.imwrite(tmp, pages, metadata=None, photometric="minisblack",
                         bigtiff=pages.nbytes > 2**31, extratags=extratags, **options)
    return path


def view_pixel_size(cfg: SystemConfig) -> float:
    """Spacing of a view's samples on the image (MLA) plane [m]: ``mla_pitch / scan``."""
    return cfg.mla_pitch / cfg.scan


def _imagej_tags(views: np.ndarray, cfg: SystemConfig | None, text: str
                 ) -> tuple[list, dict]:
    """The ImageDescription tags of a view stack: the JSON description first (what
    ``page.description`` returns: docs/conventions.md), then, where ImageJ can hold the stack
    (uint8, uint16 or float32 under 4 GB), an ImageJ stack description (nnum² slices, so that
    ``tifffile.imread`` still returns the pages in order, page ``u·nnum + v`` = view (u, v);
    slice labels "view u=.. v=..", µm units, the image-plane sample spacing as the resolution).
    Returns (extratags, more tifffile.imwrite keywords)."""
    import tifffile

    tags = [(270, "s", 0, text, True)]
    if views.dtype not in (np.uint8, np.uint16, np.float32) or views.nbytes > 2**32 - 2**25:
        return tags, {}
    n, _, h, w = views.shape
    meta: dict = {"axes": "ZYX"}
    options: dict = {}
    if cfg is not None:
        um = view_pixel_size(cfg) * 1e6
        meta.update(unit="um")
        options = {"resolution": (1.0 / um, 1.0 / um), "resolutionunit": 1}
    tags.append((270, "s", 0, tifffile.imagej_description((n * n, h, w), **meta), True))
    labels = {"Labels": [f"view u={u} v={v}" for u in range(n) for v in range(n)],
              "Info": f"metasensor view stack: slice u*{n}+v = view (u, v); axes (u, v, y, x)"}
    tags += [(*t[:4], True) for t in tifffile.imagej_metadata_tag(labels, "<")]
    return tags, options


def _write_zarr(path: Path, views: np.ndarray, meta: dict) -> Path:
    """Write the store under a unique temporary name, then swap it in (:func:`replace_tree`);
    an existing folder is replaced only if it is a metasensor Zarr store."""
    from metasensor.io.atomic import staged_zarr
    from metasensor.io.interrupt import quiet_zarr

    zarr = quiet_zarr()  # Ctrl-C reaches the main thread

    with staged_zarr(path) as tmp:
        arr = zarr.open_array(str(tmp), mode="w-", shape=views.shape, dtype=views.dtype,
                              chunks=(1, 1, min(1024, views.shape[2]), min(1024, views.shape[3])))
        for u in range(views.shape[0]):
            arr[u] = views[u]
        arr.attrs.update(meta)
    return path


def _open_zarr(path: Path):
    """The array of a Zarr view store, read-only; one ``ValueError`` line if there is none."""
    from metasensor.io.interrupt import quiet_zarr

    zarr = quiet_zarr()  # Ctrl-C reaches the main thread

    try:
        return zarr.open_array(str(path), mode="r")
    except Exception as exc:  # noqa: BLE001 - zarr raises several kinds for a store without one
        raise ValueError(f"{path}: not a Zarr view stack (no readable array: "
                         f"{str(exc).strip().splitlines()[0] if str(exc).strip() else exc!r})"
                         ) from None


def read_views(path: str | Path, nnum: int | None = None, mmap: bool = False) -> np.ndarray:
    """Read a view stack written by :func:`write_views` (or any ``nnum²``-page TIFF).

    ``nnum`` is taken from the metadata, else from the page count (which must be a square).
    ``.zarr`` stores are returned lazily as a zarr array (index it to load blocks). A truncated
    or corrupt TIFF (a broken page chain, data past the end of the file, fewer pages than its
    description names) is one ``ValueError`` line (:mod:`metasensor.io.tiff`).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"view stack not found: {path}")
    from metasensor.io.omezarr import is_ome_zarr, read_ome_zarr

    if is_ome_zarr(path):
        return read_ome_zarr(path)[0]
    if path.suffix.lower() == ".zarr":
        arr = _open_zarr(path)
        if arr.ndim != 4:
            raise ValueError(f"{path}: expected a 4-D (nnum, nnum, H, W) array, got {arr.shape}")
        _real_dtype(arr.dtype, path)
        if arr.size and arr.nchunks_initialized == 0:
            raise ValueError(f"{path}: the Zarr view store holds no data (every chunk missing)")
        return CheckedZarr(arr, path)
    pages = read_tiff(path, mmap=mmap)  # not a TIFF, truncated or corrupt: one ValueError line
    _real_dtype(pages.dtype, path)
    if pages.size == 0:
        raise ValueError(f"{path}: not a readable TIFF view stack (no image data)")
    if pages.ndim == 2:
        pages = pages[None]
    elif pages.ndim == 4:  # an ImageJ hyperstack (T = u, Z = v): the same pages
        pages = pages.reshape(-1, *pages.shape[2:])
    if pages.ndim != 3:
        raise ValueError(f"{path}: expected a stack of 2-D pages, got shape {pages.shape}")
    if nnum is None:
        cfg = read_config_from_views(path)
        nnum = cfg.nnum if cfg is not None else math.isqrt(pages.shape[0])
    if nnum * nnum != pages.shape[0]:
        raise ValueError(f"{path}: {pages.shape[0]} pages is not nnum² for nnum = {nnum}")
    return pages.reshape(nnum, nnum, *pages.shape[1:])


def _real_dtype(dtype, path: Path) -> None:
    if np.dtype(dtype).kind not in "buif":
        raise ValueError(f"{path}: views must be real numbers, got dtype {np.dtype(dtype)}")


class CheckedZarr:
    """A Zarr view store read lazily (``shape``, ``dtype``, slicing, ``np.asarray``) whose
    damaged chunks are one ``ValueError`` line naming the store, not the codec's error."""

    def __init__(self, array, path: Path) -> None:
        self.array, self.path = array, Path(path)

    def __getattr__(self, name):  # shape, dtype, ndim, attrs, chunks, ...
        if name in ("array", "path"):
            raise AttributeError(name)
        return getattr(self.array, name)

    def __len__(self) -> int:
        return len(self.array)

    def __getitem__(self, key):
        try:
            return self.array[key]
        except (MemoryError, IndexError):
            raise
        except Exception as exc:  # noqa: BLE001 - codecs raise many types for damaged chunks
            text = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            raise ValueError(f"{self.path}: damaged Zarr chunk ({text})") from None

    def __array__(self, dtype=None, copy=None):
        return np.asarray(self[...], dtype=dtype)

    def __repr__(self) -> str:
        return f"CheckedZarr({str(self.path)!r}, shape={self.array.shape})"


def _stored_meta(path: Path) -> dict | None:
    """The JSON dict of a TIFF's description or a Zarr's attributes; ``None`` if it holds none
    (ValueError for a file that is not a readable TIFF)."""
    import tifffile

    from metasensor.io.omezarr import is_ome_zarr, read_ome_zarr

    if is_ome_zarr(path):
        meta = read_ome_zarr(path)[1]
    elif path.suffix.lower() == ".zarr":
        meta = dict(_open_zarr(path).attrs)
    else:
        warned = TiffWarnings()  # tifffile's logged warnings: kept off stderr, named here
        try:  # page 0 only (the rest of the chain is read_views' to check)
            with warned, tifffile.TiffFile(path) as tif:
                desc = tif.pages.first.description
                utf8 = _utf8_description(tif)
        except Exception as exc:
            detail = warned.messages[0] if warned.messages else f"{type(exc).__name__}: {exc}"
            if _first_ifd_cut(path):
                raise truncated(path, detail) from None
            raise unreadable(path, detail) from None
        if warned.messages:  # page 0's tags cut short: its description cannot be trusted
            raise truncated(path, warned.messages[0])
        try:
            meta = json.loads(desc)
        except (json.JSONDecodeError, RecursionError):  # not JSON, or nested thousands deep
            return None
        if not utf8 and isinstance(meta, dict) and path not in _NOTED:  # Windows-1252
            import sys

            _NOTED.add(path)
            print(f"note: {path.name}'s description is not UTF-8 text; read as Windows-1252",
                  file=sys.stderr)
    return meta if isinstance(meta, dict) else None


_NOTED: set[Path] = set()  # files whose non-UTF-8 description was named once


def _utf8_description(tif) -> bool:
    """Whether page 0's ImageDescription bytes are UTF-8 (tifffile decodes others silently)."""
    tag = tif.pages.first.tags.get(270)
    if tag is None or not isinstance(tag.value, str) or tag.value.isascii():
        return True
    try:
        tif.filehandle.seek(tag.valueoffset)
        tif.filehandle.read(tag.count).rstrip(b"\0").decode("utf-8")
    except UnicodeDecodeError:
        return False
    except Exception:  # noqa: BLE001 - unreadable bytes: the description stands as decoded
        return True
    return True


def _first_ifd_cut(path: Path) -> bool:
    """True for a classic TIFF whose first IFD starts inside the file but does not end there
    (a file cut inside page 0's tags), as opposed to a file that is no TIFF at all."""
    import struct

    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(10)
    if len(head) < 8 or head[:4] not in (b"II*\x00", b"MM\x00*"):
        return False
    order = "<" if head[:2] == b"II" else ">"
    offset = struct.unpack(order + "I", head[4:8])[0]
    if not 8 <= offset < size:
        return False
    with open(path, "rb") as fh:
        fh.seek(offset)
        count = fh.read(2)
    return len(count) < 2 or offset + 2 + 12 * struct.unpack(order + "H", count)[0] + 4 > size


def read_config_from_views(path: str | Path, strict: bool = True) -> SystemConfig | None:
    """The SystemConfig stored in a view stack's metadata, or ``None``. ``strict=False``: a
    stored configuration that cannot be read (an older version's field, a foreign description)
    is named on stderr and counts as none (for callers given a configuration of their own); a
    file that is not a readable TIFF, or a truncated or corrupt one, is an error either way."""
    if not strict:
        try:
            return read_config_from_views(path)
        except TiffReadError:  # not a TIFF, truncated, corrupt: its reader would fail anyway
            raise
        except ValueError as exc:  # ConfigError is a ValueError
            import sys

            print(f"note: ignoring the configuration stored in {Path(path).name}: {exc}",
                  file=sys.stderr)
            return None
    path = Path(path)
    meta = _stored_meta(path)
    if meta is None:
        return None
    fields = set(SystemConfig.__dataclass_fields__)
    top = {k: v for k, v in meta.items() if k in fields}
    if top:  # the configuration itself (this writer's layout, or a bare one)
        return SystemConfig.from_dict(top)
    nested = meta.get("metasensor")
    cfg = nested.get("config") if isinstance(nested, dict) else None  # the older layout
    if cfg and not isinstance(cfg, dict):
        raise ValueError(f"{path}: the stored metasensor config is not a table: {cfg!r:.60}")
    return SystemConfig.from_dict(cfg) if cfg else None


def stored_extras(path: str | Path) -> dict:
    """What a TIFF or Zarr written by this package keeps under ``"metasensor"`` in its
    description (e.g. ``scan_order``, ``moving``), or ``{}`` (none, or not readable)."""
    try:
        meta = _stored_meta(Path(path))
    except Exception:  # unreadable: the caller's defaults apply
        return {}
    extra = meta.get("metasensor") if meta is not None else None
    return extra if isinstance(extra, dict) else {}


def check_against_stored(cfg, stored, source: Path, views: Path) -> None:
    """A configuration ``cfg`` (from ``source``) given for views that store their own
    (``stored``): a different sampling (nnum, scan) would silently process the wrong grid, so it
    is refused; other differences (e.g. a
    corrected NA) are the user's to make, and are named on stderr."""
    for name in ("nnum", "scan"):
        if getattr(cfg, name) != getattr(stored, name):
            raise ValueError(f"{source}: {name} = {getattr(cfg, name)} but {views} was captured "
                             f"with {name} = {getattr(stored, name)}")
    diff = [k for k, v in cfg.to_dict().items() if stored.to_dict().get(k) != v]
    if diff:
        import sys

        print(f"note: {source} differs from the configuration stored in {Path(views).name} in "
              f"{', '.join(diff)}; using {Path(source).name}'s", file=sys.stderr)
