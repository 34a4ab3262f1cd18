"""The demo's measurements: bar groups per location, fringe ratio, resolved frequency, the
2D / meta-imaging ratio (a lower bound where the 2D sensor resolves nothing), the printed lines
and the comparison figure (panels of one size, colour bars for intensity and differences)."""

from types import SimpleNamespace

import matplotlib
import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from metasensor.config import SystemConfig
from metasensor.io import figures
from metasensor.report.commands import bar_lines
from metasensor.report.demo_measure import comparison_figure, measure
from metasensor.simulation.bars import bar_chart

matplotlib.use("Agg")


def test_bar_rows_fringe_and_resolved_frequency():
    truth = bar_chart(256)
    results = {"2D sensor": (gaussian_filter(truth, 4.0), truth),
               "meta-imaging sensor (5x5 scan)": (gaussian_filter(truth, 0.7), truth)}
    table = [{"sensor": k} for k in results]
    places = {k: (0, (truth.shape, (3, 3), 3)) for k in results}
    rows = measure(table, results, places, 256, bars="rows")
    assert {r["location"] for r in rows} >= {"centre", "top-left", "bottom-right"}
    centre = next(r for r in rows if r["location"] == "centre")
    assert centre["meta-imaging sensor (5x5 scan)"] < 5 and (
        centre["2D sensor"] is None or centre["2D sensor"] > 10)
    assert centre["gain_2d_over_meta"] > 2
    assert table[1]["resolved_cpp"] > table[0]["resolved_cpp"] > 0
    assert all(np.isfinite(r["fringe_ratio"]) for r in table)
    lines = bar_lines(rows)
    assert lines[0].startswith("finest resolved bar group") and len(lines) == len(rows) + 1
    assert any("centre" in ln and "x" in ln for ln in lines)
    assert measure([{"sensor": "2D sensor"}], results, places, 256, bars=None) == []


@pytest.fixture
def saved(monkeypatch):
    kept = []
    monkeypatch.setattr(figures, "save_figure", lambda fig, path, **_: kept.append(fig) or path)
    return kept


def test_comparison_figure_has_panels_of_one_size_and_two_colour_bars(saved, tmp_path):
    truth = np.random.default_rng(0).random((45, 45)).astype(np.float32)
    cfg = SystemConfig()
    cap = SimpleNamespace(truth=truth, config=cfg)
    lf = SimpleNamespace(truth=truth[:40, :40], config=cfg.replace(scan=1))
    results = {"2D sensor": (truth + 0.1, truth), "plain": (truth[:40, :40], lf.truth),
               "meta": (truth - 0.05, truth)}
    comparison_figure(tmp_path / "c.png", cap, lf, results)
    fig = saved[-1]
    shown = [ax for ax in fig.axes if ax.images and ax.get_label() != "<colorbar>"]
    assert len(shown) == 7 and len({ax.images[0].get_array().shape for ax in shown}) == 1
    bars = sorted(ax.get_ylabel() for ax in fig.axes if ax.get_label() == "<colorbar>")
    assert bars == ["difference (DN)", "intensity (DN)"]
    lo, hi = shown[-1].images[0].get_clim()
    assert -lo == hi > 0
