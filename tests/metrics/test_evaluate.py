"""evaluate(): PSNR/SSIM/MTF dict; `metasensor evaluate` CLI files and errors."""

import json
import subprocess
import sys
from functools import cache
from pathlib import Path

import numpy as np
import pytest
import tifffile
from typer.testing import CliRunner

from metasensor.metrics import evaluate
from metasensor.metrics import synthetic as S


@cache
def pair():
    truth, _ = S.render_square_chart(160, n=2, angle_deg=5.0, sigma=0.3)
    blurred, _ = S.render_square_chart(160, n=2, angle_deg=5.0, sigma=1.2)
    return truth.astype(np.float32), blurred.astype(np.float32)


def test_evaluate_dict():
    truth, img = pair()
    res = evaluate(img, truth, chart=True)
    assert res["shape"] == [160, 160]
    assert 10 < res["psnr_db"] < 60 and 0 < res["ssim"] < 1
    assert len(res["mtf"]) == 16  # 2 x 2 squares, 4 edges each
    assert all(r["mtf50"] is not None for r in res["mtf"])
    assert res["field"]["n_measured"] == 16
    json.dumps(res)  # JSON-ready
    only = evaluate(img, truth)
    assert "mtf" not in only and only["ssim"] == res["ssim"]
    roi = res["mtf"][0]["roi"]
    one = evaluate(img, rois=[roi])
    assert one["mtf"][0]["mtf50"] == pytest.approx(res["mtf"][0]["mtf50"])


def test_evaluate_errors():
    truth, img = pair()
    with pytest.raises(ValueError, match="nothing to evaluate"):
        evaluate(img)
    with pytest.raises(ValueError, match="shape"):
        evaluate(img, truth[:-1])
    bad = img.copy()
    bad[3, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        evaluate(bad, truth)


def group_app():
    # a command group holding this stage's commands (a Typer app with one command and no
    # callback would run that command without its name)
    import typer

    from metasensor.metrics.commands import register

    app = typer.Typer()
    app.callback()(lambda: None)
    register(app)
    return app


def test_cli_writes_outputs(tmp_path):
    app = group_app()
    truth, img = pair()
    tifffile.imwrite(tmp_path / "r.tif", img)
    tifffile.imwrite(tmp_path / "t.tif", truth)
    before = (tmp_path / "r.tif").read_bytes()
    out = tmp_path / "eval"
    res = CliRunner().invoke(app, ["evaluate", str(tmp_path / "r.tif"), "--truth",
                                   str(tmp_path / "t.tif"), "--chart", "--pixel-pitch", "4.6e-6",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    names = {p.name for p in out.iterdir()}
    assert {"evaluation.json", "evaluation.csv", "evaluation.txt", "mtf_curves.png",
            "mtf50_field.png", "images.png", "difference.png"} <= names
    assert not [n for n in names if n.startswith(".")]
    data = json.loads((out / "evaluation.json").read_text())
    assert data["field"]["centre_mtf50_lpmm"] > 0
    assert len((out / "evaluation.csv").read_text().splitlines()) == 1 + 16
    assert (tmp_path / "r.tif").read_bytes() == before
    res = CliRunner().invoke(app, ["evaluate", str(tmp_path / "r.tif"), "--roi",
                                   ",".join(map(str, data["mtf"][0]["roi"])), "--out",
                                   str(tmp_path / "e2")])
    assert res.exit_code == 0, res.output
    # the documented command has no --out: the folder defaults to <stem>_evaluation beside it
    res = CliRunner().invoke(app, ["evaluate", str(tmp_path / "r.tif"), "--truth",
                                   str(tmp_path / "t.tif")])
    assert res.exit_code == 0, res.output
    assert json.loads((tmp_path / "r_evaluation" / "evaluation.json").read_text())["ssim"] > 0


def test_cli_bad_input_one_line(tmp_path):
    src = str(Path(__file__).resolve().parents[2] / "src")
    code = ("from metasensor.cli import app, main\n"
            "if len(app.registered_commands) == 1: app.callback()(lambda: None)\n"
            "main()")
    tifffile.imwrite(tmp_path / "r.tif", np.zeros((8, 8), np.float32))
    whole = tmp_path / "whole.tif"
    tifffile.imwrite(whole, np.ones((64, 64), np.float32))
    (tmp_path / "cut.tif").write_bytes(whole.read_bytes()[:9000])  # a truncated result
    for args, msg in [(["missing.tif", "--truth", "x.tif", "--out", "o"], "not found"),
                      (["cut.tif", "--chart", "--out", "o"], "truncated or corrupt TIFF"),
                      ([str(tmp_path / "r.tif"), "--roi", "1,2,3", "--out", "o"], "--roi"),
                      ([str(tmp_path / "r.tif"), "--out", "o"], "nothing to evaluate")]:
        p = subprocess.run([sys.executable, "-c", code, "evaluate", *args], capture_output=True,
                           text=True, cwd=tmp_path, env={"PYTHONPATH": src, "PATH": ""})
        assert p.returncode == 2, p.stderr
        assert msg in p.stderr and len(p.stderr.strip().splitlines()) == 1
