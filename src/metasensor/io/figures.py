"""Small shared figure helpers (matplotlib, Agg backend), every file written atomically.

- :func:`save_figure`: save any matplotlib figure to PNG atomically and close it.
- :func:`save_image`: one grayscale image (optionally with a colour bar).
- :func:`save_panel`: images side by side with titles, one shared intensity range by default,
  optional rectangles (e.g. zoom boxes or ROIs) drawn on each panel.
- :func:`save_lines`: line plot of several curves (e.g. MTF curves, scan-period studies).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from metasensor.io.atomic import atomic_path

__all__ = ["new_figure", "save_figure", "save_image", "save_panel", "save_lines"]


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def new_figure(nrows: int = 1, ncols: int = 1, *, size: tuple[float, float] | None = None):
    """A new figure and its axes array (``squeeze=False``) on the Agg backend."""
    plt = _plt()
    if size is None:
        size = (4.0 * ncols, 3.6 * nrows)
    return plt.subplots(nrows, ncols, figsize=size, squeeze=False)


def save_figure(fig, path: str | Path, *, dpi: int = 110, tight: bool = True) -> Path:
    """Write ``fig`` to ``path`` (PNG) atomically and close it (``tight``: tight_layout first;
    off for figures laid out by hand, e.g. a colorbar shared by an axes grid)."""
    plt = _plt()
    path = Path(path)
    try:
        if tight:
            fig.tight_layout()
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=dpi)
    finally:
        plt.close(fig)
    return path


def _check_image(image, name: str = "image") -> np.ndarray:
    a = np.asarray(image)
    if a.ndim != 2:
        raise ValueError(f"{name} must be a 2-D image (H, W), got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise TypeError(f"{name} must be a real numeric array, got dtype {a.dtype}")
    return a


def _finite_range(arrays: Sequence[np.ndarray]) -> tuple[float, float]:
    vals = [a[np.isfinite(a)] for a in arrays]
    vals = [v for v in vals if v.size]
    if not vals:
        return 0.0, 1.0
    lo = min(float(v.min()) for v in vals)
    hi = max(float(v.max()) for v in vals)
    return (lo, hi if hi > lo else lo + 1.0)


def save_image(path: str | Path, image, *, title: str | None = None, cmap: str = "gray",
               vmin: float | None = None, vmax: float | None = None, colorbar: bool = False,
               colorbar_label: str | None = None, dpi: int = 110) -> Path:
    """Save a 2-D image ``[y, x]`` as a PNG figure (row 0 at the top), atomically; a colour bar
    (labelled with ``colorbar_label``, its units) if ``colorbar`` or a label is given."""
    a = _check_image(image)
    lo, hi = _finite_range([a])
    h, w = a.shape
    scale = 6.0 / max(h, w)
    bar = colorbar or bool(colorbar_label)
    fig, ax = new_figure(size=(max(2.5, w * scale + (1.2 if bar else 0.3)),
                               max(2.5, h * scale + 0.6)))
    im = ax[0, 0].imshow(a, cmap=cmap, vmin=lo if vmin is None else vmin,
                         vmax=hi if vmax is None else vmax, interpolation="nearest")
    ax[0, 0].set_axis_off()
    if title:
        ax[0, 0].set_title(title)
    if colorbar or colorbar_label:
        fig.colorbar(im, ax=ax[0, 0], fraction=0.046, pad=0.04, label=colorbar_label)
    return save_figure(fig, path, dpi=dpi)


def save_panel(path: str | Path, images: Sequence[tuple[str, np.ndarray]] | Mapping, *,
               ncols: int | None = None, cmap: str = "gray", shared_range: bool = True,
               suptitle: str | None = None,
               boxes: Sequence[tuple[float, float, float, float]] | None = None,
               colorbar_label: str | None = None, dpi: int = 110) -> Path:
    """Images side by side, each with its title; one intensity range for all if ``shared_range``.

    images: list of (title, 2-D array) or a mapping title -> array; boxes: rectangles
    ``(y0, y1, x0, x1)`` in pixels drawn on every panel; colorbar_label: draw one colour bar
    for the shared range with this label (its units, e.g. ``"intensity (DN)"``). Panels of
    arrays of one shape are drawn at one size.
    """
    items = list(images.items()) if isinstance(images, Mapping) else list(images)
    if not items:
        raise ValueError("images is empty: nothing to draw")
    arrays = [_check_image(a, f"image {t!r}") for t, a in items]
    n = len(items)
    ncols = n if ncols is None else max(1, min(int(ncols), n))
    nrows = math.ceil(n / ncols)
    bar = colorbar_label is not None and shared_range
    fig, axes = new_figure(nrows, ncols, size=(3.6 * ncols + (0.8 if bar else 0),
                                               3.6 * nrows + 0.4))
    if bar:
        fig.set_layout_engine("constrained")
    shared = _finite_range(arrays)
    im = None
    for i, ax in enumerate(axes.ravel()):
        ax.set_axis_off()
        if i >= n:
            continue
        lo, hi = shared if shared_range else _finite_range([arrays[i]])
        im = ax.imshow(arrays[i], cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest")
        ax.set_title(str(items[i][0]), fontsize=10)
        for y0, y1, x0, x1 in boxes or ():
            ax.add_patch(_rect(y0, y1, x0, x1))
    if bar:
        fig.colorbar(im, ax=list(axes.ravel()), fraction=0.025, pad=0.02, label=colorbar_label)
    if suptitle:
        fig.suptitle(suptitle)
    return save_figure(fig, path, dpi=dpi, tight=not bar)


def _rect(y0, y1, x0, x1, color: str = "tab:red"):
    from matplotlib.patches import Rectangle

    return Rectangle((x0 - 0.5, y0 - 0.5), x1 - x0, y1 - y0, fill=False, edgecolor=color, lw=1.0)


def save_lines(path: str | Path, series: Sequence[tuple[str, np.ndarray, np.ndarray]], *,
               xlabel: str = "", ylabel: str = "", title: str | None = None,
               xlim: tuple[float, float] | None = None, ylim: tuple[float, float] | None = None,
               hlines: Sequence[float] = (), styles: Sequence[str] | None = None,
               dpi: int = 110) -> Path:
    """Line plot of several curves ``(label, x, y)``; optional horizontal reference lines."""
    if not series:
        raise ValueError("series is empty: nothing to plot")
    fig, ax = new_figure(size=(5.5, 4.0))
    a = ax[0, 0]
    for i, (label, x, y) in enumerate(series):
        x = np.asarray(x, float)
        y = np.asarray(y, float)
        if x.shape != y.shape or x.ndim != 1:
            raise ValueError(f"series {label!r}: x and y must be 1-D of equal length, got "
                             f"{x.shape} and {y.shape}")
        a.plot(x, y, styles[i] if styles else "-", label=str(label), lw=1.4)
    for h in hlines:
        a.axhline(h, color="0.6", lw=0.8, ls=":")
    a.set_xlabel(xlabel)
    a.set_ylabel(ylabel)
    if title:
        a.set_title(title)
    if xlim:
        a.set_xlim(*xlim)
    if ylim:
        a.set_ylim(*ylim)
    a.grid(alpha=0.3)
    a.legend(fontsize=8)
    return save_figure(fig, path, dpi=dpi)
