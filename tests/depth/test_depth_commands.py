"""`metasensor depth` command: outputs, units in the metadata, figure, errors, input untouched."""

import json
import sys

import numpy as np
import pytest
import tifffile

import metasensor as ms
from metasensor.depth import synthetic
from metasensor.io.views import write_views


@pytest.fixture(scope="module")
def views_file(tmp_path_factory):
    cfg = ms.SystemConfig(scan=5, focal_length=0.05, focus_distance=2.0)
    tex = synthetic.random_texture((90, 90), seed=3)
    sv = synthetic.render_views(tex, [synthetic.Layer(np.ones((90, 90)), 0.9)], cfg,
                                snr_db=35, seed=2)
    path = tmp_path_factory.mktemp("depth") / "views.tif"
    write_views(path, sv.views, cfg)
    return path, sv


def _main(argv, monkeypatch):
    """Run the depth command as `metasensor depth ...` does (errors → one line, exit 2); the
    app is built here with a group callback so that it works whatever other stages register."""
    import typer

    from metasensor.depth.commands import register

    app = typer.Typer(add_completion=False, pretty_exceptions_enable=False)

    @app.callback()
    def _group() -> None:
        """metasensor (test copy)."""

    register(app)
    try:
        app(argv, standalone_mode=False)
    except (ValueError, TypeError, FileNotFoundError, OSError) as exc:  # as metasensor.cli.main
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


def test_depth_command_writes_maps_and_figure(views_file, tmp_path, monkeypatch):
    path, sv = views_file
    before = path.read_bytes()
    out = tmp_path / "out"
    code = _main(["depth", str(path), "--out", str(out), "--candidates", "32"], monkeypatch)
    assert code in (0, None)
    assert path.read_bytes() == before  # input never modified
    disp = tifffile.imread(out / "disparity.tif")
    assert disp.shape == sv.views.shape[2:] and disp.dtype == np.float32
    assert np.median(disp[5:-5, 5:-5]) == pytest.approx(0.3, abs=0.02)  # 0.9 image px / d = 3
    for name in ("confidence", "image_depth", "object_distance"):
        assert tifffile.imread(out / f"{name}.tif").shape == disp.shape
    with tifffile.TiffFile(out / "image_depth.tif") as tif:
        meta = json.loads(tif.pages[0].description)["metasensor"]
    assert meta["unit"].startswith("m ")
    summary = json.loads((out / "depth.json").read_text())
    assert summary["depth_kind"] == "object"
    assert summary["views_used"] == 113  # the configured pupil: the views beyond it are dark
    lo, hi = summary["disparity_p5_p95"]
    assert lo <= summary["median_disparity"] <= hi
    png = (out / "depth.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000


def test_depth_command_bad_input(views_file, tmp_path, monkeypatch, capsys):
    path, _ = views_file
    assert _main(["depth", str(tmp_path / "missing.tif"), "--out", str(tmp_path / "o")],
                 monkeypatch) == 2
    assert "not found" in capsys.readouterr().err
    assert _main(["depth", str(path), "--out", str(tmp_path / "o"), "--range", "a,b"],
                 monkeypatch) == 2
    assert "--range" in capsys.readouterr().err
    assert _main(["depth", str(path), "--out", str(tmp_path / "o"), "--system",
                  str(tmp_path / "nope.h5")], monkeypatch) == 2
    assert "system calibration not found" in capsys.readouterr().err
    # a stack without configuration needs --config
    bare = tmp_path / "bare.tif"
    tifffile.imwrite(bare, np.ones((225, 8, 8), np.float32))
    assert _main(["depth", str(bare), "--out", str(tmp_path / "o")], monkeypatch) == 2
    assert "--config" in capsys.readouterr().err


def test_depth_config_must_sample_like_the_stack(views_file, tmp_path, monkeypatch, capsys):
    path, _ = views_file
    ms.SystemConfig(scan=3).to_toml(tmp_path / "scan3.toml")
    assert _main(["depth", str(path), "--config", str(tmp_path / "scan3.toml"), "--out",
                  str(tmp_path / "o")], monkeypatch) == 2
    assert "scan = 3" in capsys.readouterr().err
