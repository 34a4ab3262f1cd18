"""The plugin's pipeline widgets (npe2 ``widgets`` contributions): Calibrate, Realign,
Reconstruct, Motion, Depth and Evaluate.

Each is a :class:`~metasensor.napari.widgets.CommandWidget` over the ``metasensor`` command of
the same name: it runs that command (no second implementation), writes into the output folder
chosen in the form (with ``summary.json``: the settings and the command line that repeats the
run) and shows what the command wrote as layers, read by the plugin's reader.
"""

from __future__ import annotations

from pathlib import Path

import napari

from metasensor.napari import readers
from metasensor.napari.widgets import CommandWidget

__all__ = ["CalibrateWidget", "RealignWidget", "ReconstructWidget", "MotionWidget",
           "DepthWidget", "EvaluateWidget", "add_layers"]

_ORDERS = ["row-major", "serpentine"]


def add_layers(viewer, tuples) -> list:
    """Add layer data tuples to ``viewer``, replacing layers read from the same file before
    (a re-run shows its new result, not a second copy)."""
    from napari.layers import Layer

    added = []
    for data, kwargs, kind in tuples:
        source = kwargs.get("metadata", {}).get("metasensor", {}).get("source")
        for old in [la for la in viewer.layers
                    if source and la.metadata.get("metasensor", {}).get("source") == source]:
            viewer.layers.remove(old)
        added.append(viewer.add_layer(Layer.create(data, kwargs, kind)))
    return added


def _prefill(viewer, widget: CommandWidget, name: str, kinds) -> None:
    """Start the input field at the file of the selected layer when it is of a fitting kind."""
    layer = viewer.layers.selection.active if viewer is not None else None
    meta = layer.metadata.get("metasensor", {}) if layer is not None else {}
    if meta.get("kind") in kinds and meta.get("source"):
        widget.fields[name].value = meta["source"]


def _names(command: str) -> set[str]:
    from metasensor.napari.widgets import cli_params

    return {p.name for p in cli_params(command)}


def _show_folder(widget: CommandWidget, result) -> None:
    add_layers(widget.viewer, readers.read_result_folder(result.out))


def _show_views(widget: CommandWidget, result) -> None:
    add_layers(widget.viewer, [readers.read_views_file(result.out / widget.out_name)])


class CalibrateWidget(CommandWidget):
    """Calibrate: the lenslet grid found on a white (or textured) frame, drawn over that frame,
    with the fit's figures (pitch, rotation, centre, lenslets kept, scan-phase offsets)."""

    def __init__(self, napari_viewer: napari.viewer.Viewer | None = None) -> None:
        super().__init__(napari_viewer, "calibrate", ["white", "out", "config", "scan", "order",
                                                      "moving", "flat"],
                         choices={"order": _ORDERS, "moving": ["mla", "image"]},
                         out_name="calib.toml", on_done=_show_calibration)
        _prefill(napari_viewer, self, "white", ("frames",))


def _show_calibration(widget: CommandWidget, result) -> None:
    from metasensor.config import SystemConfig
    from metasensor.io.views import read_config_from_views
    from metasensor.sensor.calibration import Calibration

    run = widget.job.run
    white = Path(run.inputs[0])
    calib = Calibration.from_toml(result.out / "calib.toml")
    config = dict(run.options).get("--config")
    cfg = SystemConfig.from_toml(config) if config else read_config_from_views(white,
                                                                               strict=False)
    pitch = cfg.pixel_pitch if cfg is not None else SystemConfig().mla_pitch / calib.nnum
    frames = readers._read_frames(white)
    grid = readers.read_calibration(result.out / "calib.toml", pixel_pitch=pitch)
    add_layers(widget.viewer, [frames, grid])
    lines = [ln for ln in result.stdout.strip().splitlines() if not ln.startswith("->")]
    lines.append(f"lattice contrast {calib.contrast:.3f} (lattice peak over mean, 0..1)")
    widget.status.value = "\n".join(lines)


class RealignWidget(CommandWidget):
    """Realign: raw frames (and a calibration) into a view stack, shown as (u, v, y, x)."""

    def __init__(self, napari_viewer: napari.viewer.Viewer | None = None) -> None:
        super().__init__(napari_viewer, "realign",
                         ["raw_path", "out", "calib_path", "config", "scan", "order", "moving",
                          "offsets", "method", "apply_flat", "dtype"],
                         choices={"order": _ORDERS, "moving": ["mla", "image"],
                                  "offsets": ["measure", "calib", "nominal"],
                                  "method": ["lanczos", "spline", "cubic"],
                                  "dtype": ["float32", "input"]},
                         out_name="views.tif", on_done=_show_views)
        _prefill(napari_viewer, self, "raw_path", ("frames",))


