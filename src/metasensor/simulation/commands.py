"""Command-line commands of the simulate stage (registered on the main app by metasensor.cli)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from metasensor.cli_options import SCAN_ORDER_HELP, SCAN_ORDER_NAMES, parse_scan_order
from metasensor.optics.psf_io import parse_zernike


def write_capture(cap, out: Path, figure: bool = True, clean: bool = False) -> list[Path]:
    """Write a :class:`Capture` into folder ``out`` (atomically, file by file)."""
    import numpy as np
    import tifffile

    from metasensor.io.atomic import atomic_path, atomic_write_text
    from metasensor.io.views import description, write_views

    out.mkdir(parents=True, exist_ok=True)
    cfg = cap.config
    meta = {"scan_order": [list(p) for p in cap.scan_order], "moving": "mla", "scale": cap.scale,
            "gain": cap.noise.gain, "photons": cap.noise.photons,
            "read_noise": cap.noise.read_noise, "bit_depth": cap.noise.bit_depth,
            "snr_db": None if not np.isfinite(cap.snr_db) else cap.snr_db,
            "offset": cap.offset, "units": "DN"}
    written = []

    def tif(name, arr, extra=None):
        path = out / name
        desc = description(cfg, kind=name.split(".")[0], **meta, **(extra or {}))
        with atomic_path(path) as tmp:
            tifffile.imwrite(tmp, arr, description=json.dumps(desc), metadata=None,
                             bigtiff=arr.nbytes > 2**31)
        written.append(path)

    tif("frames.tif", cap.frames)
    written.append(write_views(out / "views.tif", cap.views.astype(np.uint16), cfg, meta))
    if clean:
        written.append(write_views(out / "views_clean.tif", cap.views_clean, cfg, meta))
    tif("truth.tif", cap.truth)
    if cap.sensor2d is not None:
        tif("sensor2d.tif", cap.sensor2d)
        tif("hardware_ao.tif", cap.hardware_ao)
    wf = {"noll": "z[j-1] is Noll index j, waves r.m.s.",
          "zernike": None if cap.zernike is None else np.asarray(cap.zernike).tolist(),
          "field_zernike": None if cap.field_zernike is None else cap.field_zernike.tolist(),
          "ao_residual_rms": cap.ao_residual_rms}
    written.append(atomic_write_text(out / "wavefront.json", json.dumps(wf, indent=1)))
    arr = cap.zernike
    if arr is not None:
        with atomic_path(out / "wavefront.npy") as tmp:
            np.save(tmp, np.asarray(arr))
        written.append(out / "wavefront.npy")
    if cap.phase_screens is not None:
        with atomic_path(out / "phase_screens.npy") as tmp:
            np.save(tmp, cap.phase_screens)
        written.append(out / "phase_screens.npy")
    written.append(cfg.to_toml(out / "config.toml"))
    written.append(atomic_write_text(out / "capture.json", json.dumps(meta, indent=1)))
    if figure:
        written.append(capture_figure(cap, out / "figure.png"))
    # a capture written over an earlier one: that run's files this one did not write would
    # contradict it (e.g. an old wavefront.npy beside a new aberration-free wavefront.json)
    for name in CAPTURE_FILES:
        if out / name not in written and (out / name).is_file():
            (out / name).unlink()
    return written


CAPTURE_FILES = ("frames.tif", "views.tif", "views_clean.tif", "truth.tif", "sensor2d.tif",
                 "hardware_ao.tif", "wavefront.json", "wavefront.npy", "phase_screens.npy",
                 "config.toml", "capture.json", "figure.png")


def capture_figure(cap, path: Path) -> Path:
    """2D sensor vs centre view (nearest-upsampled to the truth grid) vs truth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from metasensor.io.atomic import atomic_path

    d = cap.config.scan_step_px
    centre = np.kron(cap.centre_view, np.ones((d, d)))[:cap.truth.shape[0], :cap.truth.shape[1]]
    panels = [("2D sensor", cap.sensor2d), (f"centre view (x{d} nearest)", centre),
              ("truth", cap.truth)]
    panels = [p for p in panels if p[1] is not None]
    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 5.4))
    for ax, (title, img) in zip(np.atleast_1d(axes), panels, strict=True):
        ax.imshow(img, cmap="gray", vmin=0, vmax=float(np.percentile(cap.truth, 99.5)) or 1)
        ax.set_title(title)
        ax.axis("off")
    fig.suptitle(f"scan {cap.config.scan}x{cap.config.scan}, SNR {cap.snr_db:.1f} dB")
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)
    return path


