"""Scenario ``gigapixel`` (Extended Data Fig. 7 of the paper): one lens, the sensor moved
laterally to a grid of positions with small overlaps, every capture reconstructed with the
aberration of its position in the lens's field, the tiles registered and blended.

The lens is the single plastic lens of the demo (:class:`~metasensor.simulation.lens.SingleLens`)
whose field aberration is given once, in the lens's field coordinates (the mosaic's normalised
coordinates: one system calibration, not per tile); every tile's reconstruction evaluates it at
the tile's commanded position (:meth:`~metasensor.mosaic.layout.MosaicLayout.tile_field_zernike`).
The sensor lands at the commanded position plus a seeded sub-pixel error (up to ``jitter``
pixels), which the stitcher does not know: the tiles are registered on their overlaps
(:mod:`metasensor.mosaic.register`), compared with the true positions, and blended into an
OME-Zarr pyramid (:mod:`metasensor.mosaic.blend`), the meta-imaging sensor's tiles and the 2D
sensor's alike. The scene is a scikit-image photograph resized to cover the mosaic.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metasensor.scenarios.report import ScenarioSettings

__all__ = ["GigapixelSettings", "run_gigapixel"]


@dataclass(frozen=True)
class GigapixelSettings(ScenarioSettings):
    """:class:`~metasensor.scenarios.report.ScenarioSettings` (``blocks``: per tile; ``seed``:
    positions and noise) and tile : sensor side of one capture (pixels); grid : (rows, columns)
    of positions; overlap : nominal overlap of the reconstructed tiles (pixels); jitter : largest
    sensor positioning error (pixels, per axis); field_px : the lens's field over the mosaic in
    prototype-sensor pixels (stretches the aberrations of a whole field over a small mosaic, as
    the demo); chunk : output chunk side; scheduler : Dask scheduler (None: local threads; an
    address: a cluster); scene : the built-in natural image; space_variant : reconstruct every
    tile with the space-variant model (PSF banks at its blocks' corners blended inside the
    operator, :class:`~metasensor.recon.options.ReconOptions` ``space_variant``; default solver
    only), as the single-lens demo; False: one bank per block; sim_blocks : (rows, columns) of
    field points per tile at which the simulator computes the lens's PSF banks (blended
    bilinearly between them), finer than the reconstruction's banks (no inverse crime)."""

    tile: int = 162
    grid: tuple[int, int] = (2, 2)
    overlap: int = 40
    jitter: float = 1.5
    field_px: int = 6004
    chunk: int = 128
    scheduler: str | None = None
    scene: str = "astronaut"
    space_variant: bool = True
    sim_blocks: tuple[int, int] = (4, 4)

    def __post_init__(self) -> None:
        sb = self.sim_blocks
        if not (isinstance(sb, tuple) and len(sb) == 2
                and all(isinstance(v, int) and 1 <= v <= 16 for v in sb)):
            raise ValueError(f"sim_blocks must be two integers in [1, 16], got {sb!r}")
        if not isinstance(self.space_variant, bool):
            raise TypeError(f"space_variant must be True or False, got {self.space_variant!r}")
        if not (isinstance(self.tile, int) and self.tile >= 96):
            raise ValueError(f"tile must be an integer >= 96, got {self.tile!r}")
        if not 0 <= self.jitter < self.overlap / 4:
            raise ValueError(f"jitter must lie in [0, overlap / 4), got {self.jitter!r}")


def _scene(name: str, shape: tuple[int, int]) -> np.ndarray:
    from metasensor.simulation.scenes import load_scene

    return load_scene(name, shape=shape).astype(np.float64)


def _sample(big: np.ndarray, origin: tuple[float, float], shape: tuple[int, int]) -> np.ndarray:
    from scipy import ndimage

    yy, xx = np.meshgrid(origin[0] + np.arange(shape[0]), origin[1] + np.arange(shape[1]),
                         indexing="ij")
    out = ndimage.map_coordinates(big, [yy, xx], order=3, mode="nearest")
    return np.clip(out, 0.0, None).astype(np.float32)  # cubic overshoot: radiance >= 0


