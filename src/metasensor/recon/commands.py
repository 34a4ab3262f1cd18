"""Command-line commands of the recon stage (registered on the main app by metasensor.cli)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer

__all__ = ["register", "read_psf_file", "write_outputs"]


def read_psf_file(path: Path, with_attrs: bool = False):
    """PSF bank (nnum, nnum, K, K) and its SystemConfig from a ``metasensor psf`` HDF5 file
    (:func:`metasensor.optics.psf_io.load_psf`), plus its attributes if ``with_attrs``; refuses
    banks sampled finer than the pixels. An authors' MATLAB v7.3 file (``psf_z``) gives the
    bank on the pixel grid and no configuration (None)."""
    from metasensor.optics.psf_io import is_matlab_psf, load_matlab_psf, load_psf

    if is_matlab_psf(path):  # the authors' psf_z (MATLAB v7.3): no configuration inside
        bank = load_matlab_psf(path)
        return (bank, None, {"source": "matlab"}) if with_attrs else (bank, None)
    bank, cfg, attrs = load_psf(path, with_attrs=True)
    if int(np.ravel(attrs.get("subsample", 1))[0]) != 1:
        raise ValueError(f"{path}: PSF bank sampled at pixel_pitch/{attrs['subsample']}; "
                         "reconstruction needs subsample 1")
    return (bank, cfg, attrs) if with_attrs else (bank, cfg)


def write_outputs(out: Path, rec, views, origin=None, provenance: dict | None = None
                  ) -> list[Path]:
    """image.tif (float32, config JSON in the description), zernike.npy, summary.json and a PNG.
    ``origin``: the views' stored sensor origin (realign's), recorded with the image."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import tifffile

    from metasensor.io.atomic import atomic_path, atomic_write_text
    from metasensor.io.views import description

    out.mkdir(parents=True, exist_ok=True)
    image = np.asarray(rec.image, dtype=np.float32)
    meta = description(rec.config, **image_meta(rec, origin))
    with atomic_path(out / "image.tif") as tmp:
        tifffile.imwrite(tmp, image, description=json.dumps(meta), metadata=None)
    with atomic_path(out / "zernike.npy") as tmp:
        np.save(tmp, rec.zernike)
    summary = {"method": rec.method, "blocks": [len(rec.history), len(rec.history[0])],
               "solver": rec.solver,  # Richardson-Lucy's parameters; HQS uses neither
               "iterations": rec.iterations if rec.solver == "rl" else None,
               "subsets": rec.subsets if rec.solver == "rl" else None,
               "seconds": rec.seconds, "views_used": rec.views_used,
               "shape": list(image.shape), "history": rec.history,
               "registration_px": rec.registration,
               "registration_zernike": (None if rec.registration_zernike is None
                                        else rec.registration_zernike.tolist())}
    if rec.method in ("wave", "geometric"):  # DAO: the estimated wavefront of every block
        summary["zernike_per_block"] = np.asarray(rec.zernike).tolist()
    if provenance is not None:
        summary["provenance"] = provenance
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1, default=str))
    c = rec.config.center
    d = rec.config.scan_step_px
    f = _preview_factor(image.shape)  # a sensor-sized field is drawn block-averaged
    centre = _upsampled_block_mean(np.asarray(views[c, c], dtype=np.float32), d, f)
    shown = _block_mean(image, f)
    fig, axes = plt.subplots(1, 2, figsize=(10, 5.4), constrained_layout=True)
    for ax, img, title in ((axes[0], centre, f"centre view ({c}, {c}), up-sampled x{d}"),
                           (axes[1], shown, f"ISA reconstruction ({rec.method})")):
        lo, hi = np.percentile(img, [0.5, 99.5])
        ax.imshow(img, cmap="gray", vmin=lo, vmax=hi if hi > lo else lo + 1)
        ax.set_title(title)
        ax.set_axis_off()
    for b in rec.blocks[1:] if len(rec.blocks) > 1 else []:
        y0, y1, x0, x1 = (e / f for e in b.core)
        axes[1].plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], lw=0.4, color="tab:orange")
    with atomic_path(out / "reconstruction.png") as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    return [out / n for n in ("image.tif", "zernike.npy", "summary.json", "reconstruction.png")]


