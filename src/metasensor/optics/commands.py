"""Command-line commands of the optics stage (registered on the main app by metasensor.cli)."""

from __future__ import annotations

from pathlib import Path

import typer


def register(app: typer.Typer) -> None:
    """Add this stage's commands to app."""

    @app.command("psf")
    def psf_command(
        config: Path | None = typer.Option(None, "--config", help="system configuration (TOML; "
                                           "default: the prototype)"),
        out: Path = typer.Option(..., "--out", "-o", dir_okay=False,
                                 help="output HDF5 file (dataset 'psf', axes u, v, y, x)"),
        zernike: str = typer.Option("", "--zernike",
                                    help="Noll index:waves pairs, e.g. '4:0.5,7:-0.2', or a .npy "
                                         "Noll vector"),
        depth: float = typer.Option(0.0, "--depth", help="defocus on the image side, metres"),
        subsample: int = typer.Option(1, "--subsample", help="point positions per pixel (1, 3)"),
        size: int = typer.Option(0, "--size", help="PSF window K in pixels (odd; 0 = auto)"),
        png: Path = typer.Option(None, "--png", dir_okay=False,
                                 help="figure path (default: OUT with .png)"),
        device: str = typer.Option(None, "--device", help="torch device (default: auto)"),
    ) -> None:
        """Compute the phase-space PSF bank of every view and write it to HDF5 plus a figure.

        Example: metasensor psf --config cfg.toml --zernike "4:0.5,7:-0.2" --out psf.h5
        """
        from metasensor.config import SystemConfig
        from metasensor.io.guard import guard, npy_argument
        from metasensor.optics.psf import view_psfs
        from metasensor.optics.psf_io import parse_zernike, plot_views, save_psf

        guard([config, npy_argument(zernike)], [out, png or out.with_suffix(".png")])
        cfg = SystemConfig.from_toml(config) if config is not None else SystemConfig()
        z = parse_zernike(zernike)
        if out.suffix.lower() not in (".h5", ".hdf5"):
            raise ValueError(f"--out must end in .h5 or .hdf5, got {out.name!r}")
        bank = view_psfs(cfg, z, depth, subsample=subsample, size=size or None, device=device)
        save_psf(out, bank, cfg, zernike=z, depth=depth, subsample=subsample)
        fig = plot_views(bank, cfg, png or out.with_suffix(".png"), subsample=subsample)
        typer.echo(f"wrote {out} {tuple(bank.shape)} and {fig}")
