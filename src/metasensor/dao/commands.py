"""Command line of the DAO stage: ``metasensor calibrate-aberration`` (register with
``metasensor.dao.commands.register(app)``)."""

from __future__ import annotations

from pathlib import Path

import typer

from metasensor.cli_options import parse_pair

__all__ = ["register"]


def register(app: typer.Typer) -> None:
    """Add the DAO stage's commands to ``app``."""

    @app.command("calibrate-aberration")
    def calibrate_aberration(
        capture: Path = typer.Argument(..., help="view stack (TIFF/Zarr) of a textured target"),
        out: Path | None = typer.Option(None, "--out", "-o", dir_okay=False,
                                        help="calibration file (HDF5; default: "
                                        "<CAPTURE stem>_system.h5 beside the capture)"),
        config: Path | None = typer.Option(None, "--config",
                                           help="system TOML (default: the capture's metadata)"),
        blocks: str = typer.Option("4x4", help="blocks whose centres get a wavefront, e.g. 4x4"),
        grid: str = typer.Option("15x20", help="registration control points (rows x cols)"),
        iterations: int = typer.Option(200, help="Adam steps per pyramid level"),
        threshold: float = typer.Option(0.5, help="pupil binarisation threshold in (0, 1) "
                                        "(the paper: 0.5-0.8 all work)"),
        figure: bool = typer.Option(True, help="also write <out>.png (wavefront map)"),
    ) -> None:
        """Global system-aberration calibration from a textured capture (e.g. a checkerboard).

        Registers every view to the centre view (smooth non-rigid), turns the disparities into
        a field-dependent wavefront map (Zernike 4-45 per block) and pupil amplitudes.

        Example: metasensor calibrate-aberration checker_views.tif --out system.h5 --blocks 4x4
        """
        from metasensor.config import SystemConfig
        from metasensor.dao.system_aberration import calibrate_system, plot_wavefront_map
        from metasensor.io.views import check_against_stored, read_config_from_views, read_views

        if not capture.exists():
            raise FileNotFoundError(f"capture not found: {capture}")
        if out is None:  # beside its input, like the other commands; never in the cwd
            out = capture.parent / f"{capture.stem}_system.h5"
        from metasensor.io.guard import guard

        guard([capture, config], [out, out.with_suffix(".png") if figure else None])
        if iterations < 1:
            raise ValueError(f"--iterations must be >= 1, got {iterations}")
        if not 0.0 < threshold < 1.0:
            raise ValueError(f"--threshold must lie in (0, 1), got {threshold}")
        stored = read_config_from_views(capture, strict=config is None)
        cfg = SystemConfig.from_toml(config) if config is not None else stored
        if config is not None and stored is not None:
            check_against_stored(cfg, stored, config, capture)
        if cfg is None:
            raise ValueError(f"{capture} carries no system configuration: pass --config")
        views = read_views(capture, nnum=cfg.nnum)
        if min(views.shape[2:]) < 4:  # named here, not as the registration's "movings"
            raise ValueError(f"{capture}: views of {tuple(views.shape[2:])} samples are too "
                             "small to calibrate (at least 4 x 4)")
        sa = calibrate_system(views, cfg, blocks=parse_pair(blocks, "--blocks"),
                              grid=parse_pair(grid, "--grid"), iterations=iterations,
                              threshold=threshold, progress=True)
        sa.save(out)
        typer.echo(f"wrote {out}")
        if figure:
            png = plot_wavefront_map(sa, out.with_suffix(".png"))
            typer.echo(f"wrote {png}")
