"""Calibration of frames whose lenslet blocks tile the sensor from its first pixel (as
``simulate`` writes them: ``unrealign`` of views, the scan margin unlit): every lenslet that is
on the sensor at every phase is kept, the views' start on the sensor is stored as ``origin``,
and realign --calib reproduces the uncalibrated views. Analytic reference: the exact grid
(pitch 15 px, no rotation, lenslet (0, 0) centred on sensor pixel (7, 7) at phase (0, 0))."""

from __future__ import annotations

import json

import lf_synth as ls
import numpy as np
import pytest
from typer.testing import CliRunner

import metasensor as ms
from metasensor.cli import app
from metasensor.io.raw import write_raw
from metasensor.io.views import description, read_views, stored_extras
from metasensor.sensor.calibrate import calibrate
from metasensor.sensor.scan import scan_order

N = 15
CFG = ms.SystemConfig(scan=5)
ORDER = scan_order(5)


def pupil_views(ly=12, lx=12, seed=None):
    """Views (N, N, ly*5, lx*5) of a white (seed None) or textured scene behind the lenslets'
    pupil image, in DN."""
    u = np.arange(N) - (N - 1) / 2
    pup = ls.pupil(u[:, None], u[None, :])[:, :, None, None]
    scene = np.ones((ly * 5, lx * 5))
    if seed is not None:
        scene = np.random.default_rng(seed).uniform(0.3, 1.0, scene.shape)
    return np.round(3000 * pup * scene).astype(np.uint16)


def test_lenslets_tiling_the_sensor_edge_are_kept():
    white = ms.unrealign(pupil_views(), CFG, ORDER)  # (25, 192, 192), margin 12 px unlit
    assert white.shape[1:] == (192, 192)
    calib = calibrate(white[0], N, frames=white, scan=5)
    # every lenslet is on the sensor at every phase (first block at pixels 0..14 at phase 0,
    # last at 177..191 at phase (4, 4)): all 12 x 12 are kept (was 10 x 10: a 2-px border on
    # the block edges dropped the first and the last)
    assert calib.lenslets == (12, 12)
    np.testing.assert_allclose(calib.origin, (0.0, 0.0), atol=0.02)
    # the unlit scan margin does not bias the fit (was 15.012 px)
    assert abs(calib.pitch - N) < 0.002
    assert abs(calib.rotation) < 0.002
    assert np.abs(calib.offset_errors()).max() < 0.01


def test_lenslet_overhanging_the_sensor_is_dropped():
    # lenslet (0, 0) centred at (4, 4): its first pixels (centres at -3) are off the sensor
    frame = ls.render((150, 150), N, 15.0, 0.0, (4.0, 4.0), white=True)
    calib = calibrate(frame, N)
    np.testing.assert_allclose(calib.center, (19.0, 19.0), atol=0.02)
    # centres 19 + 15 k: k = 8 ends at pixel 146 (kept), k = 9 would end at 161 (off)
    assert calib.lenslets == (9, 9)


def test_realign_with_calibration_keeps_the_views_and_stores_their_origin(tmp_path):
    run = CliRunner().invoke
    desc = json.dumps(description(CFG, kind="frames", scan_order=[list(p) for p in ORDER],
                                  moving="mla"))
    write_raw(tmp_path / "white.tif", ms.unrealign(pupil_views(), CFG, ORDER), description=desc)
    views = pupil_views(seed=3)
    write_raw(tmp_path / "raw.tif", ms.unrealign(views, CFG, ORDER), description=desc)
    res = run(app, ["calibrate", str(tmp_path / "white.tif"), "--out",
                    str(tmp_path / "c.toml"), "--no-flat"])
    assert res.exit_code == 0, res.output
    assert "12x12 lenslets kept" in res.output
    res = run(app, ["realign", str(tmp_path / "raw.tif"), "--calib", str(tmp_path / "c.toml"),
                    "--offsets", "calib", "--out", str(tmp_path / "v.tif")])
    assert res.exit_code == 0, res.output
    got = read_views(tmp_path / "v.tif")
    assert got.shape == views.shape
    assert np.abs(got - views).max() <= 0.01 * views.max()
    np.testing.assert_allclose(stored_extras(tmp_path / "v.tif")["origin"], (0, 0), atol=0.02)
    res = run(app, ["realign", str(tmp_path / "raw.tif"), "--out", str(tmp_path / "w.tif")])
    assert res.exit_code == 0, res.output
    assert stored_extras(tmp_path / "w.tif")["origin"] == [0.0, 0.0]


def test_realign_with_calibration_names_the_bad_frame(tmp_path):
    # frame 3 holds the NaN: measuring offsets per frame used to call it "frame 0"
    run = CliRunner().invoke
    desc = json.dumps(description(CFG, kind="frames", scan_order=[list(p) for p in ORDER],
                                  moving="mla"))
    white = ms.unrealign(pupil_views(), CFG, ORDER)
    write_raw(tmp_path / "white.tif", white, description=desc)
    raw = white.astype(np.float32)
    raw[3, 50, 50] = np.nan
    write_raw(tmp_path / "raw.tif", raw, description=desc)
    res = run(app, ["calibrate", str(tmp_path / "white.tif"), "--out", str(tmp_path / "c.toml"),
                    "--no-flat"])
    assert res.exit_code == 0, res.output
    res = run(app, ["realign", str(tmp_path / "raw.tif"), "--calib", str(tmp_path / "c.toml"),
                    "--out", str(tmp_path / "v.tif")])
    assert res.exit_code != 0 and "frame 3" in str(res.exception)


def test_single_frame_calibration_leaves_room_for_the_stage_steps():
    # from one frame the offsets are nominal: a 2-px margin keeps realign working when the
    # stage's actual step differs (phase (4, 4) displaced by 1 px here; with no margin realign
    # stopped: "lenslet blocks leave the sensor"); measured offsets keep every lenslet. A
    # displacement beyond half the 3-px scan step puts the frame nearer another phase: refused
    from metasensor.sensor.rectify import rectify_frames
    from metasensor.sensor.reuse import frame_offset

    white = ms.unrealign(pupil_views(), CFG, ORDER).astype(np.float32)
    assert calibrate(white[0], N, frames=white, scan=5).lenslets == (12, 12)
    calib = calibrate(white[0], N, scan=5)
    assert calib.lenslets == (10, 10)
    for shift in (1, 2):
        frames = white.copy()
        frames[24] = np.roll(frames[24], (shift, shift), (0, 1))
        frames[24][:shift] = 0
        frames[24][:, :shift] = 0
        out = rectify_frames(list(frames), calib, ORDER,
                             offsets=lambda f, fr, ph: frame_offset(fr, calib, ph, index=f))
        if shift == 1:
            out = list(out)
            assert len(out) == 25 and all(np.isfinite(o).all() for o in out)
        else:
            with pytest.raises(ValueError, match=r"^frame 24 sits 2\.0 px from its nominal"):
                list(out)