class ReconstructWidget(CommandWidget):
    """Reconstruct: ISA with multisite blocks and DAO; shows the image and the per-block
    wavefronts (a grid of pupil maps beside the image, one per block)."""

    def __init__(self, napari_viewer: napari.viewer.Viewer | None = None) -> None:
        super().__init__(napari_viewer, "reconstruct",
                         ["views", "out", "config", "method", "blocks", "overlap", "solver",
                          "register_views", "iterations", "subsets", "view_radius", "zernike",
                          "field_zernike", "system", "psf", "device", "zarr_out"],
                         choices={"method": ["isa", "wave", "geometric"],
                                  "solver": ["hqs", "rl"], "device": ["cpu", "cuda"]},
                         on_done=_show_folder)
        _prefill(napari_viewer, self, "views", ("views",))


class MotionWidget(CommandWidget):
    """Motion: scan artefacts of moving objects removed; the corrected views as a layer."""

    def __init__(self, napari_viewer: napari.viewer.Viewer | None = None) -> None:
        super().__init__(napari_viewer, "motion",
                         ["views", "out", "scan_order", "period", "reference", "mode",
                          "flow_view", "method", "scatter"],
                         choices={"scan_order": _ORDERS, "mode": ["object", "turbulence"],
                                  "method": ["dis", "farneback"],
                                  "scatter": ["linear", "cubic"]},
                         out_name="views.tif", on_done=_show_views)
        _prefill(napari_viewer, self, "views", ("views",))


class DepthWidget(CommandWidget):
    """Depth: disparity, image-side depth and confidence maps on the views' grid."""

    def __init__(self, napari_viewer: napari.viewer.Viewer | None = None) -> None:
        super().__init__(napari_viewer, "depth",
                         ["views", "out", "system", "config", "candidates", "disparity_range",
                          "occlusion", "radius", "device"],
                         choices={"device": ["cpu", "cuda"]}, on_done=_show_folder)
        _prefill(napari_viewer, self, "views", ("views",))


class EvaluateWidget(CommandWidget):
    """Evaluate: PSNR, SSIM and slanted-edge MTF; a metrics table and the MTF curves."""

    def __init__(self, napari_viewer: napari.viewer.Viewer | None = None) -> None:
        from magicgui import widgets as mw

        super().__init__(napari_viewer, "evaluate",
                         [n for n in ("result", "truth", "chart", "roi", "pixel_pitch",
                                      "data_range", "out") if n in _names("evaluate")],
                         on_done=_show_evaluation)
        self.table = mw.Table(value={"metric": [], "value": []}, name="metrics_table")
        self.append(self.table)
        self.metric_rows: dict = {"metric": [], "value": []}
        self.figure, self.canvas = _mtf_canvas()
        self.native.layout().addWidget(self.canvas)
        _prefill(napari_viewer, self, "result", ("image",))


def _mtf_canvas():
    from matplotlib.backends.backend_qtagg import FigureCanvasQTAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4, 2.6), tight_layout=True)
    canvas = FigureCanvasQTAgg(fig)
    canvas.setMinimumHeight(200)
    return fig, canvas


def metrics_rows(ev: dict) -> dict:
    """The metrics table of an ``evaluation.json``: PSNR/SSIM, the field's MTF50 summary and
    each ROI's MTF50 (cycles/pixel)."""
    rows: list[tuple[str, str]] = []
    for key in ("psnr_db", "ssim"):
        if ev.get(key) is not None:
            rows.append((key, f"{ev[key]:.4f}"))
    for key, value in (ev.get("field") or {}).items():
        if isinstance(value, float | int) and value is not None:
            rows.append((f"field {key}", f"{value:.4f}"))
    for r in ev.get("mtf", []):
        if r.get("mtf50") is not None:
            rows.append((f"ROI {r['index']} mtf50 (r {r['field_radius']:.2f})",
                         f"{r['mtf50']:.4f}"))
    return {"metric": [a for a, _ in rows], "value": [b for _, b in rows]}


def _show_evaluation(widget: CommandWidget, result) -> None:
    import json

    ev = json.loads((result.out / "evaluation.json").read_text())
    widget.metric_rows = metrics_rows(ev)
    widget.table.value = widget.metric_rows
    fig = widget.figure
    fig.clear()
    ax = fig.add_subplot(1, 1, 1)
    curves = [r for r in ev.get("mtf", []) if r.get("freq")]
    for r in curves:
        ax.plot(r["freq"], r["mtf"], lw=1, label=f"ROI {r['index']}")
    ax.axhline(0.5, color="0.6", lw=0.6, ls="--")
    ax.set_xlabel("cycles / pixel")
    ax.set_ylabel("MTF")
    ax.set_title("slanted-edge MTF" if curves else "no slanted edges measured")
    if 0 < len(curves) <= 8:
        ax.legend(fontsize=6)
    widget.canvas.draw_idle()

