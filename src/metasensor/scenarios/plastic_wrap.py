"""Scenario ``plastic-wrap`` (Fig. 3 of the paper): strong, nonuniform environmental aberrations
and an extended depth of field.

A diffraction-limited lens (no aberration of its own; its f-number matched to the lenslets, as
every lens of this simulator, image-side NA ``cfg.na``) looks through sheets of plastic wrap a
distance in front of it (:class:`~metasensor.scenarios.screens.PlasticWrap`: several waves
r.m.s., every field point seeing a different part of the sheets). The scene is a resolution
chart in focus (the bar chart of :mod:`metasensor.simulation.bars` by default, or the demo's
chart), with a nearer object (a natural-image patch over the chart's bottom-left location)
defocused by ``near_depth`` on the image side (a depth map). Three sensors of one pixel pitch
and photon budget see it: the 2D sensor (focused on the chart), a plain light-field camera
(1 × 1 scan, ISA without aberration knowledge) and the meta-imaging sensor (5 × 5 scan, ISA
with multisite wave DAO from scratch, no calibration: every block estimates its own wavefront,
defocus included, so the near object's blocks come out in focus: all-in-focus by per-block
defocus; ``PlasticWrapSettings(depth_layers="auto")`` adds the depth-aware block model,
``reconstruct(depth_layers="auto")`` (:mod:`metasensor.recon.layers`), which gives each of the
two depth layers of a block holding both the chart and the near object its own defocus).
Resolution is read two ways: the finest bar group resolved at every chart location
(:func:`~metasensor.scenarios.measure.bar_periods`, the bar chart only) and the local resolved
frequency (:func:`~metasensor.scenarios.measure.resolved_frequency`) on a grid over the field;
the near object's resolved frequency is compared with the chart's (the mean of the grid regions
it does not touch).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from metasensor.scenarios.report import ScenarioSettings
from metasensor.scenarios.screens import PlasticWrap

__all__ = ["PlasticWrapSettings", "run_plastic_wrap", "near_object_scene"]


@dataclass(frozen=True)
class PlasticWrapSettings(ScenarioSettings):
    """:class:`~metasensor.scenarios.report.ScenarioSettings` (``blocks``: simulation and DAO,
    default 4 x 4; ``iterations``: after DAO) and size : scene side (pixels); grid : regions of
    the resolution maps; near_depth : image-side defocus of the near object (metres); wrap :
    the sheets (default 3 waves r.m.s. over three sheets, correlation 0.25 D, footprints spread
    by 0.1 D between field centre and edge, so that the wrap changes little inside a 4 x 4
    block and DAO's one aberration per block holds
    (:meth:`~metasensor.scenarios.screens.PlasticWrap.block_variation` measures it; the
    figures: docs/decisions.md, "DAO on the plastic wrap"); chart : "bars" or "chart"
    (the scene behind the near object); depth_layers : the meta-imaging reconstruction's
    depth-aware block model (``reconstruct``'s option, "off" by default or "auto"; HQS only, so
    "off" with ``iterations``; why off: docs/decisions.md, "the depth-aware block model" and
    "the depth-aware block model's layers decided on the image")."""

    size: int = 240
    chart: str = "bars"
    blocks: tuple[int, int] = (4, 4)
    grid: tuple[int, int] = (4, 4)
    near_depth: float = 1.0e-3
    depth_layers: str = "off"
    wrap: PlasticWrap = field(default_factory=lambda: PlasticWrap(rms_waves=3.0,
                                                                  correlation=0.25, spread=0.1))

    def __post_init__(self) -> None:
        if not (isinstance(self.size, int) and self.size >= 96):
            raise ValueError(f"size must be an integer >= 96, got {self.size!r}")
        if min(self.blocks) < 1 or min(self.grid) < 1:
            raise ValueError(f"blocks and grid must be positive, got {self.blocks}, {self.grid}")
        if self.chart not in ("bars", "chart"):
            raise ValueError(f"chart must be 'bars' or 'chart', got {self.chart!r}")
        if self.depth_layers not in ("auto", "off"):
            raise ValueError(f"depth_layers must be 'auto' or 'off', got {self.depth_layers!r}")
        if not np.isfinite(self.near_depth):
            raise ValueError(f"near_depth must be finite, got {self.near_depth!r}")


def near_object_scene(size: int, near_depth: float, chart: str = "bars"
                      ) -> tuple[np.ndarray, np.ndarray, tuple]:
    """The chart (``"bars"`` or ``"chart"``) with a natural-image patch over the bar chart's
    bottom-left location: (scene (size, size) float32, depth map [m], the patch's box
    (y0, y1, x0, x1) in scene pixels)."""
    from metasensor.simulation.bars import bar_groups
    from metasensor.simulation.scenes import load_scene, natural_image

    scene = load_scene(chart, size).astype(np.float32)
    corner = [g for g in bar_groups(size) if g.location == "bottom-left"]
    y0 = int(min(g.y0 for g in corner)) - 2
    x0 = int(min(g.x0 for g in corner)) - 2
    y1 = int(np.ceil(max(g.y0 + g.extent for g in corner))) + 2
    x1 = int(np.ceil(max(g.x0 + g.extent for g in corner))) + 2
    patch = natural_image("camera", shape=(y1 - y0, x1 - x0)).astype(np.float32)
    scene[y0:y1, x0:x1] = 0.1 + 0.9 * patch
    depth = np.zeros_like(scene, dtype=np.float64)
    depth[y0:y1, x0:x1] = near_depth
    return scene, depth, (y0, y1, x0, x1)


def _chart_cells(shape, grid, box) -> np.ndarray:
    """(gy, gx) True for the grid regions (as in ``field_resolution``) that miss ``box``."""
    ys = np.array_split(np.arange(shape[0]), grid[0])
    xs = np.array_split(np.arange(shape[1]), grid[1])
    y0, y1, x0, x1 = box
    return np.array([[y[-1] < y0 or y[0] >= y1 or x[-1] < x0 or x[0] >= x1 for x in xs]
                     for y in ys])


def _measure(images: dict, truths: dict, offsets: dict, s: PlasticWrapSettings,
             box) -> tuple[list[dict], dict, dict]:
    """Per sensor: PSNR, SSIM, resolved-frequency map, near object, bar periods. ``box`` is
    the near object in scene pixels; ``offsets`` the scene pixel of each truth's (0, 0)."""
    from metasensor.metrics import psnr, ssim
    from metasensor.scenarios.measure import bar_periods, field_resolution, resolved_frequency
    from metasensor.simulation.bars import bar_groups

    rows, maps, bars = [], {}, {}
    for name, img in images.items():
        truth, o = truths[name], offsets[name]
        h, w = truth.shape
        near_box = (max(box[0] - o, 0), min(box[1] - o, h), max(box[2] - o, 0),
                    min(box[3] - o, w))
        rng = float(truth.max() - truth.min())
        fmap = field_resolution(img, truth, s.grid)
        chart = _chart_cells(truth.shape, s.grid, near_box)
        y0, y1, x0, x1 = near_box
        near = resolved_frequency(img[y0:y1, x0:x1], truth[y0:y1, x0:x1])
        maps[name] = fmap
        row = {"sensor": name, "psnr_db": psnr(truth=truth, image=img, data_range=rng),
               "ssim": ssim(truth=truth, image=img, data_range=rng),
               "resolved_mean_cpp": float(fmap.mean()),
               "resolved_worst_cpp": float(fmap.min()),
               "resolved_chart_cpp": float(fmap[chart].mean()),
               "resolved_near_object_cpp": near}
        if s.chart == "bars":
            groups = bar_groups(s.size, origin=float(o))
            bars[name] = bar_periods(img, groups, exclude=near_box)
            row["bar_px"] = {k: v["period_px"] for k, v in bars[name].items()}
        rows.append(row)
    return rows, maps, bars


def _gains(rows: list[dict], maps: dict, bars: dict, floor: float) -> dict:
    """Meta-imaging (last row) against the 2D sensor (first row): resolved-frequency ratio over
    the grid (a region resolving nothing counts as ``floor``, the centre of the lowest frequency
    bin its spectrum is read in, so the ratio there is a lower bound), bar-group ratio per
    location (lower bounds where the 2D sensor resolves none), the near object's resolved
    frequency over the chart's."""
    from metasensor.scenarios.measure import bar_gains

    names = [r["sensor"] for r in rows]
    two_d, meta = maps[names[0]], maps[names[-1]]
    ratio = np.maximum(meta, floor) / np.maximum(two_d, floor)
    worst = two_d <= two_d.min() + 1e-12
    out = {"gain_at_2d_worst": float(ratio[worst].min()), "gain_mean": float(ratio.mean()),
           "floor_cpp": floor, "gain_at_2d_worst_is_lower_bound": bool(two_d.min() <= 0),
           "near_over_chart_meta": rows[-1]["resolved_near_object_cpp"]
           / max(rows[-1]["resolved_chart_cpp"], 1e-9),
           "near_over_chart_2d": rows[0]["resolved_near_object_cpp"]
           / max(rows[0]["resolved_chart_cpp"], 1e-9)}
    if bars:
        g = bar_gains(bars[names[0]], bars[names[-1]])
        p2d = {k: (v["period_px"] or np.inf) for k, v in bars[names[0]].items()}
        worst_p = max(p2d.values())
        at_worst = [g[k]["gain"] for k in g if p2d[k] == worst_p]
        out.update({"bar_gain_per_location": g,
                    "bar_gain_at_2d_worst": float(min(at_worst)),
                    "bar_gain_mean": float(np.mean([v["gain"] for v in g.values()])),
                    "bar_gain_is_lower_bound": any(v["bound"] for v in g.values())})
    return out


def _dao_error(true_z: np.ndarray, est: np.ndarray) -> np.ndarray | None:
    """(by, bx) r.m.s. (waves, Noll 4-45) of DAO's estimate minus the wrap at each block centre
    (None when the grids differ)."""
    if true_z.shape[:2] != est.shape[:2]:
        return None
    j = min(true_z.shape[-1], est.shape[-1], 45)
    return np.sqrt(((est[..., 3:j] - true_z[..., 3:j]) ** 2).sum(-1))


def run_plastic_wrap(out: str | Path, settings: PlasticWrapSettings | None = None,
                     progress: bool = True) -> dict:
    """Run the scenario and write its report into ``out``; returns the summary."""
    import metasensor as ms
    from metasensor.io.figures import save_panel
    from metasensor.recon.parallel import local_workers
    from metasensor.scenarios.measure import frequency_floor
    from metasensor.scenarios.report import save_maps, scenario_run

    s = settings or PlasticWrapSettings()
    with scenario_run(out, "plastic-wrap", 4, progress) as run:
        out, steps = run.out, run.steps
        cfg = ms.SystemConfig()
        scene, depth, box = near_object_scene(s.size, s.near_depth, s.chart)
        fz = s.wrap.field_zernike()
        cpu = [time.process_time()]
        cap = ms.simulate(scene, cfg, field_zernike=fz, depth=depth, snr_db=s.snr_db, seed=s.seed,
                          field_blocks=s.blocks)
        lf = ms.simulate(scene, cfg, scan=1, field_zernike=fz, depth=depth,
                         snr_db=s.snr_db, seed=s.seed + 1, comparison=False, field_blocks=s.blocks)
        steps.update()
        cpu.append(time.process_time())
        views = ms.realign(cap.frames, cap.config, cap.scan_order)
        workers = local_workers(s.blocks[0] * s.blocks[1])  # a block per CPU thread
        rec = ms.reconstruct(views, cap.config, method="wave", blocks=s.blocks,
                             iterations=s.iterations, num_workers=workers,
                             depth_layers=s.depth_layers if s.iterations is None else "off")
        steps.update()
        cpu.append(time.process_time())
        rec_lf = ms.reconstruct(lf.views, lf.config, blocks=s.blocks, solver="rl",
                                num_workers=workers)
        steps.update()
        cpu.append(time.process_time())
        images = {"2D sensor": cap.sensor2d, "plain light field": rec_lf.image,
                  "meta-imaging + DAO": np.asarray(rec.image)}
        truths = {"2D sensor": cap.truth, "plain light field": lf.truth,
                  "meta-imaging + DAO": cap.truth}
        offsets = {"2D sensor": cap.offset, "plain light field": lf.offset,
                   "meta-imaging + DAO": cap.offset}
        rows, maps, bars = _measure(images, truths, offsets, s, box)
        gy, gx = s.grid
        floor = frequency_floor((cap.truth.shape[0] // gy, cap.truth.shape[1] // gx))
        gains = _gains(rows, maps, bars, floor)
        h, w = cap.truth.shape
        o = cap.offset
        shift = (max(box[0] - o, 0), min(box[1] - o, h), max(box[2] - o, 0),
                 min(box[3] - o, w))
        lo, hi = float(cap.truth.min()), float(cap.truth.max())
        panel = [("ground truth", cap.truth)] + [(k, np.clip(v, lo, hi)) for k, v in images.items()]
        figs = {"full field": save_panel(out / "full_field.png", panel, ncols=4,
                                         suptitle="Diffraction-limited lens behind plastic wrap")}
        y0, y1, x0, x1 = shift
        figs["near object"] = save_panel(out / "near_object.png",
                                         [(t, a[y0:y1, x0:x1]) for t, a in panel], ncols=4,
                                         suptitle="the nearer object (defocused in the 2D sensor)")
        figs["resolution maps"] = save_maps(out / "resolution_maps.png", maps,
                                            "resolved frequency over the field", "cycles / pixel")
        true_z = np.asarray(cap.zernike)
        summary = {
            "scenario": "plastic-wrap", "table": rows, "gains": gains,
            "maps_cpp": maps, "wrap": {"layers": s.wrap.layers, "rms_waves": s.wrap.rms_waves,
                                       "correlation_pupil_diameters": s.wrap.correlation,
                                       "spread_pupil_diameters": s.wrap.spread,
                                       "seed": s.wrap.seed,
                                       "block_variation_waves": s.wrap.block_variation(s.blocks)},
            "true_rms_waves_per_block": np.sqrt((true_z[..., 3:] ** 2).sum(-1)),
            "dao_error_waves_per_block": _dao_error(true_z, np.asarray(rec.zernike)),
            "estimated_defocus_waves_per_block": np.asarray(rec.zernike)[..., 3],
            "dao_fit_px_per_block": rec.dao_fit_px,
            "depth_layers_per_block": rec.depth_layers,
            "stage_cpu_seconds": dict(zip(("simulation", "meta-imaging reconstruction",
                                           "light-field reconstruction"), np.diff(cpu).tolist(),
                                          strict=True)),
            "settings": {"size": s.size, "chart": s.chart, "blocks": s.blocks, "snr_db": s.snr_db,
                         "near_depth_m": s.near_depth, "seed": s.seed,
                         "depth_layers": s.depth_layers},
        }
        return run.finish(summary, figs, "metasensor scenario: plastic wrap (Fig. 3)")
