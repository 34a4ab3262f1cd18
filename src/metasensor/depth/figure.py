"""Figure of a depth result: centre view, disparity, metric depth and confidence, with units."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from metasensor.io.atomic import atomic_path

__all__ = ["depth_figure"]


def depth_figure(result, centre_view: np.ndarray | None, path: str | Path) -> Path:
    """Write a PNG with colour bars (disparity in view px per view step, depth in mm or m,
    confidence in [0, 1]); returns the path. Written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = []
    if centre_view is not None:
        panels.append(("centre view", np.asarray(centre_view), "gray", "intensity"))
    panels.append(("disparity", result.disparity, "turbo", "view px per view step"))
    if result.depth_kind == "object":
        panels.append(("object distance", result.depth, "turbo_r", "m from the main lens"))
    else:
        panels.append(("image-side depth", result.image_depth * 1e3, "turbo",
                       "mm in front of the MLA"))
    panels.append(("confidence", result.confidence, "viridis", "[0, 1]"))
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.0),
                             constrained_layout=True)
    for ax, (title, img, cmap, unit) in zip(axes, panels, strict=True):
        finite = np.isfinite(img)
        lo, hi = (np.percentile(img[finite], [1, 99]) if finite.any() else (0.0, 1.0))
        if title == "confidence":
            lo, hi = 0.0, 1.0
        im = ax.imshow(img, cmap=cmap, vmin=lo, vmax=hi if hi > lo else lo + 1e-9)
        ax.set_title(title)
        ax.set_axis_off()
        fig.colorbar(im, ax=ax, shrink=0.8, label=unit)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path
