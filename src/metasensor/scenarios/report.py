"""Shared ending of every scenario: figures, ``summary.json`` and ``index.html``, atomically."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from metasensor.io.atomic import atomic_write_text

__all__ = ["write_report", "to_jsonable", "save_maps"]


def to_jsonable(value):
    """NumPy scalars and arrays (and nested containers of them) as plain JSON values."""
    if isinstance(value, dict):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, np.floating | float):
        v = float(value)
        return v if np.isfinite(v) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def write_report(out: Path, summary: dict, title: str) -> dict:
    """Write ``summary.json`` and ``index.html`` (table + figures + settings) into ``out``."""
    from metasensor.report.html import write_html_report

    summary = to_jsonable(summary)
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2))
    write_html_report(out / "index.html", summary, title=title)
    return summary


def save_maps(path: Path, maps: dict[str, np.ndarray], title: str, unit: str) -> Path:
    """Heat maps side by side with one colour scale (e.g. resolved frequency over the field)."""
    from metasensor.io.figures import new_figure, save_figure

    fig, axes = new_figure(1, len(maps), size=(3.6 * len(maps), 3.4))
    lo = min(float(np.nanmin(m)) for m in maps.values())
    hi = max(float(np.nanmax(m)) for m in maps.values())
    for ax, (name, m) in zip(axes[0], maps.items(), strict=True):
        im = ax.imshow(m, vmin=lo, vmax=hi, cmap="viridis")
        for (i, j), v in np.ndenumerate(m):
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", color="w", fontsize=8)
        ax.set_title(name, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=list(axes[0]), shrink=0.8, label=unit)
    fig.suptitle(title)
    return save_figure(fig, path, tight=False)