def _write_tile(path: Path, image: np.ndarray) -> str:
    from metasensor.io.interrupt import quiet_zarr

    zarr = quiet_zarr()  # Ctrl-C reaches the main thread

    z = zarr.open_array(str(path), mode="w", shape=image.shape, chunks=(128, 128),
                        dtype="f4", zarr_format=2)
    z[:] = image
    return str(path)


def _capture_tiles(out: Path, s: GigapixelSettings, layout, lens, cfg, big, margin, steps,
                   cpu: dict):
    """Simulate, realign and reconstruct every tile; write the meta-imaging and 2D tiles.
    ``cpu``: CPU seconds (all threads) added per stage, the PSF banks computed (cache misses)
    apart from the rest.

    Returns (true positions, meta tile paths, 2D tile paths, the photon scale)."""
    import metasensor as ms
    from metasensor.optics.cache import stats
    from metasensor.recon.parallel import local_workers

    o = cfg.field_offset_px
    fz_lens = lens.field_zernike(cfg, (s.field_px, s.field_px))
    rng = np.random.default_rng(s.seed)
    true_pos, meta_paths, s2d_paths, scale = {}, {}, {}, None
    for k in layout.indices:
        oy, ox = layout.origin(k)
        err = (0.0, 0.0) if k == (0, 0) else tuple(rng.uniform(-s.jitter, s.jitter, 2))
        true_pos[k] = (oy + err[0], ox + err[1])
        # the sensor's pixel (0, 0) sits o pixels before the tile image's (0, 0)
        scene = _sample(big, (margin + true_pos[k][0] - o, margin + true_pos[k][1] - o),
                        (s.tile, s.tile))
        fz_sim = layout.tile_field_zernike(fz_lens, k, (s.tile, s.tile),
                                           offset=(err[0] - o, err[1] - o))
        c0, b0 = time.process_time(), stats["compute_seconds"]
        cap = ms.simulate(scene, cfg, field_zernike=fz_sim, snr_db=s.snr_db,
                          seed=s.seed + 1 + layout.indices.index(k), field_blocks=s.sim_blocks,
                          scale=scale, comparison="2d")
        c1, b1 = time.process_time(), stats["compute_seconds"]
        scale = cap.scale
        views = ms.realign(cap.frames, cap.config, cap.scan_order)
        rec = ms.reconstruct(views, cap.config, blocks=s.blocks, iterations=s.iterations,
                             field_zernike=layout.tile_field_zernike(fz_lens, k),
                             space_variant=s.space_variant and s.iterations is None,
                             num_workers=local_workers(s.blocks[0] * s.blocks[1]))
        c2, b2 = time.process_time(), stats["compute_seconds"]
        for name, value in (("simulation PSF banks", b1 - b0),
                            ("simulation, rest", c1 - c0 - (b1 - b0)),
                            ("reconstruction PSF banks", b2 - b1),
                            ("reconstruction, rest", c2 - c1 - (b2 - b1))):
            cpu[name] = cpu.get(name, 0.0) + value
        meta_paths[k] = _write_tile(out / "tiles" / f"meta_{k[0]}_{k[1]}.zarr",
                                    np.asarray(rec.image))
        s2d_paths[k] = _write_tile(out / "tiles" / f"sensor2d_{k[0]}_{k[1]}.zarr", cap.sensor2d)
        steps.update()
    return true_pos, meta_paths, s2d_paths, scale


