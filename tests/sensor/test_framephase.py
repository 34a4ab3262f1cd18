"""Rectified frames realigned without a calibration: each frame's lattice phase is measured and
frames taken in another scan order than the one given are refused, naming the order they fit."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
from typer.testing import CliRunner

from metasensor.cli import app
from metasensor.sensor.framephase import lattice_shift, phase_checked
from metasensor.sensor.scan import scan_order

runner = CliRunner()


def _frames(nnum, scan, order, seed=0, size=150):
    """Rectified moving-MLA frames: a textured scene times a lenslet pattern whose lattice is
    shifted by each phase's nominal offset."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[:size, :size]
    scene = 1 + 0.5 * np.sin(x / 7.0) * np.cos(y / 11.0) + 0.2 * rng.random((size, size))
    step = nnum // scan
    out = []
    for r, c in order:
        u, v = (y - r * step) % nnum - nnum // 2, (x - c * step) % nnum - nnum // 2
        pupil = (np.hypot(u, v) < 0.4 * nnum).astype(float)
        out.append(scene * pupil + 0.01 * rng.random((size, size)))
    return np.array(out)


@pytest.mark.parametrize("nnum, scan", [(15, 5), (15, 3)])
def test_lattice_shift_measures_the_phase(nnum, scan):
    order = scan_order(scan, "serpentine")
    frames = _frames(nnum, scan, order)
    got = np.array([lattice_shift(f, nnum) for f in frames])
    dev = (got - got[0]) - (nnum // scan) * np.array(order, float)
    dev -= nnum * np.round(dev / nnum)
    assert np.abs(dev).max() < 0.1
    assert len(list(phase_checked(frames, nnum, scan, order))) == len(frames)  # none refused


def test_lattice_shift_none_without_lattice():
    rng = np.random.default_rng(1)
    assert lattice_shift(rng.random((150, 150)), 15) is None
    assert lattice_shift(np.zeros((150, 150)), 15) is None
    assert lattice_shift(np.ones((40, 40)), 15) is None


@pytest.mark.parametrize("nnum, scan", [(15, 5), (15, 3)])
def test_wrong_order_is_refused_naming_the_fit(nnum, scan):
    frames = _frames(nnum, scan, scan_order(scan, "serpentine"))
    with pytest.raises(ValueError, match=r"not in row-major order \(they fit serpentine\)"):
        list(phase_checked(frames, nnum, scan, scan_order(scan, "row-major")))


def test_later_frame_out_of_place_is_refused():
    order = scan_order(3, "row-major")
    frames = _frames(15, 3, order + order)
    frames[12] = frames[13]  # frame 12 (phase (1, 0)) taken at phase (1, 1)
    with pytest.raises(ValueError, match="^frame 12 sits 5.0 px"):
        list(phase_checked(frames, 15, 3, order))


def test_realign_without_calib_refuses_another_order(tmp_path):
    frames = np.round(3000 * _frames(15, 5, scan_order(5, "serpentine"))).astype(np.uint16)
    tifffile.imwrite(tmp_path / "raw.tif", frames, metadata=None)
    res = runner.invoke(app, ["realign", str(tmp_path / "raw.tif"), "--out",
                              str(tmp_path / "v.tif")])
    assert res.exit_code != 0
    assert "they fit serpentine" in str(res.exception) + res.output
    assert not (tmp_path / "v.tif").exists()
    res = runner.invoke(app, ["realign", str(tmp_path / "raw.tif"), "--scan-order",
                              "serpentine", "--out", str(tmp_path / "v.tif")])
    assert res.exit_code == 0, res.output