def register(app: typer.Typer) -> None:
    """Add this stage's commands to app."""

    @app.command("simulate")
    def simulate_cmd(
        out: Path = typer.Option(..., "--out", "-o", file_okay=False, help="output folder"),
        scene: str = typer.Option("chart", help="built-in scene name or an image file"),
        size: int = typer.Option(512, help="scene size in pixels (square)"),
        config: Path = typer.Option(None, help="system configuration TOML (default: prototype)"),
        rms: float = typer.Option(0.0, help="random aberration, waves r.m.s. (Noll 4-45)"),
        zernike: str = typer.Option("", help="explicit Noll coefficients, e.g. '4:0.5,7:-0.2', "
                                    "or a .npy Noll vector"),
        lens: bool = typer.Option(False, help="field-dependent single-lens (f=135 mm f/10)"),
        scan: int = typer.Option(None, help="scan period (default: the config's)"),
        order: str = typer.Option("row-major", *SCAN_ORDER_NAMES, help=SCAN_ORDER_HELP),
        snr: float = typer.Option(None, help="target SNR of the views in dB (default: no noise)"),
        photons: float = typer.Option(None, help="photo-electrons at full scale (or --snr)"),
        read_noise: float = typer.Option(2.0, help="read noise, electrons r.m.s."),
        bits: int = typer.Option(None, help="ADC bits (8, 10, 12, 14 or 16; default: config)"),
        seed: int = typer.Option(0, help="random seed (aberration and noise)"),
        clean: bool = typer.Option(False, help="also write the noise-free views"),
        device: str = typer.Option(None, help="torch device (default: CUDA if present)"),
    ) -> None:
        """Simulate a raw meta-imaging capture with known truth and comparison sensors.

        Example: metasensor simulate --scene chart --size 1024 --rms 1.0 --scan 5 --snr 30
        --out cap/
        """
        import numpy as np

        from metasensor.config import SystemConfig
        from metasensor.io.atomic import StagedFolder
        from metasensor.io.guard import guard, npy_argument
        from metasensor.simulation.capture import simulate
        from metasensor.simulation.lens import SingleLens
        from metasensor.simulation.scenes import load_scene

        # the capture files written (or removed as stale) must not be what this run reads
        guard([Path(scene), config, npy_argument(zernike)],
              [out / name for name in CAPTURE_FILES], folders=[out])
        cfg = SystemConfig.from_toml(config) if config is not None else SystemConfig()
        if size < 8:
            raise ValueError(f"--size must be at least 8, got {size}")
        img = load_scene(scene, size)
        z = parse_zernike(zernike)
        if rms:
            if rms < 0:
                raise ValueError(f"--rms must be >= 0, got {rms}")
            from metasensor.optics.zernike import random_zernike
            from metasensor.simulation.layers import add_zernike

            z = add_zernike(z, np.asarray(random_zernike(rms, seed=seed), dtype=np.float64))
        field = None
        if lens:
            single = SingleLens()
            cfg = single.config(cfg)
            field = single.field_zernike(cfg, img.shape)
        order = parse_scan_order(order, scan, default_period=cfg.scan)
        cap = simulate(img, cfg, zernike=z, field_zernike=field, scan=scan, scan_order=order,
                       snr_db=snr, seed=seed, photons=photons, read_noise=read_noise,
                       bit_depth=bits, device=device, progress=True)
        typer.echo(f"writing the capture to {out} ...", err=True)
        staged = StagedFolder(out, CAPTURE_FILES)  # the folder appears complete, or not at all
        files = write_capture(cap, staged.path, clean=clean)
        staged.commit()
        typer.echo(f"wrote {len(files)} files to {out} (SNR {cap.snr_db:.2f} dB, "
                   f"views {cap.views.shape}, frames {cap.frames.shape})")
