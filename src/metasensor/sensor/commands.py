"""Command-line commands of the sensor stage: ``calibrate`` and ``realign``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from metasensor.cli_options import SCAN_ORDER_HELP, SCAN_ORDER_NAMES


def _config(config: Path | None, scan: int | None, moving: str | None = None):
    from metasensor.config import SystemConfig

    cfg = SystemConfig.from_toml(config) if config is not None else SystemConfig()
    return _with(cfg, scan, moving)


def _with(cfg, scan: int | None, moving: str | None):
    """``cfg`` with the scan period and what moves given on the command line (validated
    together: a period that does not divide nnum needs moving = image)."""
    changes = {}
    if scan is not None and scan != cfg.scan:
        changes["scan"] = scan
    if moving is not None and moving != cfg.moving:
        if moving not in ("mla", "image"):
            raise ValueError(f"--moving must be mla or image, got {moving!r}")
        changes["moving"] = moving
    return cfg.replace(**changes) if changes else cfg


def _order(text: str | None, period: int):
    from metasensor.cli_options import parse_scan_order
    from metasensor.sensor.scan import check_scan_order

    return parse_scan_order(text, period) or check_scan_order(None, period)


def calibrate_cmd(
    white: Path = typer.Argument(..., help="white (flat-field) or textured raw frame(s), TIFF"),
    out: Path = typer.Option(..., "--out", "-o", dir_okay=False,
                             help="calibration file to write (.toml)"),
    config: Path | None = typer.Option(None, "--config", help="system configuration TOML"),
    scan: int | None = typer.Option(None, "--scan", help="scan period of a multi-page input"),
    order: str | None = typer.Option(None, *SCAN_ORDER_NAMES, help=SCAN_ORDER_HELP),
    moving: str | None = typer.Option(None, "--moving", help="what moves during the scan: "
                                      "mla|image (default: the config's moving, else mla)"),
    flat: bool = typer.Option(True, "--flat/--no-flat", help="also write the flat-field map"),
    figure: Path | None = typer.Option(None, "--figure", dir_okay=False,
                                       help="PNG: fitted grid over the frame, offsets against "
                                       "nominal"),
) -> None:
    """Calibrate the lenslet grid (pitch, rotation, centre, flat field, scan offsets).

    A one-page TIFF gives the grid; a TIFF with scan² pages (one scan period, in
    --scan-order) also gives each scan phase's actual offset, reported against nominal.
    Use a white frame where you can: a textured scene biases the fitted pitch (up to 0.6 % on
    a 192-px frame, 0.03 % on a 768-px one; a white one 0.01 %).

    Example: metasensor calibrate white.tif --out calib.toml
    """
    from metasensor.io.atomic import atomic_path
    from metasensor.io.raw import open_raw
    from metasensor.sensor.calibrate import calibrate, flat_field

    cfg = _config(config, scan, moving)
    moving = cfg.moving
    from metasensor.io.guard import guard

    flat_path = out.parent / out.with_suffix(".flat.tif").name if flat else None
    guard([white, config], [out, figure, flat_path])
    with open_raw(white) as raw:
        pages = len(raw)
        period = cfg.scan if scan is not None else (int(round(pages**0.5)) if pages > 1 else 1)
        phases = _order(order, period)
        if pages not in (1, period * period):
            raise ValueError(f"{white}: {pages} pages; expected 1 or one {period}x{period} scan "
                             f"period ({period * period})")
        frames = [raw[t] for t in range(pages)] if pages > 1 else None
        ref = frames[phases.index((0, 0))] if frames is not None else raw[0]
    calib = calibrate(ref, cfg.nnum, frames=frames, scan=period, scan_order=phases,
                      moving=moving)
    if flat:
        import tifffile

        flat_name = out.with_suffix(".flat.tif").name
        with atomic_path(out.parent / flat_name) as tmp:
            tifffile.imwrite(tmp, flat_field(ref, calib), metadata=None,
                             description="metasensor flat field (rectified, phase 0,0)")
        calib = calib.replace(flat=flat_name)
    calib.to_toml(out)
    if figure is not None:
        _calibration_figure(ref, calib, figure)
    typer.echo(f"pitch {calib.pitch:.4f} px, rotation {calib.rotation:+.4f} deg, centre "
               f"({calib.center[0]:.3f}, {calib.center[1]:.3f}) px, {calib.lenslets[0]}x"
               f"{calib.lenslets[1]} lenslets kept")
    if calib.offsets is not None:
        err = calib.offset_errors()
        typer.echo("scan-phase offsets, measured - nominal [px]: " + ", ".join(
            f"{ph}: ({e[0]:+.2f}, {e[1]:+.2f})" for ph, e in zip(calib.scan_order, err,
                                                                  strict=True)))
    typer.echo(f"-> {out}")


def realign_cmd(
    raw_path: Path = typer.Argument(..., metavar="RAW", help="raw frames, multi-page TIFF"),
    out: Path = typer.Option(..., "--out", "-o", help="view stack(s) to write (.tif or .zarr)"),
    calib_path: Path | None = typer.Option(None, "--calib", help="calibration TOML, or a "
                                           "napari-LF .lfc file (none: frames are already "
                                           "rectified)"),
    config: Path | None = typer.Option(None, "--config", help="system configuration TOML "
                                       "(default: the one stored in RAW's description, if any)"),
    scan: int | None = typer.Option(None, "--scan", help="scan period (default: config's)"),
    order: str | None = typer.Option(None, *SCAN_ORDER_NAMES,
                                     help=f"{SCAN_ORDER_HELP} (default: RAW's stored order, "
                                     "else row-major)"),
    moving: str | None = typer.Option(None, "--moving", help="what moves during the scan: "
                                      "mla|image (default: RAW's stored value, else the "
                                      "config's moving, else mla)"),
    offsets: str = typer.Option("measure", "--offsets", help="per-frame grid offsets: measure "
                                "(from each frame), calib (stored), nominal"),
    sliding: bool = typer.Option(False, "--sliding", help="one view stack per frame (a sliding "
                                 "window of one scan period) instead of one per period"),
    start_phase: int = typer.Option(0, "--start-phase", help="index in the order of frame 0"),
    method: str = typer.Option("lanczos", "--method", help="interpolator: lanczos|spline|cubic"),
    apply_flat: bool = typer.Option(False, "--flat", help="divide by the calibration's flat "
                                    "field"),
    dtype: str = typer.Option("float32", "--dtype", help="views: float32, or input (the raw "
                              "integer type, rectified views rounded back: half the memory; "
                              "--flat always gives float32)"),
) -> None:
    """Realign raw frames into view stacks (page u*nnum + v = view (u, v)).

    Frames are streamed from the TIFF, rectified with the calibration (each frame on
    its own measured grid offset) and realigned one scan period at a time (--sliding:
    one stack per frame). Several stacks are written as OUT_00000.tif, OUT_00001.tif...

    Example: metasensor realign raw.tif --calib calib.toml --scan 5 --out views.tif
    """
    from contextlib import ExitStack

    from tqdm import tqdm

    from metasensor.io.raw import open_raw
    from metasensor.sensor.realign import realign_sequence

    _check_realign_options(dtype, offsets, out)
    from metasensor.io.guard import guard

    guard([raw_path, config, calib_path], [out], lock=False)
    cfg, phases, moving = _stored_settings(raw_path, config, scan, order, moving)
    with open_raw(raw_path) as raw, ExitStack() as bars:  # the bar closes on any error
        calib = _read_calib(calib_path, cfg, raw.shape[1:])
        n_frames = len(raw)
        names = _stack_names(raw_path, out, n_frames, cfg.scan, len(phases), sliding)
        guard([raw_path, config, calib_path, _flat_input(calib, calib_path)], names,
              lock=[out])  # one lock for the family of numbered stacks
        if calib is None:
            _check_period(raw, cfg, config, raw_path)
        stream = bars.enter_context(tqdm(raw, total=n_frames, desc="realign", unit="frame"))
        if calib is None and moving == "mla":  # each frame's lattice phase against its place
            from metasensor.sensor.framephase import phase_checked

            stream = phase_checked(stream, cfg.nnum, cfg.scan, phases, start_phase)
        if calib is not None:
            calib, stream = _rectified(stream, raw, calib, cfg, phases, moving, offsets,
                                       start_phase, method, dtype)
        flat = _flat(calib, calib_path, cfg) if apply_flat else None
        # where the views' grid starts on the raw frames: sensor (row, col) of the first pixel
        # of view lenslet (0, 0) at phase (0, 0) (the calibration's kept grid, else pixel 0)
        origin = [0.0, 0.0] if calib is None else [round(v, 4) for v in calib.origin]
        meta = {"scan_order": [list(p) for p in phases], "moving": moving,
                "source": str(raw_path), "sliding": sliding, "origin": origin}
        written = _write_stacks(realign_sequence(stream, cfg, phases, moving, sliding=sliding,
                                                 start_phase=start_phase),
                                names, cfg, meta, flat, dtype, start_phase)
    typer.echo(f"-> {written[0]}" + (f" ... {written[-1]} ({len(written)} stacks)"
                                     if len(written) > 1 else ""))


def _stack_names(raw_path: Path, out: Path, n_frames: int, scan: int, tp: int,
                 sliding: bool) -> list[Path]:
    """The view stacks' paths (``OUT``, or ``OUT_00000`` ... for several), after checking that
    ``n_frames`` hold whole scan periods of ``tp`` frames (or at least one, ``sliding``)."""
    if n_frames < tp:
        raise ValueError(f"{raw_path}: {n_frames} frames but one {scan}x{scan} scan period "
                         f"needs {tp}")
    if not sliding and n_frames % tp:
        raise ValueError(f"{raw_path}: frame count {n_frames} is not a multiple of the "
                         f"{scan}x{scan} scan ({tp}); use --sliding for a window")
    n_out = n_frames - tp + 1 if sliding else n_frames // tp
    return [out] if n_out == 1 else [out.with_name(f"{out.stem}_{k:05d}{out.suffix}")
                                     for k in range(n_out)]


def _write_stacks(stacks, names, cfg, meta, flat, dtype, start_phase):
    """Write each realigned view stack to its name (flat-fielded, or float32 for
    ``dtype="float32"``), with the phases in the order its frames were taken; the paths."""
    from metasensor.io.views import write_views

    phases = [tuple(p) for p in meta["scan_order"]]
    tp = len(phases)
    written = []
    for k, views in enumerate(stacks):
        if flat is not None:
            views = np.where(flat > 0.05, views / np.maximum(flat, 0.05), 0).astype(np.float32)
        elif dtype == "float32" and views.dtype != np.float32:
            views = views.astype(np.float32)  # exact for raw data up to 24 bits
        # the phases in the order this stack's frames were taken (what motion correction
        # needs): window k starts at frame k (sliding) or k·T, i.e. at phase index
        # (start + k) % T or start % T of the scan order
        s = (start_phase + (k if meta["sliding"] else 0)) % tp
        taken = [list(q) for q in phases[s:] + phases[:s]]
        write_views(names[k], views, cfg, extra={**meta, "window": k, "scan_order": taken})
        written.append(names[k])
    return written


def _check_realign_options(dtype: str, offsets: str, out: Path) -> None:
    """One-line errors for ``realign``'s choice options and output suffix."""
    if dtype not in ("float32", "input"):
        raise ValueError(f"--dtype must be float32 or input, got {dtype!r}")
    if offsets not in ("measure", "calib", "nominal"):
        raise ValueError(f"--offsets must be measure, calib or nominal, got {offsets!r}")
    if out.suffix.lower() not in (".tif", ".tiff", ".zarr"):
        raise ValueError(f"--out must end in .tif, .tiff or .zarr: {out}")


