"""Reports a person can read: settings as rows, blank MTF50 cells explained, a warning for a
demo too small to judge, figures with units, a colour bar or a key, and panels of one size."""

import matplotlib
import numpy as np
import pytest
from typer.testing import CliRunner

from metasensor import cli
from metasensor.io import figures
from metasensor.report import demo
from metasensor.report.html import write_html_report

matplotlib.use("Agg")


@pytest.fixture
def saved(monkeypatch):
    """Every figure passed to save_figure, kept open for inspection."""
    kept = []

    def keep(fig, path, **_):
        kept.append(fig)
        return path

    monkeypatch.setattr(figures, "save_figure", keep)
    return kept


def test_settings_are_rows_and_blank_mtf50_cells_are_explained(tmp_path):
    summary = {"warnings": ["too small"], "settings": {"size": 384, "blocks": (3, 3)},
               "table": [{"sensor": "2D sensor", "psnr_db": 14.7, "ssim": 0.53,
                          "centre_mtf50": None, "edge_mtf50": float("nan"),
                          "mtf_note": "none of the 12 slanted edges gave an MTF50"}],
               "seconds": 12.0}
    page = write_html_report(tmp_path / "index.html", summary).read_text()
    assert "{'size'" not in page and "<th>settings / size</th><td>384</td>" in page
    assert "<td>3, 3</td>" in page
    assert "none of the 12 slanted edges gave an MTF50" in page and "nan" not in page
    assert "mtf_note" not in page and "warning: too small" in page


def test_small_demo_warns_before_it_runs(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    assert demo.demo_warnings(demo.DemoSettings()) == []
    small = demo.DemoSettings(size=128, blocks=(2, 2))
    assert "too small to judge" in demo.demo_warnings(small)[0]

    class Stop(Exception):
        pass

    def stop(*_, **__):
        raise Stop

    monkeypatch.setattr("metasensor.simulation.capture.simulate", stop)
    with pytest.warns(UserWarning, match="too small to judge"), pytest.raises(Stop):
        demo.run_demo("unused", small, progress=False)
    res = CliRunner().invoke(cli.app, ["demo", "--size", "128", "--blocks", "2x2", "-o", "x"])
    assert isinstance(res.exception, Stop)
    assert "warning: a 128-px chart in 2x2 blocks (64-px blocks) is too small" in res.output


def test_comparison_panels_share_one_grid_and_a_colour_bar(saved, tmp_path):
    truth = np.random.default_rng(0).random((45, 45)).astype(np.float32)
    lf_image = np.random.default_rng(1).random((45, 45)).astype(np.float32)
    placed = demo._on_grid(lf_image, -6, truth.shape)  # the 1x1 grid starts 6 px earlier
    assert placed.shape == truth.shape
    np.testing.assert_array_equal(placed[6:, 6:], lf_image[:-6, :-6])
    assert np.isnan(placed[:6]).all() and np.isnan(placed[:, :6]).all()
    figures.save_panel(tmp_path / "p.png", [("truth", truth), ("light field", placed)],
                       colorbar_label="intensity (DN)")
    fig = saved[-1]
    images = [ax for ax in fig.axes if ax.images and ax.get_label() != "<colorbar>"]
    assert len(images) == 2 and len({ax.images[0].get_array().shape for ax in images}) == 1
    bars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(bars) == 1 and bars[0].get_ylabel() == "intensity (DN)"


def test_difference_image_has_a_symmetric_colour_bar(saved, tmp_path):
    from metasensor.metrics.evaluation import evaluate_full, write_evaluation

    truth = np.random.default_rng(2).random((32, 32)).astype(np.float32)
    image = truth + 0.1
    res, fm = evaluate_full(image, truth)
    write_evaluation(tmp_path, res, fm, image=image, truth=truth)
    diff = next(f for f in saved if any(ax.get_title() == "result - truth" for ax in f.axes))
    bar = next(ax for ax in diff.axes if ax.get_label() == "<colorbar>")
    assert "image units" in bar.get_ylabel()
    lo, hi = diff.axes[0].images[0].get_clim()
    assert lo == pytest.approx(-hi) and hi > 0


def test_calibration_arrows_have_a_key(monkeypatch, tmp_path):
    import matplotlib.pyplot as plt
    from matplotlib.quiver import QuiverKey

    from metasensor.sensor.calibration import Calibration
    from metasensor.sensor.commands import _calibration_figure

    kept = []
    monkeypatch.setattr(plt, "close", kept.append)
    offsets = tuple((0.003 * r, -0.002 * c) for r in range(3) for c in range(3))
    calib = Calibration(nnum=15, pitch=15.0, rotation=0.0, center=(7.0, 7.0), lenslets=(8, 8),
                        sensor_shape=(150, 150), scan=3,
                        scan_order=tuple((r, c) for r in range(3) for c in range(3)),
                        offsets=offsets)
    _calibration_figure(np.ones((150, 150), np.float32), calib, tmp_path / "c.png")
    keys = [a for ax in kept[-1].axes for a in ax.get_children() if isinstance(a, QuiverKey)]
    assert len(keys) == 1 and "px" in keys[0].text.get_text()
