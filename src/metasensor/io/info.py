"""``metasensor info FILE``: what a file holds (kind, shape, dtype, axes, units, configuration,
provenance) for the files this package reads and writes: TIFF view stacks, raw frames and images,
Zarr / OME-Zarr stores, HDF5 PSF banks (this package's, the authors' MATLAB ``psf_z``),
napari-LF ``.lfc`` calibrations, configuration and calibration TOML files, ``summary.json``."""

from __future__ import annotations

import json
from pathlib import Path

import typer

__all__ = ["describe", "register"]

_CONFIG_KEYS = ("nnum", "scan", "moving", "mla_pitch", "mla_focal", "wavelength", "na")


def _config_lines(data: dict) -> list[str]:
    shown = [f"{k} = {data[k]}" for k in _CONFIG_KEYS if k in data]
    return [f"configuration: {', '.join(shown)}"] if shown else []


def _tiff(path: Path) -> list[str]:
    import tifffile

    with tifffile.TiffFile(path) as tif:
        series = tif.series[0]
        page = tif.pages.first
        lines = [f"pages: {len(tif.pages)}", f"shape: {tuple(series.shape)}",
                 f"dtype: {series.dtype}"]
        try:
            meta = json.loads(page.description or "")
        except ValueError:
            meta = None
        extra = meta.get("metasensor", {}) if isinstance(meta, dict) else {}
        lines.insert(0, f"kind: {extra.get('kind', 'TIFF')}")
        axes = extra.get("axes") or series.axes
        lines.append(f"axes: {axes}")
        if "pixel_size_m" in extra:
            lines.append(f"pixel size: {extra['pixel_size_m'] * 1e6:.4g} um")
        elif tif.is_imagej and tif.imagej_metadata.get("unit"):
            res = page.resolution
            lines.append(f"pixel size: {1 / res[0]:.4g} {tif.imagej_metadata['unit']}")
        if isinstance(meta, dict):
            lines += _config_lines(meta)
        lines += [f"{k}: {v}" for k, v in extra.items()
                  if k not in ("kind", "axes", "pixel_size_m", "view_shape")]
        if tif.is_imagej:
            lines.append("ImageJ metadata: yes")
    return lines


def _zarr(path: Path) -> list[str]:
    from metasensor.io.omezarr import is_ome_zarr, read_ome_zarr

    if is_ome_zarr(path):
        arr, meta = read_ome_zarr(path)
        lines = [f"kind: OME-Zarr {meta.get('kind', '')}".rstrip()]
    else:
        from metasensor.io.interrupt import quiet_zarr

        zarr = quiet_zarr()  # Ctrl-C reaches the main thread

        arr = zarr.open_array(str(path), mode="r")
        meta = dict(arr.attrs)
        lines = ["kind: Zarr " + str(meta.get("metasensor", {}).get("kind", ""))]
    lines += [f"shape: {tuple(arr.shape)}", f"dtype: {arr.dtype}"]
    extra = meta.get("metasensor", meta) if isinstance(meta, dict) else {}
    lines += _config_lines(meta) + _config_lines(extra)
    return lines + [f"{k}: {v}" for k, v in extra.items()
                    if k not in _CONFIG_KEYS and not isinstance(v, dict)][:20]


def _hdf5(path: Path) -> list[str]:
    import h5py

    with h5py.File(path, "r") as f:
        if "psf" in f:
            kind = "PSF bank (metasensor)"
        elif "psf_z" in f:
            kind = "PSF (authors' MATLAB v7.3 psf_z, MATLAB axes (y, x, u, v))"
        elif "geometry" in f:
            kind = "napari-LF calibration"
        else:
            kind = "HDF5"
        lines = [f"kind: {kind}"]

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset) and len(lines) < 30:
                lines.append(f"dataset {name}: shape {obj.shape}, dtype {obj.dtype}")

        f.visititems(visit)
        attrs = dict(f["psf"].attrs) if "psf" in f else {}
        if "config" in attrs:
            lines += _config_lines(json.loads(str(attrs["config"])))
        if "geometry" in f:
            g = f["geometry"].attrs
            lines.append("lenslet grid: " + ", ".join(f"{k} = {g[k]}" for k in
                                                      ("nu", "nv", "ns", "nt") if k in g))
    return lines


def describe(path: str | Path) -> list[str]:
    """Lines describing what ``path`` holds (see the module docstring)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"file not found: {path}")
    name = path.name.lower()
    if path.is_dir() or name.endswith(".zarr"):
        return [f"file: {path}", *_zarr(path)]
    head = path.read_bytes()[:1024]
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        return [f"file: {path}", *_tiff(path)]
    if b"\x89HDF" in head or name.endswith((".h5", ".hdf5", ".mat", ".lfc")):
        return [f"file: {path}", *_hdf5(path)]
    if name.endswith(".toml"):
        import tomllib

        data = tomllib.loads(path.read_text())
        if "calibration" in data:
            c = data["calibration"]
            return [f"file: {path}", "kind: lenslet-grid calibration",
                    *(f"{k}: {c[k]}" for k in ("nnum", "pitch", "rotation", "center",
                                               "lenslets", "scan", "moving", "peak_strength",
                                               "fit_residual") if k in c)]
        return [f"file: {path}", "kind: system configuration",
                *_config_lines(data.get("system", data))]
    if name.endswith(".json"):
        data = json.loads(path.read_text())
        return [f"file: {path}", "kind: JSON " + ("summary" if "summary" in name else ""),
                *(f"{k}: {json.dumps(v)[:100]}" for k, v in data.items())]
    raise ValueError(f"{path}: not a file metasensor knows (TIFF, Zarr, HDF5, TOML, JSON)")


def info_cmd(
    path: Path = typer.Argument(..., help="a file metasensor reads or writes"),
    out: Path | None = typer.Option(None, "--out", "-o", dir_okay=False,
                                    help="also write the description to this text file"),
) -> None:
    """Print what a file holds: kind, shape, axes, units, configuration, provenance.

    Example: metasensor info views.tif
    """
    lines = describe(path)
    if out is not None:
        from metasensor.io.atomic import atomic_write_text
        from metasensor.io.guard import guard

        guard([path], [out])
        atomic_write_text(out, "\n".join(lines) + "\n")
    for line in lines:
        typer.echo(line)


def register(app: typer.Typer) -> None:
    """Add ``info`` to the app."""
    app.command("info")(info_cmd)