def _rectified(stream, raw, calib, cfg, phases, moving, offsets, start_phase, method, dtype):
    """(calibration adapted to the scan, the frames rectified one by one) for ``realign``:
    each frame on its own measured grid offset (``offsets="measure"``, a moving MLA), the
    stored ones (``"calib"``) or the nominal ones; rounded back to the raw integer type for
    ``dtype="input"``."""
    from metasensor.sensor.rectify import check_fits, rectify_frames
    from metasensor.sensor.reuse import adapt

    check_fits(calib, raw.shape[1:], cfg.nnum)
    calib = adapt(calib, cfg.scan, phases, moving)
    off = offsets if offsets != "calib" else None
    if offsets == "measure" and moving == "mla":
        from metasensor.sensor.reuse import checked_offsets

        off = checked_offsets(calib, start_phase)
    elif offsets == "measure":
        off = "nominal"
    stream = rectify_frames(stream, calib, phases, offsets=off, start_phase=start_phase,
                            method=method)
    if dtype == "input" and raw.dtype.kind in "ui":
        stream = _round_to(stream, raw.dtype)
    return calib, stream


def _stored_settings(raw_path: Path, config, scan, order, moving):
    """(config, scan order, moving) for ``realign``: the options given, else what ``simulate``
    (or another writer of this package) stored in the raw frames' description, else defaults."""
    from metasensor.io.views import check_against_stored, read_config_from_views, stored_extras
    from metasensor.sensor.scan import check_scan_order

    stored = read_config_from_views(raw_path, strict=config is None) if raw_path.is_file() \
        else None
    extra = stored_extras(raw_path) if raw_path.is_file() else {}
    if moving is None and extra.get("moving") in ("mla", "image"):
        moving = extra["moving"]
    if config is None and stored is not None:
        cfg = _with(stored, scan, moving)
    else:
        cfg = _config(config, scan, moving)
    if stored is not None and (config is not None or scan is not None):
        # frames taken with one scan cannot be realigned as another
        check_against_stored(cfg, stored, config if config is not None else "--scan", raw_path)
    used = []
    if config is None and stored is not None:
        used.append("configuration")
    phases = None
    if order is None and isinstance(extra.get("scan_order"), list):
        try:
            phases = check_scan_order([tuple(p) for p in extra["scan_order"]], cfg.scan)
            used.append("scan order")
        except (TypeError, ValueError):
            phases = None  # stored for another period: the default applies
    if phases is None:
        phases = _order(order, cfg.scan)
    if "moving" in extra and moving == extra["moving"]:
        used.append("moving")
    moving = cfg.moving
    if used:
        typer.echo(f"using the {', '.join(used)} stored in {raw_path.name}")
    return cfg, phases, moving


