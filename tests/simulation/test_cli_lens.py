"""The ``metasensor simulate`` command and the single-lens aberration model."""

import json
import math

import numpy as np
import pytest
import tifffile
from typer.testing import CliRunner

import metasensor as ms
from metasensor.cli import app
from metasensor.simulation.lens import SingleLens


def _run(args):
    # typer collapses a one-command app; with other stages' commands it is a group
    import typer

    group = hasattr(typer.main.get_command(app), "commands")
    return CliRunner().invoke(app, (["simulate"] if group else []) + args)


def test_cli_writes_a_capture(tmp_path, standin):
    out = tmp_path / "cap"
    res = _run(["--scene", "chart", "--size", "70", "--scan",
                                   "3", "--snr", "25", "--zernike", "4:0.3,6:0.2", "--out",
                                   str(out)])
    assert res.exit_code == 0, res.output
    names = {p.name for p in out.iterdir()}
    for name in ("frames.tif", "views.tif", "truth.tif", "sensor2d.tif", "hardware_ao.tif",
                 "wavefront.json", "wavefront.npy", "config.toml", "capture.json", "figure.png"):
        assert name in names
    frames = tifffile.imread(out / "frames.tif")
    cfg = ms.SystemConfig.from_toml(out / "config.toml")
    assert frames.dtype == np.uint16 and frames.shape == (9, 70, 70) and cfg.scan == 3
    from metasensor.io.views import read_views

    assert np.array_equal(read_views(out / "views.tif"), ms.realign(frames, cfg))
    wf = json.loads((out / "wavefront.json").read_text())
    assert wf["zernike"][3] == 0.3 and wf["zernike"][5] == 0.2
    meta = json.loads((out / "capture.json").read_text())
    assert abs(meta["snr_db"] - 25) < 0.5
    # the same folder again, aberration-free: the earlier wavefront.npy would contradict the
    # new wavefront.json, so it goes; files that are not the capture's stay
    (out / "notes.txt").write_text("mine")
    res = _run(["--scene", "chart", "--size", "70", "--scan", "3", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert not (out / "wavefront.npy").exists() and (out / "notes.txt").read_text() == "mine"
    assert json.loads((out / "wavefront.json").read_text())["zernike"] is None


def test_cli_bad_input(tmp_path, standin):
    res = _run(["--scene", "nope", "--size", "64", "--out",
                                   str(tmp_path)])
    assert res.exit_code != 0 and "unknown scene" in str(res.exception)
    res = _run(["--zernike", "4=1", "--size", "64", "--out",
                                   str(tmp_path)])
    assert res.exit_code != 0 and "--zernike" in str(res.exception)


def test_single_lens_aberrations_grow_with_field():
    # analytic scaling of third-order theory: astigmatism and field curvature ∝ r², coma ∝ r,
    # spherical constant; orientation follows the field azimuth (Noll 6/8 on the x axis, 5/7 off)
    cfg = ms.SystemConfig()
    f = SingleLens().field_zernike(cfg, (2048, 2048))
    z1, z2 = f(np.array(0.0), np.array(0.5)), f(np.array(0.0), np.array(1.0))
    assert z2[5] == pytest.approx(4 * z1[5]) and z2[3] == pytest.approx(4 * z1[3])
    assert z2[7] == pytest.approx(2 * z1[7]) and z2[10] == pytest.approx(z1[10])
    assert abs(z2[4]) < 1e-12 and abs(z2[6]) < 1e-12  # on the x axis: cos terms only
    diag = f(np.array(math.sqrt(0.5)), np.array(math.sqrt(0.5)))
    assert abs(diag[5]) < 1e-12 and diag[4] == pytest.approx(z2[5])
    assert np.allclose(f(np.array(0.0), np.array(0.0))[:10], 0)
    # magnitude: W222 = H²K/2 at the edge of a 2048-px field (4.71 mm, θ = 0.0349 rad)
    y = 0.135 / 20
    theta = 1024 * cfg.pixel_pitch / 0.135
    w222 = (y * theta) ** 2 / 0.135 / 2
    assert z2[5] == pytest.approx(w222 / (2 * math.sqrt(6)) / cfg.wavelength, rel=1e-9)
    with pytest.raises(ValueError, match="f_number"):
        SingleLens(f_number=0)


def test_single_lens_drives_a_field_dependent_capture(standin):
    from metasensor.simulation.capture import simulate

    cfg = ms.SystemConfig(sensor_shape=(132, 132))
    lens = SingleLens()
    cap = simulate(np.ones((132, 132), np.float32), lens.config(cfg), scan=3,
                   field_zernike=lens.field_zernike(cfg, (132, 132)), field_blocks=(2, 2),
                   comparison=False)
    g = cap.field_zernike
    assert g.shape == (2, 2, 11)
    # the four block centres sit symmetrically: same field curvature, mirrored astigmatism
    np.testing.assert_allclose(g[..., 3], g[0, 0, 3])
    np.testing.assert_allclose(g[0, 0, 4], -g[0, 1, 4])
    assert g[0, 0, 3] > 0
