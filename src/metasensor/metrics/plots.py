"""Figures of MTF measurements: curves at several field positions (like the paper's Fig. 2f) and
a map of MTF50 over the field. Written atomically through :mod:`metasensor.io.figures`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metasensor.io.figures import new_figure, save_figure, save_lines
from metasensor.metrics.field import FieldMTF

__all__ = ["plot_mtf_curves", "plot_field_map"]


def plot_mtf_curves(path: str | Path, fm: FieldMTF, *, n: int = 4, title: str | None = None,
                    fmax: float = 0.5) -> Path:
    """MTF curves of up to ``n`` ROIs spread from the field centre to the edge (cycles/pixel)."""
    idx = fm.positions(n)
    if not idx:
        raise ValueError("no successful MTF measurement to plot")
    series = []
    for i in idx:
        r = fm.results[i]
        keep = r.freq <= fmax + 1e-9
        series.append((f"field r = {fm.radius[i]:.2f} (MTF50 {fm.mtf50[i]:.3f})",
                       r.freq[keep], r.mtf[keep]))
    return save_lines(path, series, xlabel="spatial frequency (cycles/pixel)", ylabel="MTF",
                      title=title or "Slanted-edge MTF across the field", xlim=(0, fmax),
                      ylim=(0, 1.05), hlines=(0.5,))


def plot_field_map(path: str | Path, fm: FieldMTF, image=None, *, title: str | None = None
                   ) -> Path:
    """MTF50 at each ROI centre over the image (left) and MTF50 against field radius (right)."""
    fig, ax = new_figure(1, 2, size=(10.0, 4.2))
    a, b = ax[0, 0], ax[0, 1]
    h, w = fm.shape
    if image is not None:
        a.imshow(np.asarray(image), cmap="gray", interpolation="nearest")
    else:
        a.set_xlim(-0.5, w - 0.5)
        a.set_ylim(h - 0.5, -0.5)
    ok = np.isfinite(fm.mtf50)
    sc = a.scatter(fm.centres[ok, 1], fm.centres[ok, 0], c=fm.mtf50[ok], cmap="viridis", s=28,
                   edgecolors="k", linewidths=0.4)
    if (~ok).any():
        a.scatter(fm.centres[~ok, 1], fm.centres[~ok, 0], marker="x", c="tab:red", s=24,
                  label="failed")
        a.legend(fontsize=8, loc="lower right")
    if ok.any():
        fig.colorbar(sc, ax=a, fraction=0.046, pad=0.04, label="MTF50 (cycles/pixel)")
    a.set_title("MTF50 over the field")
    a.set_axis_off()
    b.plot(fm.radius[ok], fm.mtf50[ok], "o", ms=4)
    b.set_xlabel("normalised field radius (0 centre, 1 corner)")
    b.set_ylabel("MTF50 (cycles/pixel)")
    b.set_xlim(0, 1)
    b.grid(alpha=0.3)
    s = fm.summary()
    b.set_title(f"centre {s['centre_mtf50']:.3f}, edge {s['edge_mtf50']:.3f} cycles/pixel")
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)