def _read_calib(path: Path | None, cfg, sensor_shape):
    """The calibration of ``--calib``: this package's TOML, or a napari-LF ``.lfc`` file."""
    from metasensor.sensor.calibration import Calibration

    if path is None:
        return None
    if path.suffix.lower() == ".lfc":
        from metasensor.sensor.lfc import read_lfc

        return read_lfc(path, nnum=cfg.nnum, sensor_shape=tuple(sensor_shape))
    return Calibration.from_toml(path)


def _check_period(raw, cfg, config, raw_path: Path) -> None:
    """Without a calibration the frames must be rectified with the configured nnum: a measured
    lenslet period that contradicts it (:func:`metasensor.sensor.checks.period_mismatch`) is
    refused, or realignment would silently scramble the views."""
    from metasensor.sensor.checks import period_mismatch

    got = period_mismatch(raw, cfg.nnum)
    if got is not None:
        source = config if config is not None else "the default configuration"
        raise ValueError(f"{raw_path}: the frames' lenslet period measures {got:.2f} px but "
                         f"nnum is {cfg.nnum} ({source}); set nnum = {round(got)} in --config "
                         "if the lenslets are that size, or give --calib for a grid to rectify")


def _round_to(frames, dtype):
    info = np.iinfo(dtype)
    for frame in frames:
        yield np.clip(np.rint(frame), info.min, info.max).astype(dtype)


