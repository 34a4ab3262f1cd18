"""Evaluation of a result image: PSNR/SSIM against a truth, slanted-edge MTF across the field.

:func:`evaluate` returns a JSON-ready dict (what the demo report calls); :func:`write_evaluation`
writes it as JSON, a CSV table and a text summary, plus figures, all atomically.
"""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path

import numpy as np

from metasensor.io.atomic import atomic_write_text
from metasensor.metrics.field import FieldMTF, field_mtf
from metasensor.metrics.quality import psnr, ssim

__all__ = ["evaluate", "evaluate_full", "write_evaluation", "CSV_COLUMNS"]

CSV_COLUMNS = ("index", "y0", "y1", "x0", "x1", "centre_y", "centre_x", "field_radius",
               "orientation", "angle_deg", "mtf50", "mtf50_lpmm", "mtf_at_0.25cpp",
               "error")


def _finite(v):
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def evaluate_full(image, truth=None, chart: bool = False, rois=None, *,
                  pixel_pitch: float | None = None, oversample: int = 4,
                  window: str = "hamming", progress: bool = False,
                  data_range: float | None = None) -> tuple[dict, FieldMTF | None]:
    """Like :func:`evaluate`, also returning the :class:`FieldMTF` (None without MTF work)."""
    a = np.asarray(image)
    if a.ndim != 2:
        raise ValueError(f"image must be a 2-D image (H, W), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError("image contains NaN or infinite values")
    if truth is None and not chart and not rois:
        raise ValueError("nothing to evaluate: give a truth image, chart=True or rois")
    if pixel_pitch is not None and not (pixel_pitch > 0 and np.isfinite(pixel_pitch)):
        raise ValueError(f"pixel_pitch must be a positive length in metres, got {pixel_pitch!r}")
    out: dict = {"shape": list(a.shape), "pixel_pitch": pixel_pitch}
    if truth is not None:
        t = np.asarray(truth)
        if t.shape != a.shape:
            raise ValueError(f"truth shape {t.shape} differs from image shape {a.shape}")
        out["psnr_db"] = _finite(psnr(truth=t, image=a, data_range=data_range))
        out["ssim"] = ssim(truth=t, image=a, data_range=data_range)
        out["data_range"] = float(t.max() - t.min()) if data_range is None else float(data_range)
    fm = None
    if chart or rois:
        fm = field_mtf(a, list(rois) if rois else None, reference=truth,
                       pixel_pitch=pixel_pitch, oversample=oversample, window=window,
                       progress=progress)
        out["field"] = {k: _finite(v) if isinstance(v, float) else v
                        for k, v in fm.summary().items()}
        rows = []
        for i, res in enumerate(fm.results):
            row = {"index": i, "roi": [int(v) for v in fm.rois[i]],
                   "centre": [float(v) for v in fm.centres[i]],
                   "field_radius": float(fm.radius[i]), "error": fm.errors[i]}
            if res is not None:
                keep = res.freq <= 0.5 + 1e-9
                row.update(orientation=res.orientation, angle_deg=res.angle_deg,
                           mtf50=_finite(res.mtf50), mtf50_lpmm=_finite(res.mtf50_lpmm),
                           **{"mtf_at_0.25cpp": float(res.at(0.25))},
                           freq=[round(float(f), 5) for f in res.freq[keep]],
                           mtf=[round(float(m), 5) for m in res.mtf[keep]])
            rows.append(row)
        out["mtf"] = rows
        out["mtf_positions"] = fm.positions(4)
    return out, fm


def evaluate(image, truth=None, chart: bool = False, rois=None, *,
             pixel_pitch: float | None = None, oversample: int = 4, window: str = "hamming",
             progress: bool = False, data_range: float | None = None) -> dict:
    """Quality figures of a result image, as a JSON-ready dict.

    image: 2-D result; truth: 2-D reference of the same shape (gives ``psnr_db``, ``ssim``,
    compared as given with ``data_range``, default the truth's range); chart: find slanted-edge
    squares (on the truth if given, else on the image) and measure the MTF in each; rois:
    explicit list of (y0, y1, x0, x1) instead. Keys: ``shape``, ``psnr_db``, ``ssim``,
    ``field`` (MTF50 summary: ``centre_mtf50``, ``edge_mtf50``, ``edge_over_centre``;
    cycles/pixel), ``mtf`` (per ROI:
    roi, centre, field_radius, orientation, angle_deg, mtf50, freq, mtf up to 0.5 cycles/pixel,
    error), ``mtf_positions`` (ROI indices spread from centre to edge). Unavailable values
    (e.g. infinite PSNR, no MTF50) are None.
    """
    return evaluate_full(image, truth, chart, rois, pixel_pitch=pixel_pitch,
                         oversample=oversample, window=window, progress=progress,
                         data_range=data_range)[0]


def _csv_text(result: dict) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in result.get("mtf", []):
        y0, y1, x0, x1 = r["roi"]
        vals = [r["index"], y0, y1, x0, x1, f"{r['centre'][0]:.2f}", f"{r['centre'][1]:.2f}",
                f"{r['field_radius']:.4f}", r.get("orientation", ""),
                "" if r.get("angle_deg") is None else f"{r['angle_deg']:.3f}",
                "" if r.get("mtf50") is None else f"{r['mtf50']:.5f}",
                "" if r.get("mtf50_lpmm") is None else f"{r['mtf50_lpmm']:.3f}",
                "" if r.get("mtf_at_0.25cpp") is None else f"{r['mtf_at_0.25cpp']:.4f}",
                r.get("error") or ""]
        w.writerow(vals)
    return buf.getvalue()


def _summary_text(result: dict) -> str:
    lines = [f"image shape: {tuple(result['shape'])}"]
    if "ssim" in result:
        p = result["psnr_db"]
        lines.append(f"PSNR: {'inf' if p is None else f'{p:.3f}'} dB   SSIM: {result['ssim']:.4f}"
                     f"   (data range {result['data_range']:.4g})")
    if "field" in result:
        f = result["field"]

        def g(k):
            return "n/a" if f.get(k) is None else f"{f[k]:.4f}"

        lines.append(f"MTF ROIs: {f['n_rois']} ({f['n_measured']} measured)")
        lines.append(f"MTF50 centre: {g('centre_mtf50')} cycles/pixel   edge: {g('edge_mtf50')}"
                     f"   edge/centre: {g('edge_over_centre')}"
                     + (f"   (field radius {f['centre_radius']:.2f} / {f['edge_radius']:.2f})"
                        if "centre_radius" in f else ""))
        if f.get("n_above_nyquist"):
            lines.append(f"note: {f['n_above_nyquist']} ROI(s) read MTF50 above Nyquist "
                         "(0.5 cycles/pixel): edges sharpened past what the pixels sample "
                         "(a prior or ringing), not resolved detail")
        if "centre_mtf50_lpmm" in f:
            lines.append(f"MTF50 centre: {g('centre_mtf50_lpmm')} lp/mm   edge: "
                         f"{g('edge_mtf50_lpmm')} lp/mm")
    return "\n".join(lines) + "\n"


OUTPUT_FILES = ("evaluation.json", "evaluation.txt", "evaluation.csv", "mtf_curves.png",
                "mtf50_field.png", "images.png", "difference.png")  # write_evaluation's files


def write_evaluation(out_dir: str | Path, result: dict, fm: FieldMTF | None = None, *,
                     image=None, truth=None, name: str = "evaluation") -> list[Path]:
    """Write ``<name>.json``, ``<name>.csv`` (per-ROI table), ``<name>.txt`` (summary) and the
    figures (``mtf_curves.png``, ``mtf50_field.png``, ``images.png``) into ``out_dir``."""
    from metasensor.io.figures import save_image, save_panel
    from metasensor.metrics.plots import plot_field_map, plot_mtf_curves

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = [atomic_write_text(out / f"{name}.json", json.dumps(result, indent=1)),
               atomic_write_text(out / f"{name}.txt", _summary_text(result))]
    if "mtf" in result:
        written.append(atomic_write_text(out / f"{name}.csv", _csv_text(result)))
    if fm is not None and np.isfinite(fm.mtf50).any():
        written.append(plot_mtf_curves(out / "mtf_curves.png", fm))
        written.append(plot_field_map(out / "mtf50_field.png", fm, image))
    if image is not None:
        panels = [("result", np.asarray(image))]
        if truth is not None:
            panels += [("truth", np.asarray(truth)),
                       ("result - truth", np.asarray(image, float) - np.asarray(truth, float))]
        boxes = [tuple(r) for r in fm.rois] if fm is not None else None
        written.append(save_panel(out / "images.png", panels[:2], boxes=boxes,
                                  colorbar_label="intensity (image units)",
                                  suptitle="{1} x {0} px".format(*panels[0][1].shape)))
        if truth is not None:
            diff = panels[2][1]
            peak = float(np.max(np.abs(diff))) or 1.0  # symmetric: white is no difference
            written.append(save_image(out / "difference.png", diff, cmap="RdBu_r", vmin=-peak,
                                      vmax=peak, title="result - truth",
                                      colorbar_label="difference (image units)"))
    return written
