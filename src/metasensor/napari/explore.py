"""Explore a view stack: an epipolar-plane image (EPI) along a line the user draws, and the
pupil (u, v) intensity map of the lenslet under the cursor. The (u, v) sliders are napari's own
dimension sliders over the 4-D view layer.

EPI: along a line in the view plane, the profiles of the views in the centre row (line mostly
along x) or the centre column (mostly along y) of the pupil, stacked by view: a point at
disparity δ (view px per view step, docs/conventions.md) draws a line of slope δ in it.
Pupil map: the ``nnum × nnum`` samples ``views[:, :, Y, X]`` — the pixels behind the lenslet
that took view sample (Y, X), i.e. that lenslet's image of the main lens's pupil.
"""

from __future__ import annotations

import napari
import numpy as np
from magicgui import widgets as mw

__all__ = ["epi", "pupil_map", "ExploreWidget"]


def epi(views, p0, p1, samples: int | None = None) -> tuple[np.ndarray, str]:
    """Epipolar-plane image along the segment ``p0 → p1`` (view-sample (Y, X) coordinates).

    Parameters
    ----------
    views : (nnum, nnum, H, W) view stack.
    p0, p1 : segment end points (row, col) in view samples.
    samples : points along the segment (default: one per sample of its length, plus one).

    Returns
    -------
    (epi, axis) : ``epi`` (nnum, samples) float32, row k = view (c, k) (``axis == "v"``, a line
        mostly along x) or view (k, c) (``axis == "u"``), sampled bilinearly along the segment;
        outside the views: 0.
    """
    from scipy.ndimage import map_coordinates

    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    n = views.shape[0]
    if samples is None:
        samples = int(np.ceil(np.hypot(*(p1 - p0)))) + 1
    samples = max(2, int(samples))
    t = np.linspace(0.0, 1.0, samples)
    coords = p0[:, None] + (p1 - p0)[:, None] * t[None]
    axis = "v" if abs(p1[1] - p0[1]) >= abs(p1[0] - p0[0]) else "u"
    c = n // 2
    y0, x0 = np.floor(coords.min(axis=1)).astype(int) - 1
    y1, x1 = np.ceil(coords.max(axis=1)).astype(int) + 2
    y0, x0 = max(y0, 0), max(x0, 0)
    out = np.zeros((n, samples), np.float32)
    for k in range(n):
        uv = (c, k) if axis == "v" else (k, c)
        patch = np.asarray(views[uv[0], uv[1], y0:y1, x0:x1], dtype=np.float32)
        if patch.size:
            out[k] = map_coordinates(patch, coords - np.array([[y0], [x0]]), order=1,
                                     mode="constant", cval=0.0)
    return out, axis


def pupil_map(views, y: int, x: int) -> np.ndarray:
    """The (u, v) intensities of view sample (y, x): ``views[:, :, y, x]`` as float32."""
    return np.asarray(views[:, :, int(y), int(x)], dtype=np.float32)


def _canvas(height: int = 220):
    from matplotlib.backends.backend_qtagg import FigureCanvasQTAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(4, 2.4), tight_layout=True)
    canvas = FigureCanvasQTAgg(fig)
    canvas.setMinimumHeight(height)
    return fig, canvas


class ExploreWidget(mw.Container):
    """The Explore dock: pick a view-stack layer; draw a line (an "EPI line" shapes layer) for
    the EPI; move the cursor over the views for the pupil map."""

    def __init__(self, napari_viewer: napari.viewer.Viewer) -> None:
        super().__init__(labels=True)
        viewer = self.viewer = napari_viewer
        self.layer_box = mw.ComboBox(name="views", label="view stack",
                                     choices=self._views_layers,
                                     tooltip="the 4-D (u, v, y, x) layer to explore")
        self.line_button = mw.PushButton(text="Draw an EPI line")
        self.info = mw.Label(value="move the cursor over the views for the pupil map")
        self.extend([self.layer_box, self.line_button, self.info])
        self.epi_figure, self.epi_canvas = _canvas()
        self.pupil_figure, self.pupil_canvas = _canvas()
        self.native.layout().addWidget(self.epi_canvas)
        self.native.layout().addWidget(self.pupil_canvas)
        self.epi_image: np.ndarray | None = None
        self.pupil_image: np.ndarray | None = None
        self.pupil_at: tuple[int, int] | None = None
        self.line_layer = None
        self.line_button.changed.connect(self.start_line)
        viewer.layers.events.inserted.connect(self._refresh_choices)
        viewer.layers.events.removed.connect(self._refresh_choices)
        viewer.cursor.events.position.connect(self._on_cursor)

    def _views_layers(self, *_) -> list:
        return [(la.name, la) for la in self.viewer.layers
                if la.metadata.get("metasensor", {}).get("kind") == "views"]

    def _refresh_choices(self, *_) -> None:
        self.layer_box.reset_choices()

    @property
    def views(self):
        return self.layer_box.value

    # ------------------------------------------------------------------ EPI
    def start_line(self, *_) -> None:
        """Add (or select) the "EPI line" layer on the views' (y, x) grid, in line mode."""
        layer = self.views
        if layer is None:
            self.info.value = "open a view stack first"
            return
        if self.line_layer is None or self.line_layer not in self.viewer.layers:
            self.line_layer = self.viewer.add_shapes(
                ndim=2, name="EPI line", shape_type="line", edge_color="cyan",
                edge_width=0.5, scale=layer.scale[2:], translate=layer.translate[2:])
            self.line_layer.events.data.connect(self._on_line)
        self.viewer.layers.selection.active = self.line_layer
        self.line_layer.mode = "add_line"

    def _on_line(self, *_) -> None:
        if self.line_layer is None or not len(self.line_layer.data) or self.views is None:
            return
        p0, p1 = np.asarray(self.line_layer.data[-1])[[0, -1], -2:]
        self.show_epi(p0, p1)

    def show_epi(self, p0, p1) -> np.ndarray:
        """Compute and draw the EPI of the selected views along p0 → p1 (view samples)."""
        image, axis = epi(self.views.data, p0, p1)
        self.epi_image = image
        fig = self.epi_figure
        fig.clear()
        ax = fig.add_subplot(1, 1, 1)
        ax.imshow(image, cmap="gray", aspect="auto", interpolation="nearest")
        ax.set_xlabel("position along the line [view samples]")
        ax.set_ylabel(f"view {axis} (centre row)" if axis == "v" else "view u (centre column)")
        ax.set_title("epipolar-plane image")
        self.epi_canvas.draw_idle()
        return image

    # ------------------------------------------------------------------ pupil
    def _on_cursor(self, *_) -> None:
        layer = self.views
        if layer is None:
            return
        pos = layer.world_to_data(self.viewer.cursor.position)
        y, x = (int(round(float(v))) for v in pos[-2:])
        h, w = layer.data.shape[-2:]
        if 0 <= y < h and 0 <= x < w and (y, x) != self.pupil_at:
            self.show_pupil(y, x)

    def show_pupil(self, y: int, x: int) -> np.ndarray:
        """Draw the pupil (u, v) map of view sample (y, x) of the selected views."""
        image = pupil_map(self.views.data, y, x)
        self.pupil_image, self.pupil_at = image, (y, x)
        fig = self.pupil_figure
        fig.clear()
        ax = fig.add_subplot(1, 1, 1)
        ax.imshow(image, cmap="magma", interpolation="nearest")
        ax.set_xlabel("v")
        ax.set_ylabel("u")
        ax.set_title(f"pupil map of lenslet sample ({y}, {x})")
        self.pupil_canvas.draw_idle()
        return image

