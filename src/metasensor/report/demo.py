"""The end-to-end demo (``metasensor demo`` / ``make demo``).

Simulate the built-in bar-group chart (three-bar groups of 2–24 px periods at the centre, the
edge midpoints and the corners, :mod:`metasensor.simulation.bars`: scene ``"bars"``, or
``"bars-field"`` laid out about the field centre; or the ISO 12233-style chart)
through one cheap single lens with strong, field-dependent aberrations
(:class:`metasensor.simulation.lens.SingleLens`); capture it with three sensors of the same pixel
pitch and photon budget — a conventional 2D sensor (in focus), a plain light-field camera
(1 x 1 scan) and the meta-imaging sensor (5 x 5 scan), both light-field cameras at the operating
point (:data:`metasensor.simulation.capture.OPERATING_FOCUS_OFFSET` off the scene's plane);
realign the raw frames; reconstruct both light-field captures with the known system aberration
in multisite blocks; restore the 2D sensor's image with the same kind of prior (hyper-Laplacian
deconvolution with the on-axis PSF, best of three weights by the truth); and write a report (PNG
figures and an HTML page) with the full field and its differences to the truth, zoomed centre
and corners, PSNR / SSIM, the resolved frequency (:mod:`metasensor.metrics.spectral`), the finest
bar group per chart location (:mod:`metasensor.metrics.bars`), the fringe ratio at the block
borders (:mod:`metasensor.metrics.fringes`) and, on the ISO chart, the slanted-edge MTF50 at the
field centre and edge.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from metasensor.config import SystemConfig
from metasensor.io.atomic import atomic_write_text
from metasensor.report.demo_measure import comparison_figure, measure, restore_2d
from metasensor.simulation.capture import OPERATING_FOCUS_OFFSET

__all__ = ["DemoSettings", "run_demo", "sensor_field_zernike", "demo_warnings"]

#: The bar charts the demo takes and their layouts (:func:`metasensor.simulation.bars.bar_groups`)
BAR_LAYOUTS = {"bars-field": "field", "bars": "rows"}

# below these the demo runs but cannot be judged: the chart's finest bar groups and the star's
# centre are finer than a small field resolves, and small blocks are narrower than the PSF
# windows of the aberrated field
MIN_JUDGE_SIZE = 256
MIN_JUDGE_BLOCK = 96


@dataclass(frozen=True)
class DemoSettings:
    """What the demo simulates. ``size``: scene side in pixels. The scene is rendered at the
    sensor's pixel pitch, but its field positions are stretched over ``field_px`` sensor pixels
    (the prototype's full sensor height), so a small, fast scene still sees the aberrations of a
    whole field: on axis sharp; field curvature and astigmatism of ~1.1 waves r.m.s. at the
    edge midpoints, 1.9 at 0.95 of the diagonal (``edge_rms_waves`` in the summary) and 2.1 in
    the corners (the plain Seidel sums of a 135 mm f/10 plastic singlet; ``lens_strength``
    scales them); ``field_blocks``: grid of PSF banks of the simulator, blended between their
    points (finer than the reconstruction's field points and not on them, so that the simulated
    field is not the reconstruction's own interpolation of it; fine enough that the blend does
    not split a marginal view's image of a point into displaced copies, which a lens does not
    do); ``blocks``: multisite grid of the reconstruction, ``field_points`` its field points
    per block side."""

    size: int = 384
    scan: int = 5
    snr_db: float = 30.0
    lens_strength: float = 1.0
    field_px: int = 6004
    blocks: tuple[int, int] = (4, 4)
    field_blocks: tuple[int, int] = (12, 12)
    # the chart: "bars" (bar groups at nine places, in rows from each box's corner),
    # "bars-field" (the same groups oriented about the field centre) or "chart" (ISO
    # 12233-style: slanted-edge squares, a Siemens star, for the slanted-edge MTF)
    scene: str = "bars"
    # defocus of both light-field cameras [waves r.m.s., Noll Z4] (the 2D sensor stays in focus)
    focus_offset: float = OPERATING_FOCUS_OFFSET
    # the meta-imaging reconstruction's space-variant model (ReconOptions.space_variant) and
    # its field points per block side (ReconOptions.field_points)
    space_variant: bool = True
    field_points: int = 3
    # view registration before the HQS solve (ReconOptions.register); off: with the known
    # aberration and the space-variant model it registers the views against the block's mean
    # bank, a blend of PSFs that differ where the aberration changes (docs/decisions.md)
    register: bool = False
    # Richardson-Lucy iterations of the plain light field (and of the meta-imaging row with
    # solver "rl"); ISA solver of the meta-imaging row: "hqs" (the sparse-gradient prior,
    # solvers.hqs) or "rl". Measurements: docs/decisions.md.
    iterations: int | None = 6
    solver: str = "hqs"
    # blocks reconstructed at once (ReconOptions.num_workers), each on one of this process's
    # torch threads; None: one per torch thread on the CPU, one on CUDA (docs/decisions.md)
    workers: int | None = None
    seed: int = 0
    extra: dict = field(default_factory=dict)


def sensor_field_zernike(fz_sensor, cfg: SystemConfig, sensor_shape: tuple[int, int],
                         image_shape: tuple[int, int]):
    """Re-express a field aberration given over the *sensor* (normalised coordinates of the
    scene/sensor of ``sensor_shape``) in the normalised coordinates of a reconstruction grid of
    ``image_shape`` (whose pixel (i, j) is sensor pixel (i + o, j + o), docs/conventions.md)."""
    o = cfg.field_offset_px
    hs, ws = sensor_shape
    hi, wi = image_shape

    def fz(yn, xn):
        yi = (np.asarray(yn, float) + 1.0) * hi / 2.0 - 0.5 + o
        xi = (np.asarray(xn, float) + 1.0) * wi / 2.0 - 0.5 + o
        return fz_sensor(2.0 * (yi + 0.5) / hs - 1.0, 2.0 * (xi + 0.5) / ws - 1.0)

    return fz


def demo_warnings(s: DemoSettings) -> list[str]:
    """Why a demo of these settings would mislead (empty when it can be judged)."""
    side = min(s.size // b for b in s.blocks)
    if s.size >= MIN_JUDGE_SIZE and side >= MIN_JUDGE_BLOCK:
        return []
    return [f"a {s.size}-px chart in {s.blocks[0]}x{s.blocks[1]} blocks ({side}-px blocks) is "
            f"too small to judge the sensor: the finest bar groups and the star's centre are "
            f"finer than such a field resolves (they come out flat) and the blocks are narrower "
            f"than the aberrated PSFs; use --size {MIN_JUDGE_SIZE} or more (default 384) with "
            f"blocks of {MIN_JUDGE_BLOCK} px or more"]


def _on_grid(image: np.ndarray, shift: int, shape: tuple[int, int]) -> np.ndarray:
    """``image`` on another reconstruction grid: target pixel (i, j) is source pixel
    (i + shift, j + shift) (grids of different scan periods start at different sensor
    pixels, docs/conventions.md); NaN where the source has no pixel."""
    out = np.full(shape, np.nan, np.float32)
    h, w = image.shape
    ys, xs = slice(max(0, -shift), min(shape[0], h - shift)), \
        slice(max(0, -shift), min(shape[1], w - shift))
    out[ys, xs] = image[ys.start + shift:ys.stop + shift, xs.start + shift:xs.stop + shift]
    return out


def _zoom_boxes(shape: tuple[int, int], side: int) -> dict[str, tuple[int, int, int, int]]:
    h, w = shape
    s = min(side, h // 2, w // 2)
    m = 4
    return {
        "centre": ((h - s) // 2, (h + s) // 2, (w - s) // 2, (w + s) // 2),
        "top-left corner": (m, m + s, m, m + s),
        "bottom-right corner": (h - m - s, h - m, w - m - s, w - m),
    }


def _crop(a: np.ndarray, box) -> np.ndarray:
    y0, y1, x0, x1 = box
    return a[y0:y1, x0:x1]


def _mtf_centre_edge(image: np.ndarray, truth: np.ndarray) -> dict:
    """MTF50 (cycles/pixel) of the slanted edges nearest the field centre and farthest from it."""
    from metasensor.metrics import field_mtf

    try:
        res = field_mtf(image, reference=truth)
    except ValueError as exc:
        return {"mtf_note": f"no MTF measured ({exc})"}
    summary = res.summary()
    out = {k: (float(v) if isinstance(v, (float, np.floating)) else v)
           for k, v in summary.items()}
    if summary["n_measured"] == 0:
        out["mtf_note"] = (f"none of the {summary['n_rois']} slanted edges gave an MTF50 (the "
                           "edge response never fell to half contrast)")
    return out


def _quality_table(results: dict) -> list[dict]:
    """PSNR (dB), SSIM and MTF50 (cycles/pixel) of each sensor's image against its truth."""
    from metasensor.metrics import psnr, ssim

    table = []
    for name, (img, truth) in results.items():
        rng = float(truth.max() - truth.min())
        row = {"sensor": name, "psnr_db": psnr(truth=truth, image=img, data_range=rng),
               "ssim": ssim(truth=truth, image=img, data_range=rng)}
        row.update({k: v for k, v in _mtf_centre_edge(img, truth).items()
                    if k in ("centre_mtf50", "edge_mtf50", "mtf_note")})
        table.append(row)
    return table


def _figures(out: Path, cap, lf, results: dict, zoom: int) -> dict:
    """The full field and three zooms, every image on the meta-imaging capture's pixel grid
    (so all panels have one size), one intensity range and colour bar (DN)."""
    from metasensor.io.figures import save_panel

    lo, hi = float(cap.truth.min()), float(cap.truth.max())
    shift = cap.config.field_offset_px - lf.config.field_offset_px  # lf pixel - cap pixel
    panel = [("ground truth", cap.truth)] + [
        (k, np.clip(_on_grid(v[0], shift, cap.truth.shape) if v[1] is lf.truth else v[0],
                    lo, hi)) for k, v in results.items()]
    units = dict(colorbar_label="intensity (DN)", ncols=4)
    h, w = cap.truth.shape
    figs = {"full field": save_panel(
        out / "full_field.png", panel, suptitle=f"Single plastic lens, f/10, strong field "
        f"aberrations ({w} x {h} px)", **units)}
    for label, box in _zoom_boxes(cap.truth.shape, zoom).items():
        crops = [(t, _crop(a, box)) for t, a in panel]
        figs[label] = save_panel(out / f"zoom_{label.replace(' ', '_')}.png", crops,
                                 suptitle=f"zoom: {label} ({box[3] - box[2]} x "
                                 f"{box[1] - box[0]} px)", **units)
    return figs


def _check_settings(s: DemoSettings) -> None:
    """Refuse impossible settings before any output exists."""
    from metasensor.recon.blocks import split_blocks
    from metasensor.recon.options import ReconOptions

    SystemConfig(scan=s.scan)  # an impossible scan period fails here
    # a grid of fewer than 2 x 2 field points and a worker count below 1 fail here
    ReconOptions(field_points=s.field_points, num_workers=s.workers)
    if not isinstance(s.register, bool):
        raise TypeError(f"register must be True or False, got {s.register!r}")
    if not math.isfinite(s.snr_db):
        raise ValueError(f"snr_db must be a finite number of dB, got {s.snr_db!r}")
    if s.scene not in BAR_LAYOUTS and s.scene != "chart":
        raise ValueError(f"the demo's chart (scene) must be 'bars-field', 'bars' or 'chart', got "
                         f"{s.scene!r}")
    if not math.isfinite(s.focus_offset):
        raise ValueError(f"focus_offset must be a finite number of waves, got {s.focus_offset!r}")
    if min(s.blocks) < 1 or min(s.field_blocks) < 1:
        raise ValueError(f"blocks must be >= 1 each, got {s.blocks} / {s.field_blocks}")
    d = SystemConfig(scan=s.scan).scan_step_px  # blocks too small even for the whole scene
    split_blocks((s.size // d * d,) * 2, s.blocks, d)


def _simulate_both(scene: np.ndarray, cfg: SystemConfig, fz_sensor, s: DemoSettings, steps):
    """The meta-imaging sensor's capture and the plain light-field camera's (1 x 1 scan) of
    ``scene`` through the lens's field aberration ``fz_sensor``."""
    from metasensor.simulation.capture import simulate

    steps.set_postfix_str("simulating the meta-imaging sensor")
    cap = simulate(scene, cfg, field_zernike=fz_sensor, snr_db=s.snr_db, seed=s.seed,
                   field_blocks=s.field_blocks, focus_offset=s.focus_offset)
    steps.update()
    steps.set_postfix_str("simulating the plain light-field camera")
    lf = simulate(scene, cfg, scan=1, field_zernike=fz_sensor, snr_db=s.snr_db,
                  seed=s.seed + 1, comparison=False, field_blocks=s.field_blocks,
                  focus_offset=s.focus_offset)
    steps.update()
    return cap, lf


def demo_workers(s: DemoSettings) -> int:
    """Blocks the demo reconstructs at once: ``s.workers``, or
    :func:`metasensor.recon.parallel.local_workers` (one per torch thread on the CPU, one on
    CUDA)."""
    if s.workers is not None:
        return int(s.workers)
    from metasensor.recon.parallel import local_workers

    return local_workers(s.blocks[0] * s.blocks[1])


def _reconstruct_both(cap, lf, fz_sensor, scene_shape, s: DemoSettings, steps):
    """Both captures reconstructed with the known field aberration (multisite blocks): the
    meta-imaging sensor's with ``s.solver``, the plain light field's with Richardson–Lucy."""
    import metasensor as ms

    focus = np.array([0.0, 0.0, 0.0, s.focus_offset]) if s.focus_offset else None
    steps.set_postfix_str("reconstructing (meta-imaging, multisite)")
    views = ms.realign(cap.frames, cap.config, cap.scan_order)
    fz_meta = sensor_field_zernike(fz_sensor, cap.config, scene_shape, cap.truth.shape)
    hqs = s.solver == "hqs"
    workers = demo_workers(s)
    rec = ms.reconstruct(views, cap.config, method="isa", zernike=focus, field_zernike=fz_meta,
                         blocks=s.blocks, iterations=None if hqs else s.iterations,
                         solver=s.solver, register=s.register and hqs,
                         space_variant=s.space_variant and hqs,
                         field_points=s.field_points, num_workers=workers)
    steps.update()
    steps.set_postfix_str("reconstructing (plain light field)")
    fz_lf = sensor_field_zernike(fz_sensor, lf.config, scene_shape, lf.truth.shape)
    rec_lf = ms.reconstruct(lf.views, lf.config, method="isa", zernike=focus,
                            field_zernike=fz_lf, blocks=s.blocks, iterations=s.iterations,
                            solver="rl", num_workers=workers)
    steps.update()
    return rec, rec_lf


def run_demo(out: str | Path, settings: DemoSettings | None = None, progress: bool = True) -> dict:
    """Run the whole demo and write the report into ``out``; returns the summary dict."""
    import warnings

    from tqdm.auto import tqdm

    s = settings or DemoSettings()
    _check_settings(s)
    notes = demo_warnings(s)
    for note in notes:
        warnings.warn(note, UserWarning, stacklevel=2)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    with tqdm(total=5, desc="demo", disable=not progress) as steps:  # closed on any error too
        return _demo_steps(out, s, notes, steps, t_start)


def _demo_steps(out: Path, s: DemoSettings, notes: list[str], steps, t_start: float) -> dict:
    """:func:`run_demo`'s work under its progress bar ``steps``."""
    from metasensor.report.html import write_html_report
    from metasensor.simulation.lens import SingleLens
    from metasensor.simulation.scenes import load_scene

    lens = SingleLens(strength=s.lens_strength)
    cfg = lens.config(SystemConfig(scan=s.scan))
    scene = load_scene(s.scene, s.size).astype(np.float32)
    fz_sensor = lens.field_zernike(cfg, (s.field_px, s.field_px))
    cap, lf = _simulate_both(scene, cfg, fz_sensor, s, steps)
    rec, rec_lf = _reconstruct_both(cap, lf, fz_sensor, scene.shape, s, steps)
    steps.set_postfix_str("measuring and writing the report")
    meta_name = f"meta-imaging sensor ({s.scan}x{s.scan} scan)"
    results = {
        "2D sensor": (cap.sensor2d, cap.truth),
        "plain light field (1x1 scan)": (np.asarray(rec_lf.image), lf.truth),
        meta_name: (np.asarray(rec.image), cap.truth),
    }
    on_axis = fz_sensor(np.zeros(1), np.zeros(1))[0]
    restored = {"2D sensor + prior": (restore_2d(cap, on_axis), cap.truth)}
    table = _quality_table({**results, **restored})
    d = cap.config.scan_step_px
    places = {k: (cap.offset, (cap.truth.shape, s.blocks, d)) for k in (*results, *restored)}
    places["plain light field (1x1 scan)"] = (lf.offset, (lf.truth.shape, s.blocks,
                                                          lf.config.scan_step_px))
    bars = measure(table, {**results, **restored}, places, s.size, BAR_LAYOUTS.get(s.scene))
    figs = _figures(out, cap, lf, results, s.size // 5)
    figs["comparison"] = comparison_figure(out / "comparison.png", cap, lf, results)
    seconds = time.perf_counter() - t_start
    summary = {
        "warnings": notes,
        "settings": {k: v for k, v in s.__dict__.items() if k != "extra"},
        "config": cfg.to_dict(),
        "table": table,
        "bar_groups": bars,
        "seconds": seconds,
        "edge_rms_waves": float(np.sqrt((fz_sensor(np.array(0.95), np.array(0.95))[3:] ** 2
                                         ).sum())),
        "figures": {k: str(Path(v).name) for k, v in figs.items()},
    }
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2, default=float))
    write_html_report(out / "index.html", summary)
    steps.update()
    return summary