def _rows(truth, images, pos, grid, jitter, box):
    """PSNR and seam statistics of each mosaic against the truth (a rim of ``jitter`` + 2 px
    left out); ``box``: the covered rectangle the mosaics were blended on."""
    from metasensor.metrics import psnr
    from metasensor.mosaic.seams import seam_ratio

    c = int(np.ceil(jitter)) + 2
    crop = (slice(c, -c), slice(c, -c))
    rngd = float(truth.max() - truth.min())
    ys = [int(round(pos[(i, 0)][0])) - box[0] - c for i in range(1, grid[0])]
    xs = [int(round(pos[(0, j)][1])) - box[1] - c for j in range(1, grid[1])]
    return [{"sensor": name, "psnr_db": psnr(truth=truth[crop], image=img[crop], data_range=rngd),
             "seam_ratio": seam_ratio(img[crop], ys, xs),
             "truth_seam_ratio": seam_ratio(truth[crop], ys, xs)} for name, img in images]


def run_gigapixel(out: str | Path, settings: GigapixelSettings | None = None,
                  progress: bool = True) -> dict:
    """Run the scenario and write its report into ``out``; returns the summary.

    The mosaics are blended on the rectangle that the registered tiles cover
    (:meth:`~metasensor.mosaic.layout.MosaicLayout.covered`), so no uncovered rim shows."""
    import metasensor as ms
    from metasensor.mosaic import MosaicLayout, open_mosaic, register_tiles, solve_positions
    from metasensor.scenarios.report import scenario_run
    from metasensor.sensor.realign import lenslet_counts
    from metasensor.simulation.lens import SingleLens

    s = settings or GigapixelSettings()
    lens = SingleLens()
    cfg = lens.config(ms.SystemConfig())
    ly, lx = lenslet_counts((s.tile, s.tile), cfg)
    layout = MosaicLayout((ly * cfg.nnum, lx * cfg.nnum), s.grid, s.overlap)
    with scenario_run(out, "gigapixel", len(layout.indices) + 2, progress) as run:
        out, steps = run.out, run.steps
        (out / "tiles").mkdir(exist_ok=True)
        margin = cfg.field_offset_px + int(np.ceil(s.jitter)) + 4
        big = _scene(s.scene, (layout.shape[0] + 2 * margin + s.tile,
                               layout.shape[1] + 2 * margin + s.tile))
        from metasensor.optics.cache import kind_stats

        cpu: dict[str, float] = {}
        psf0 = {k: dict(v) for k, v in kind_stats.items()}
        true_pos, meta_paths, s2d_paths, scale = _capture_tiles(out, s, layout, lens, cfg, big,
                                                                margin, steps, cpu)
        c0 = time.process_time()
        tiles = {k: open_mosaic_array(p) for k, p in meta_paths.items()}
        pairs = register_tiles(tiles, layout)
        pos = solve_positions(pairs, layout)
        cpu["registration"] = time.process_time() - c0
        reg_err = max(float(np.hypot(pos[k][0] - true_pos[k][0], pos[k][1] - true_pos[k][1]))
                      for k in layout.indices)
        box = layout.covered(pos)
        shape = (box[2] - box[0], box[3] - box[1])
        t_blend = time.perf_counter()
        mosaics = _blended(out, s, cfg, pos, box, meta_paths, s2d_paths)
        t_blend = time.perf_counter() - t_blend
        cpu["blending"] = time.process_time() - c0 - cpu["registration"]
        steps.update()
        img_meta, img_2d = (open_mosaic(m)[:] for m in mosaics)
        truth = _sample(big, (margin + box[0], margin + box[1]), shape) * np.float32(scale)
        rows = _rows(truth, (("2D sensor", img_2d), ("meta-imaging", img_meta)), pos, s.grid,
                     s.jitter, box)
        figs = {"mosaic": _figure(out / "mosaic.png", s, truth, img_2d, img_meta)}
        cpu["metrics and figures"] = time.process_time() - c0 - cpu["registration"] \
            - cpu["blending"]
        summary = {
            "scenario": "gigapixel", "table": rows,
            "registration_error_px": reg_err,
            "pairs": [{"a": p.a, "b": p.b, "offset": p.offset, "error": p.error} for p in pairs],
            "positions_true": {f"{k[0]},{k[1]}": v for k, v in true_pos.items()},
            "positions_found": {f"{k[0]},{k[1]}": v for k, v in pos.items()},
            "mosaic_shape": shape, "mosaic_origin": box[:2], "blend_seconds": t_blend,
            "stage_cpu_seconds": cpu,
            "psf_banks": _psf_counts(kind_stats, psf0, "view_psfs"),
            "psfs_2d": _psf_counts(kind_stats, psf0, "widefield_psf"),
            "settings": _settings_record(s),
        }
        return run.finish(summary, figs, "metasensor scenario: gigapixel mosaic (ED Fig. 7)")


