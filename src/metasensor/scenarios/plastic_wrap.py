"""Scenario ``plastic-wrap`` (Fig. 3 of the paper): strong, nonuniform environmental aberrations
and an extended depth of field.

A diffraction-limited lens (no aberration of its own; its f-number matched to the lenslets, as
every lens of this simulator, image-side NA ``cfg.na``) looks through sheets of plastic wrap a
distance in front of it (:class:`~metasensor.scenarios.screens.PlasticWrap`: several waves
r.m.s., every field point seeing a different part of the sheets). The scene is the resolution
chart, in focus, with a nearer object (a natural-image patch) defocused by ``near_depth`` on the
image side (a depth map). Three sensors of one pixel pitch and photon budget see it: the 2D
sensor (focused on the chart), a plain light-field camera (1 × 1 scan, ISA without aberration
knowledge) and the meta-imaging sensor (5 × 5 scan, ISA with multisite wave DAO from scratch, no
calibration: every block estimates its own wavefront, defocus included, so the near object's
blocks come out in focus: all-in-focus by per-block defocus). Resolution is the local resolved
frequency (:func:`~metasensor.scenarios.measure.resolved_frequency`) on a grid over the field.
"""

from __future__ import annotations

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
    the sheets."""

    size: int = 240
    blocks: tuple[int, int] = (4, 4)
    grid: tuple[int, int] = (4, 4)
    near_depth: float = 1.0e-3
    wrap: PlasticWrap = field(default_factory=lambda: PlasticWrap(rms_waves=2.0))

    def __post_init__(self) -> None:
        if not (isinstance(self.size, int) and self.size >= 96):
            raise ValueError(f"size must be an integer >= 96, got {self.size!r}")
        if min(self.blocks) < 1 or min(self.grid) < 1:
            raise ValueError(f"blocks and grid must be positive, got {self.blocks}, {self.grid}")
        if not np.isfinite(self.near_depth):
            raise ValueError(f"near_depth must be finite, got {self.near_depth!r}")


def near_object_scene(size: int, near_depth: float) -> tuple[np.ndarray, np.ndarray, tuple]:
    """The chart with a natural-image patch pasted over its lower-left quarter-block area:
    (scene (size, size) float32, depth map [m], the patch's box (y0, y1, x0, x1))."""
    from metasensor.simulation.scenes import load_scene, natural_image

    scene = load_scene("chart", size).astype(np.float32)
    y0, y1, x0, x1 = int(0.55 * size), int(0.95 * size), int(0.05 * size), int(0.45 * size)
    patch = natural_image("camera", shape=(y1 - y0, x1 - x0)).astype(np.float32)
    scene[y0:y1, x0:x1] = 0.1 + 0.9 * patch
    depth = np.zeros_like(scene, dtype=np.float64)
    depth[y0:y1, x0:x1] = near_depth
    return scene, depth, (y0, y1, x0, x1)


def _measure(images: dict, truths: dict, grid, box) -> tuple[list[dict], dict]:
    from metasensor.metrics import psnr, ssim
    from metasensor.scenarios.measure import field_resolution, resolved_frequency

    rows, maps = [], {}
    for name, img in images.items():
        truth = truths[name]
        rng = float(truth.max() - truth.min())
        fmap = field_resolution(img, truth, grid)
        y0, y1, x0, x1 = (min(v, s) for v, s in zip(box, (truth.shape[0],) * 2 + (
            truth.shape[1],) * 2, strict=True))
        near = resolved_frequency(img[y0:y1, x0:x1], truth[y0:y1, x0:x1])
        maps[name] = fmap
        rows.append({"sensor": name, "psnr_db": psnr(truth=truth, image=img, data_range=rng),
                     "ssim": ssim(truth=truth, image=img, data_range=rng),
                     "resolved_mean_cpp": float(fmap.mean()),
                     "resolved_worst_cpp": float(fmap.min()),
                     "resolved_near_object_cpp": near})
    return rows, maps


def _gains(rows: list[dict], maps: dict) -> dict:
    names = [r["sensor"] for r in rows]
    two_d, meta = maps[names[0]], maps[names[-1]]
    floor = 1.0 / 64  # the lowest ring of a 64-px region: "nothing resolved" counts as this
    ratio = np.maximum(meta, floor) / np.maximum(two_d, floor)
    worst = two_d <= two_d.min() + 1e-12
    return {"gain_at_2d_worst": float(ratio[worst].min()), "gain_mean": float(ratio.mean()),
            "near_over_chart_meta": rows[-1]["resolved_near_object_cpp"]
            / max(rows[-1]["resolved_mean_cpp"], 1e-9),
            "near_over_chart_2d": rows[0]["resolved_near_object_cpp"]
            / max(rows[0]["resolved_mean_cpp"], 1e-9)}


def run_plastic_wrap(out: str | Path, settings: PlasticWrapSettings | None = None,
                     progress: bool = True) -> dict:
    """Run the scenario and write its report into ``out``; returns the summary."""
    import metasensor as ms
    from metasensor.io.figures import save_panel
    from metasensor.scenarios.report import save_maps, scenario_run

    s = settings or PlasticWrapSettings()
    with scenario_run(out, "plastic-wrap", 4, progress) as run:
        out, steps = run.out, run.steps
        cfg = ms.SystemConfig()
        scene, depth, box = near_object_scene(s.size, s.near_depth)
        fz = s.wrap.field_zernike()
        cap = ms.simulate(scene, cfg, field_zernike=fz, depth=depth, snr_db=s.snr_db, seed=s.seed,
                          field_blocks=s.blocks)
        lf = ms.simulate(scene, cfg, scan=1, field_zernike=fz, depth=depth,
                         snr_db=s.snr_db, seed=s.seed + 1, comparison=False, field_blocks=s.blocks)
        steps.update()
        views = ms.realign(cap.frames, cap.config, cap.scan_order)
        rec = ms.reconstruct(views, cap.config, method="wave", blocks=s.blocks,
                             iterations=s.iterations)
        steps.update()
        rec_lf = ms.reconstruct(lf.views, lf.config, blocks=s.blocks, solver="rl")
        steps.update()
        o = cap.offset
        shift = (box[0] - o, box[1] - o, box[2] - o, box[3] - o)
        images = {"2D sensor": cap.sensor2d, "plain light field": rec_lf.image,
                  "meta-imaging + DAO": np.asarray(rec.image)}
        truths = {"2D sensor": cap.truth, "plain light field": lf.truth,
                  "meta-imaging + DAO": cap.truth}
        rows, maps = _measure(images, truths, s.grid, shift)
        gains = _gains(rows, maps)
        lo, hi = float(cap.truth.min()), float(cap.truth.max())
        panel = [("ground truth", cap.truth)] + [(k, np.clip(v, lo, hi)) for k, v in images.items()]
        figs = {"full field": save_panel(out / "full_field.png", panel, ncols=4,
                                         suptitle="Diffraction-limited lens behind plastic wrap")}
        y0, y1, x0, x1 = (max(v, 0) for v in shift)
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
                                       "seed": s.wrap.seed},
            "true_rms_waves_per_block": np.sqrt((true_z[..., 3:] ** 2).sum(-1)),
            "estimated_defocus_waves_per_block": np.asarray(rec.zernike)[..., 3],
            "settings": {"size": s.size, "blocks": s.blocks, "snr_db": s.snr_db,
                         "near_depth_m": s.near_depth, "seed": s.seed},
        }
        return run.finish(summary, figs, "metasensor scenario: plastic wrap (Fig. 3)")