RESULT_FILES = ("image.tif", "image.zarr", "zernike.npy", "summary.json", "reconstruction.png")
PREVIEW_PX = 2048  # longest side of the images drawn in reconstruction.png


def _preview_factor(shape) -> int:
    return max(1, -(-max(shape) // PREVIEW_PX))


def _block_mean(img: np.ndarray, f: int) -> np.ndarray:
    """Mean over f x f blocks (the figure's preview of a large field; f = 1: the image)."""
    if f == 1:
        return img
    h, w = (img.shape[0] // f) * f, (img.shape[1] // f) * f
    return img[:h, :w].reshape(h // f, f, w // f, f).mean(axis=(1, 3))


def _overlap_matrix(n: int, d: int, f: int) -> np.ndarray:
    """(n·d // f, n) weights: the share of preview pixel i's f pixels that sample s covers when
    up-sampled x d (pixels [s·d, (s+1)·d)), over f."""
    edges = np.arange(n * d // f + 1, dtype=np.int32) * np.int32(f)
    starts = np.arange(n + 1, dtype=np.int32) * np.int32(d)
    width = np.minimum(edges[1:, None], starts[None, 1:]) - np.maximum(edges[:-1, None],
                                                                      starts[None, :-1])
    return np.clip(width, 0, None).astype(np.float32) / np.float32(f)


def _upsampled_block_mean(view: np.ndarray, d: int, f: int) -> np.ndarray:
    """``_block_mean(np.kron(view, ones((d, d))), f)`` without the d²-times larger intermediate
    (190 MB for the centre view of the whole sensor): two overlap products (their int32 weights
    ~21 MB each at f = 4)."""
    if f == 1:
        return np.kron(view, np.ones((d, d), np.float32))
    ay = _overlap_matrix(view.shape[0], d, f)
    ax = _overlap_matrix(view.shape[1], d, f)
    return ay @ view @ ax.T


def image_meta(rec, origin) -> dict:
    """What an image's description keeps under "metasensor": its kind, the method, and the
    sensor ``origin`` (row, col) of the views it came from when they stored one (realign's:
    image pixel (i, j) is sensor point ``origin + (i + o, j + o)``, docs/conventions.md)."""
    meta = {"kind": "image", "method": rec.method}
    if origin is not None:
        meta["origin"] = origin
    return meta


def _origin(value, views: Path):
    """A stored origin as [row, col] floats, or None (none stored, or malformed: named on
    stderr, and left out of the image's description)."""
    if value is None:
        return None
    try:
        pair = [] if isinstance(value, str | bytes | dict) else [float(v) for v in value]
    except (TypeError, ValueError):
        pair = []
    if len(pair) != 2 or not all(np.isfinite(pair)):
        typer.echo(f"note: {views} stores a malformed origin {value!r}; the image gets none",
                   err=True)
        return None
    return pair


def register(app: typer.Typer) -> None:
    """Add this stage's commands to app."""

    @app.command("reconstruct")
    def reconstruct_cmd(
        views: Path = typer.Argument(..., help="view stack (.tif pages u*nnum+v, or .zarr)"),
        out: Path = typer.Option(..., "--out", "-o", file_okay=False, help="output folder"),
        psf: Path | None = typer.Option(None, "--psf", help="PSF bank (HDF5, dataset 'psf')"),
        config: Path | None = typer.Option(None, "--config", help="system configuration TOML"),
        method: str = typer.Option("isa", "--method", "--dao",
                                   help="isa | wave | geometric (DAO first)"),
        system: Path | None = typer.Option(
            None, "--system", help="system aberration (system.h5 from calibrate-aberration): "
            "its field map initialises DAO, or is used as is with --method isa"),
        blocks: str = typer.Option("1x1", help="multisite blocks, e.g. 4x4"),
        overlap: int = typer.Option(20, help="block overlap in output pixels"),
        solver: str | None = typer.Option(
            None, help="ISA solver: hqs (sparse-gradient prior) | rl (Richardson-Lucy); default "
            "hqs, or rl when --iterations/--subsets is given or the scan step exceeds 5 px"),
        register_views: bool = typer.Option(
            False, "--register/--no-register",
            help="register the views against the PSF bank first (for banks that may be off)"),
        iterations: int | None = typer.Option(None, help="Richardson-Lucy iterations"),
        subsets: int | None = typer.Option(None, help="view subsets per iteration"),
        view_radius: float | None = typer.Option(
            None, "--view-radius", help="use the views within this radius (in views) of the "
            "centre view; default: the authors' 113 views (radius 6 for nnum 15); the pupil's "
            "radius (7.5) adds its edge views"),
        zernike: str | None = typer.Option(None, help="global aberration, e.g. '4:0.5,7:-0.2', "
                                            "or a .npy Noll vector (simulate's wavefront.npy)"),
        field_zernike: Path | None = typer.Option(
            None, "--field-zernike", help=".npy (by, bx, J) Noll vectors over the field"),
        scheduler: str | None = typer.Option(
            None, help="dask scheduler address tcp://host:port (trusted: dask exchanges "
            "pickles; use a private network or tls://)"),
        device: str | None = typer.Option(None, help="cpu or cuda (default: cuda if present)"),
        zarr_out: bool = typer.Option(False, "--zarr", help="also stitch into out/image.zarr "
                                      "block by block (large fields)"),
    ) -> None:
        """Reconstruct the all-in-focus image from views (ISA; multisite blocks through Dask).

        Example: metasensor reconstruct cap/views.tif --config cfg.toml --blocks 4x4 --out result/

        With DAO: metasensor reconstruct views.tif --dao wave --system system.h5 --out result/
        """
        from metasensor.config import SystemConfig
        from metasensor.io.views import (
            check_against_stored,
            read_config_from_views,
            read_views,
            stored_extras,
        )
        from metasensor.optics.psf_io import parse_zernike, read_npy
        from metasensor.recon.api import reconstruct
        from metasensor.recon.blocks import parse_pair

        if psf is not None and config is not None:
            raise ValueError("give either --psf or --config, not both")
        if solver == "hqs" and (iterations is not None or subsets is not None):
            raise ValueError("--iterations/--subsets set Richardson-Lucy's passes; --solver hqs "
                             "takes neither (drop them, or use --solver rl)")
        if psf is not None and (zernike or field_zernike is not None or system is not None):
            raise ValueError("--psf is a complete PSF bank: --zernike/--field-zernike/--system "
                             "would be ignored; give the aberration or the bank, not both")
        if not views.exists():
            raise FileNotFoundError(f"view stack not found: {views}")
        from metasensor.io.atomic import StagedFolder
        from metasensor.io.guard import guard, npy_argument

        guard([views, psf, config, field_zernike, system, npy_argument(zernike)],
              [out / n for n in RESULT_FILES], folders=[out])
        bank = None
        cfg = None
        if psf is not None:
            bank, cfg, psf_attrs = read_psf_file(psf, with_attrs=True)
        stored = read_config_from_views(views, strict=config is None and psf is None)
        if config is not None:
            cfg = SystemConfig.from_toml(config)
        if cfg is None and psf is not None:  # a bank without a configuration (authors' file)
            cfg = stored
            if cfg is not None and bank.shape[0] != cfg.nnum:
                raise ValueError(f"{psf}: {bank.shape[0]} x {bank.shape[0]} views, but {views} "
                                 f"has nnum {cfg.nnum}")
        if psf is not None and stored is not None and cfg.nnum != stored.nnum:
            raise ValueError(f"{psf}: PSF bank made for nnum {cfg.nnum}, but {views} has nnum "
                             f"{stored.nnum}")
        if psf is not None and stored is not None and cfg.scan != stored.scan:
            cfg = cfg.replace(scan=stored.scan)  # a bank does not depend on the scan
        if cfg is not None and stored is not None:
            check_against_stored(cfg, stored, psf or config, views)
        if cfg is None:
            cfg = stored
        if cfg is None:
            raise ValueError(f"{views}: no system configuration stored; pass --config cfg.toml")
        big = views.suffix.lower() != ".zarr" and views.stat().st_size > 2**29
        stack = read_views(views, nnum=cfg.nnum, mmap=big)  # zarr: lazy, read block by block
        origin = _origin(stored_extras(views).get("origin"), views)
        fz = None
        if field_zernike is not None:
            if not field_zernike.is_file():
                raise FileNotFoundError(f"field Zernike file not found: {field_zernike}")
            fz = read_npy(field_zernike, "--field-zernike")
        if system is not None:
            if fz is not None:
                raise ValueError("give either --system or --field-zernike, not both")
            from metasensor.dao.system_aberration import SystemAberration

            if not system.is_file():
                raise FileNotFoundError(f"system aberration file not found: {system}")
            fz = SystemAberration.load(system).zernike
        target = None
        if zarr_out:
            import zarr

            d = cfg.scan_step_px
            shape = (stack.shape[2] * d, stack.shape[3] * d)
            staged = StagedFolder(out, RESULT_FILES)  # complete, or not at all
            partial = staged.path / "image.zarr"
            target = zarr.open_array(str(partial), mode="w", shape=shape,
                                     chunks=(min(1024, shape[0]), min(1024, shape[1])),
                                     dtype="f4", fill_value=0.0)
        try:
            rec = reconstruct(stack, cfg, method=method, zernike=parse_zernike(zernike),
                              field_zernike=fz, blocks=parse_pair(blocks, "--blocks"),
                              overlap=overlap,
                              iterations=iterations, device=device, psf=bank, subsets=subsets,
                              scheduler=scheduler, progress=True, out=target, solver=solver,
                              register=register_views, view_radius=view_radius)
        except BaseException:
            if target is not None:
                staged.discard()
            raise
        if target is not None:
            from metasensor.io.views import description

            target.attrs.update(description(cfg, **image_meta(rec, origin)))
        else:
            staged = StagedFolder(out, RESULT_FILES)  # an earlier run's image.zarr goes
        if psf is not None:  # record the aberration the given bank was made with, if stored
            z = np.asarray(psf_attrs.get("zernike", ()), dtype=np.float64).ravel()
            if z.size and np.isfinite(z).all():
                rec.zernike = np.zeros(rec.zernike.shape[:2] + (z.size,), np.float32) + z
        from metasensor.io.provenance import provenance as _provenance

        prov = _provenance({"views": views, "psf": psf, "config": config, "system": system,
                            "field_zernike": field_zernike},
                           {"method": method, "blocks": blocks, "overlap": overlap,
                            "solver": solver, "iterations": iterations, "subsets": subsets,
                            "view_radius": view_radius, "zernike": zernike,
                            "config": cfg.to_dict()})
        written = [out / p.name for p in write_outputs(staged.path, rec, stack, origin,
                                                       provenance=prov)]
        staged.commit()
        if target is not None:
            import zarr

            rec.image = zarr.open_array(str(out / "image.zarr"), mode="r")
            written.insert(1, out / "image.zarr")
        if rec.registration_zernike is not None:
            applied = np.any(rec.registration_zernike != 0, axis=-1)
            worst = float(np.abs(rec.registration_zernike).max())
            typer.echo(f"registration: PSF banks moved in {int(applied.sum())} of {applied.size} "
                       f"block(s) (largest wavefront term {worst:.3f} λ; registration_px and "
                       "registration_zernike in summary.json)")
        typer.echo(f"reconstructed {rec.image.shape[0]}x{rec.image.shape[1]} px in "
                   f"{rec.seconds:.1f} s -> {', '.join(str(p) for p in written)}")
