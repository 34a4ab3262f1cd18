"""Command-line commands of the depth stage (registered on the main app by metasensor.cli)."""

from __future__ import annotations

from pathlib import Path

import typer


def _parse_range(text: str | None) -> tuple[float, float] | None:
    if text is None:
        return None
    try:
        lo, hi = (float(p) for p in text.replace(":", ",").split(","))
    except ValueError:
        raise ValueError(
            f"--range must be 'LO,HI' in view px per view step, got {text!r}"
        ) from None
    return lo, hi


OUTPUT_FILES = (("disparity", "tif"), ("confidence", "tif"), ("image_depth", "tif"),
                ("object_distance", "tif"), ("depth", "png"), ("depth", "json"))


def run_depth(views: Path, out: Path, system: Path | None = None, config: Path | None = None,
              candidates: int = 64, disparity_range: str | None = None, occlusion: bool = True,
              radius: int = 4, device: str | None = None, progress: bool = True) -> dict:
    """Read a view stack, estimate depth, write TIFF maps and a figure into ``out``."""
    import json

    import numpy as np
    import tifffile

    from metasensor.config import SystemConfig
    from metasensor.depth.estimate import estimate_depth
    from metasensor.depth.figure import depth_figure
    from metasensor.io.atomic import StagedFolder, atomic_path, atomic_write_text
    from metasensor.io.guard import guard
    from metasensor.io.views import check_against_stored, read_config_from_views, read_views

    views = Path(views)
    if not views.exists():
        raise FileNotFoundError(f"view stack not found: {views}")
    out = Path(out)
    names = [f"{n}.{ext}" for n, ext in OUTPUT_FILES]
    guard([views, system, config], [out / n for n in names], folders=[out])
    if config is not None:
        cfg = SystemConfig.from_toml(config)
        stored = read_config_from_views(views, strict=False)
        if stored is not None:
            check_against_stored(cfg, stored, Path(config), views)
    else:
        cfg = read_config_from_views(views)
        if cfg is None:
            raise ValueError(f"{views} carries no system configuration: pass --config cfg.toml")
    stack = np.asarray(read_views(views, nnum=cfg.nnum))
    if system is not None and not Path(system).exists():
        raise FileNotFoundError(f"system calibration not found: {system}")
    res = estimate_depth(stack, cfg, calibration=system, candidates=candidates,
                         disparity_range=_parse_range(disparity_range), occlusion=occlusion,
                         radius=radius, device=device, progress=progress)
    if progress:
        typer.echo(f"writing the depth maps and figure to {out} ...", err=True)
    staged = StagedFolder(out, names)  # the folder appears complete, or not at all
    maps = {"disparity": res.disparity, "confidence": res.confidence,
            "image_depth": res.image_depth}
    if res.object_distance is not None:
        maps["object_distance"] = res.object_distance
    units = {"disparity": "view px per view step", "confidence": "1",
             "image_depth": "m in front of the MLA", "object_distance": "m from the main lens"}
    written = {}
    for name, arr in maps.items():
        path = out / f"{name}.tif"
        with atomic_path(staged.path / path.name) as tmp:
            tifffile.imwrite(tmp, np.asarray(arr, dtype=np.float32),
                             description=json.dumps({"metasensor": {"kind": name,
                                                                    "unit": units[name]}}),
                             metadata=None)
        written[name] = str(path)
    c = cfg.center
    depth_figure(res, stack[c, c], staged.path / "depth.png")
    written["figure"] = str(out / "depth.png")
    summary = {"views": str(views), "shape": list(res.disparity.shape),
               "depth_kind": res.depth_kind, "candidates": [float(res.candidates[0]),
                                                            float(res.candidates[-1]),
                                                            len(res.candidates)],
               "median_disparity": float(np.median(res.disparity)),
               "disparity_p5_p95": [float(v) for v in np.percentile(res.disparity, [5, 95])],
               "mean_confidence": float(res.confidence.mean()),
               "views_used": int(res.views_used.sum()), "files": written}
    atomic_write_text(staged.path / "depth.json", json.dumps(summary, indent=2))
    staged.commit()
    return summary


def register(app: typer.Typer) -> None:
    """Add this stage's commands to app."""

    @app.command("depth")
    def depth(
        views: Path = typer.Argument(..., help="view stack (.tif pages u*nnum+v, or .zarr)"),
        out: Path = typer.Option(..., "--out", "-o", file_okay=False, help="output folder"),
        system: Path | None = typer.Option(None, "--system",
                                           help="system-aberration calibration (system.h5)"),
        config: Path | None = typer.Option(None, "--config",
                                           help="system TOML (default: from the views' metadata)"),
        candidates: int = typer.Option(64, "--candidates", help="number of disparity candidates"),
        disparity_range: str | None = typer.Option(
            None, "--range", help="disparity search range 'LO,HI' in view px per view step "
                                  "(default: measured from the views, widened where the "
                                  "estimate reaches an end)"),
        occlusion: bool = typer.Option(True, "--occlusion/--no-occlusion",
                                       help="half-pupil occlusion handling"),
        radius: int = typer.Option(4, "--radius", help="cost aggregation radius [view px]"),
        device: str | None = typer.Option(None, "--device", help="cpu, cuda (default: auto)"),
    ) -> None:
        """Disparity, depth and confidence maps (TIFF) and a figure from a view stack.

        Example: metasensor depth views.tif --config cfg.toml --out depth/
        (add --system system.h5 to remove the system aberration's shifts first).
        Writes disparity.tif (view px per view step), image_depth.tif (m, image side),
        object_distance.tif (m, with focal_length/focus_distance in the config),
        confidence.tif, depth.png and depth.json.
        """
        summary = run_depth(views, out, system=system, config=config, candidates=candidates,
                            disparity_range=disparity_range, occlusion=occlusion, radius=radius,
                            device=device)
        lo, hi = summary["disparity_p5_p95"]
        typer.echo(f"disparity median {summary['median_disparity']:+.3f} (5-95 %: {lo:+.3f} .. "
                   f"{hi:+.3f}) view px per view step, mean confidence "
                   f"{summary['mean_confidence']:.2f}; {summary['depth_kind']} depth maps and "
                   f"figure written to {out}")