def _calibration_figure(frame: np.ndarray, calib, path: Path) -> None:
    """Fitted lenslet centres over a central crop of the frame; measured - nominal offsets."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from metasensor.io.atomic import atomic_path

    n = calib.nnum
    a = calib.matrix * n
    ii, jj = np.meshgrid(np.arange(calib.lenslets[0]), np.arange(calib.lenslets[1]),
                         indexing="ij")
    pts = np.asarray(calib.center)[:, None] + a @ np.stack([ii.ravel(), jj.ravel()])
    cy, cx = (np.array(frame.shape) // 2).tolist()
    half = 4 * n
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6))
    axes[0].imshow(frame[cy - half:cy + half, cx - half:cx + half], cmap="gray",
                   extent=(cx - half - 0.5, cx + half - 0.5, cy + half - 0.5, cy - half - 0.5))
    sel = (np.abs(pts[0] - cy) < half) & (np.abs(pts[1] - cx) < half)
    axes[0].plot(pts[1, sel], pts[0, sel], "r+", ms=8)
    axes[0].set_title(f"pitch {calib.pitch:.4f} px, rotation {calib.rotation:+.4f} deg")
    err = calib.offset_errors()
    phases = np.array(calib.scan_order)
    peak = float(np.abs(err).max())
    q = axes[1].quiver(phases[:, 1], phases[:, 0], err[:, 1], err[:, 0], angles="xy",
                       scale_units="xy", scale=max(1e-3, 2 * peak))
    key = float(f"{max(peak, 1e-3):.1g}")  # arrows are magnified: the key gives their length
    axes[1].quiverkey(q, 0.02, -0.12, key, f"{key:g} px", labelpos="E", coordinates="axes")
    axes[0].set_xlabel("sensor column (px)")
    axes[0].set_ylabel("sensor row (px)")
    axes[1].set_xlim(-0.5, calib.scan - 0.5)
    axes[1].set_ylim(calib.scan - 0.5, -0.5)
    axes[1].set_title("scan-phase offset, measured - nominal (max "
                      f"{np.abs(err).max():.3f} px)")
    axes[1].set_xlabel("phase column")
    axes[1].set_ylabel("phase row")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def _flat_input(calib, calib_path):
    """The flat-field map a calibration names (an input of realign --flat), or None."""
    return calib.flat_path(calib_path) if calib is not None and calib.flat else None


def _flat(calib, calib_path, cfg):
    from metasensor.io.tiff import read_tiff
    from metasensor.sensor.rectify import flat_views

    if calib is None or calib.flat is None:
        raise ValueError("--flat needs a calibration with a flat-field map (--calib)")
    path = calib.flat_path(calib_path)
    if not path.is_file():
        raise FileNotFoundError(f"flat-field map not found: {path}")
    flat = read_tiff(path)  # damaged or oversized: one line naming it, before decoding
    if flat.ndim != 2 or flat.dtype.kind not in "buif":
        raise ValueError(f"flat-field map {path} must be one 2-D image of real numbers, got "
                         f"{flat.dtype} {flat.shape}")
    n = cfg.nnum
    (i0, j0), (ly, lx) = calib.flat_origin, calib.lenslets
    if i0 < 0 or j0 < 0 or (i0 + ly) * n > flat.shape[0] or (j0 + lx) * n > flat.shape[1]:
        raise ValueError(f"flat-field map {path} does not cover the lenslets kept for this scan")
    return flat_views(flat[i0 * n:(i0 + ly) * n, j0 * n:(j0 + lx) * n], n, cfg.scan)


def register(app: typer.Typer) -> None:
    """Add this stage's commands to app."""
    app.command("calibrate")(calibrate_cmd)
    app.command("realign")(realign_cmd)
