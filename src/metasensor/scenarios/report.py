"""What every scenario shares: its start (output folder, progress bar, clock) and its ending
(figures, ``summary.json`` and ``index.html``, atomically)."""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from metasensor.io.atomic import atomic_write_text

__all__ = ["write_report", "to_jsonable", "save_maps", "ScenarioRun", "scenario_run",
           "ScenarioSettings"]


@dataclass(frozen=True)
class ScenarioSettings:
    """The settings every scenario has (each scenario's settings extend them): blocks :
    multisite grid; snr_db : SNR of the captures (dB); iterations : ISA Richardson–Lucy
    iterations (None: the library's default solver); seed : noise (and the scenario's draws)."""

    blocks: tuple[int, int] = (2, 2)
    snr_db: float = 30.0
    iterations: int | None = None  # None: the library default (HQS); an int: Richardson–Lucy
    seed: int = 0


@dataclass(frozen=True)
class ScenarioRun:
    """A running scenario: its output folder, its progress bar (tqdm), its start time
    (``time.perf_counter()``, seconds) and the process's CPU time then
    (``time.process_time()``, seconds)."""

    out: Path
    steps: Any
    start: float
    cpu_start: float = 0.0

    def seconds(self) -> float:
        """Wall time since the start, seconds."""
        return time.perf_counter() - self.start

    def finish(self, summary: dict, figures: dict, title: str) -> dict:
        """Add the wall time (``seconds``), the process's CPU time (``cpu_seconds``, all its
        threads) and the figures' file names (``figures``) to ``summary``, write the report
        (:func:`write_report`) and count the last step; returns the summary as written."""
        summary = {**summary, "seconds": self.seconds(),
                   "cpu_seconds": time.process_time() - self.cpu_start,
                   "figures": {k: Path(v).name for k, v in figures.items()}}
        summary = write_report(self.out, summary, title)
        self.steps.update()
        return summary


@contextlib.contextmanager
def scenario_run(out: str | Path, desc: str, total: int, progress: bool) -> Iterator[ScenarioRun]:
    """Start a scenario: create ``out``, start the clock and a progress bar of ``total`` steps
    named ``desc`` (shown when ``progress``), closed when the scenario ends or fails."""
    from tqdm.auto import tqdm

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    with tqdm(total=total, desc=desc, disable=not progress) as steps:
        yield ScenarioRun(out, steps, start, time.process_time())


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