def _psf_counts(now: dict, before: dict, kind: str) -> dict[str, int]:
    """The PSF cache's ``kind`` lookups since ``before``: ``computed`` (misses) and
    ``from_cache`` (hits)."""
    a, b = now.get(kind, {}), before.get(kind, {})
    return {"computed": a.get("misses", 0) - b.get("misses", 0),
            "from_cache": a.get("hits", 0) - b.get("hits", 0)}


def _blended(out: Path, s: GigapixelSettings, cfg, pos: dict, box, meta_paths: dict,
             s2d_paths: dict) -> list:
    """Blend the meta-imaging and the 2D sensor's tiles into their OME-Zarr mosaics.

    Parameters
    ----------
    out : Path
        The report folder (``mosaic.ome.zarr``, ``mosaic_2d.ome.zarr``).
    s : GigapixelSettings
        ``chunk``, ``overlap`` (the ramp is half of it) and ``scheduler``.
    cfg : SystemConfig
        The system (its pixel pitch in the pyramid's metadata).
    pos : dict
        The registered tile origins [pixels] by tile index.
    box : tuple
        ``(y0, x0, y1, x1)``, the covered rectangle the mosaics are blended on (pixels).
    meta_paths, s2d_paths : dict
        The tiles' Zarr paths by tile index.

    Returns
    -------
    list
        The two mosaics (meta-imaging, 2D sensor) as :func:`metasensor.mosaic.blend_tiles`
        returns them.
    """
    from metasensor.mosaic import blend_tiles

    shape = (box[2] - box[0], box[3] - box[1])
    placed = {k: (v[0] - box[0], v[1] - box[1]) for k, v in pos.items()}
    return [blend_tiles(paths, placed, shape, out / name, chunk=s.chunk, ramp=s.overlap // 2,
                        pixel_size_um=cfg.pixel_pitch * 1e6, scheduler=s.scheduler)
            for paths, name in ((meta_paths, "mosaic.ome.zarr"),
                                (s2d_paths, "mosaic_2d.ome.zarr"))]


def _figure(path: Path, s: GigapixelSettings, truth, img_2d, img_meta) -> Path:
    """The mosaic figure: truth, 2D sensor and meta-imaging mosaics side by side, both clipped
    to the truth's range; returns :func:`metasensor.io.figures.save_panel`'s result."""
    from metasensor.io.figures import save_panel

    lo, hi = float(truth.min()), float(truth.max())
    return save_panel(path, [
        ("ground truth", truth), ("2D sensor", np.clip(img_2d, lo, hi)),
        ("meta-imaging sensor", np.clip(img_meta, lo, hi))], ncols=3,
        suptitle=f"{s.grid[0]}x{s.grid[1]} mosaic, single plastic lens")


def _settings_record(s: GigapixelSettings) -> dict:
    """The settings as ``summary.json`` records them."""
    return {"tile": s.tile, "grid": s.grid, "overlap": s.overlap, "jitter": s.jitter,
            "blocks": s.blocks, "snr_db": s.snr_db, "seed": s.seed,
            "space_variant": s.space_variant and s.iterations is None,
            "sim_blocks": s.sim_blocks}


def open_mosaic_array(path: str) -> np.ndarray:
    """A tile written by this scenario, read into memory (tiles are small in the demo)."""
    from metasensor.io.interrupt import quiet_zarr

    zarr = quiet_zarr()  # Ctrl-C reaches the main thread

    return np.asarray(zarr.open_array(path, mode="r")[:])
