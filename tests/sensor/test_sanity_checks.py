"""No silent garbage: realign refuses frames whose lenslet period is not the configured nnum,
calibrate reports its goodness of fit and refuses a fit that does not describe the field, a
sparse bead scan calibrates from all its frames, and a TOML that leaves the optics to the
prototype says so. Frames come from the continuous light-field model of ``lf_synth`` (a known
pitch, rotation and centre; a bead scene moved over a fixed MLA by 13/3 px per scan step)."""

from __future__ import annotations

import re
import sys

import lf_synth as ls
import numpy as np
import pytest
from typer.testing import CliRunner

from metasensor.cli import app
from metasensor.config import SystemConfig
from metasensor.io.raw import write_raw
from metasensor.sensor.calibrate import calibrate
from metasensor.sensor.checks import lattice_period
from metasensor.sensor.scan import scan_order

runner = CliRunner()
ORDER = scan_order(3, "spiral")


def render_beads(shape, nnum, pitch, rot, center, beads, shift, sigma=4.0):
    """Raw frame of in-focus beads (rectified positions ``beads``, image moved by ``shift``
    rectified px): each lenslet spreads the light its aperture collects over its pupil image,
    so a lenslet's pixels are its bead light (a Gaussian image of ``sigma`` px sampled at the
    lenslet centre) times the vignetted pupil disc."""
    m = ls.matrix(pitch, rot, nnum)
    yy, xx = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
    q = np.tensordot(np.linalg.inv(m), np.stack([yy - center[0], xx - center[1]]), axes=1)
    cell = np.round(q / nnum)
    local = q - nnum * cell
    lc = cell * nnum + (nnum - 1) / 2 + np.asarray(shift, float)[:, None, None]
    light = np.zeros(shape)
    for by, bx in beads:
        light += np.exp(-((lc[0] - by) ** 2 + (lc[1] - bx) ** 2) / (2 * sigma**2))
    return light * ls.pupil(local[0], local[1])


def image_scan(shape, pitch, rot, center, beads, nnum=13):
    """The 9 frames of a 3 x 3 image scan (steps of nnum/3 rectified px) in ORDER."""
    step = nnum / 3
    return np.stack([render_beads(shape, nnum, pitch, rot, center, beads, (r * step, c * step))
                     for r, c in ORDER])


@pytest.fixture(scope="module")
def bead_scan():
    shape = (286, 299)
    pitch, rot, center = 13.04, 0.3, (9.4, 11.2)
    rng = np.random.default_rng(3)
    frames = image_scan(shape, pitch, rot, center, rng.uniform(0, 1, (45, 2)) * shape)
    return dict(frames=np.round(4000 * frames / frames.max()).astype(np.uint16), pitch=pitch,
                rot=rot)


def test_sparse_bead_scan_calibrates_from_all_frames(bead_scan):
    frames = bead_scan["frames"]
    ref = frames[ORDER.index((0, 0))]
    cal = calibrate(ref, 13, frames=list(frames), scan=3, scan_order=ORDER, moving="image")
    assert abs(cal.pitch - bead_scan["pitch"]) < 0.05
    assert abs(cal.rotation - bead_scan["rot"]) < 0.02
    assert cal.peak_strength > 8 and cal.fit_residual is not None and cal.fit_residual < 0.3
    # the periodicity check agrees (nnum 13, within 2 %)
    period, strength = lattice_period(frames, 13)
    assert abs(period - bead_scan["pitch"]) < 0.1 and strength > 12


def test_untrustworthy_fit_is_refused():
    """Two lattices side by side (13.0 and 13.8 px): no single grid fits the field."""
    shape = (260, 312)
    left = ls.render(shape, 13, 13.0, 0.0, (6.0, 6.0), white=True)
    right = ls.render(shape, 13, 13.8, 0.0, (6.0, 6.0), white=True)
    frame = np.where(np.arange(shape[1])[None, :] < shape[1] // 2, left, right)
    with pytest.raises(ValueError, match="untrustworthy .* white frame, or from more frames"):
        calibrate(frame, 13)


def test_realign_refuses_frames_of_another_lenslet_size(tmp_path, bead_scan):
    """13-px lenslets realigned as the default 15-px ones: exit 2, one line naming both."""
    write_raw(tmp_path / "beads.tif", bead_scan["frames"])
    res = runner.invoke(app, ["realign", str(tmp_path / "beads.tif"), "--scan", "3", "--out",
                              str(tmp_path / "views.tif")])
    assert isinstance(res.exception, ValueError), res.output  # the CLI: exit 2, "error: ..."
    msg = str(res.exception)
    assert "\n" not in msg and re.search(r"measures 1[23]\.\d\d px", msg) and "nnum is 15" in msg
    assert not (tmp_path / "views.tif").exists()


def test_toml_leaving_optics_to_the_prototype_says_so_once(tmp_path, bead_scan, monkeypatch,
                                                          capsys):
    from metasensor.cli import main

    (tmp_path / "cfg.toml").write_text('[system]\nnnum = 13\nscan = 3\nmoving = "image"\n')
    write_raw(tmp_path / "beads.tif", bead_scan["frames"])

    def cli(*args):
        monkeypatch.setattr(sys, "argv", ["metasensor", *map(str, args)])
        with pytest.raises(SystemExit) as info:
            main()
        assert info.value.code in (0, None)
        return capsys.readouterr().err

    err = cli("realign", tmp_path / "beads.tif", "--config", tmp_path / "cfg.toml", "--out",
              tmp_path / "v.tif")
    notes = [ln for ln in err.splitlines() if "does not set" in ln]
    assert len(notes) == 1 and "na" in notes[0] and "wavelength" in notes[0]
    full = SystemConfig(nnum=13, scan=3, moving="image", mla_pitch=69e-6, mla_focal=690e-6,
                        wavelength=520e-9, na=0.05)
    full.to_toml(tmp_path / "full.toml")
    err = cli("realign", tmp_path / "beads.tif", "--config", tmp_path / "full.toml", "--out",
              tmp_path / "w.tif")
    assert "does not set" not in err


def test_a_note_left_by_a_failed_command_is_not_said_by_the_next(tmp_path, bead_scan,
                                                                 monkeypatch, capsys):
    from metasensor.cli import main
    from metasensor.config_text import note_fallbacks

    # an earlier command of this process read a TOML and failed before its optics were used
    stale = SystemConfig(nnum=13, scan=3, moving="image", wavelength=600e-9)
    note_fallbacks(tmp_path / "stale.toml", "nnum = 13\n", stale)
    write_raw(tmp_path / "beads.tif", bead_scan["frames"])
    full = SystemConfig(nnum=13, scan=3, moving="image", mla_pitch=69e-6, mla_focal=690e-6,
                        wavelength=520e-9, na=0.05)
    full.to_toml(tmp_path / "full.toml")
    monkeypatch.setattr(sys, "argv", ["metasensor", "realign", str(tmp_path / "beads.tif"),
                                      "--config", str(tmp_path / "full.toml"), "--out",
                                      str(tmp_path / "v.tif")])
    with pytest.raises(SystemExit) as info:
        main()
    assert info.value.code in (0, None)
    assert "does not set" not in capsys.readouterr().err


@pytest.mark.parametrize("nnum", [5, 9, 13, 15, 21])
def test_lattice_period_is_measured_whatever_nnum_is_configured(nnum):
    """The period is searched over every lenslet size, not only near the configured nnum, and
    harmonics (p/2, p/3...) are taken down to the fundamental."""
    frame = ls.render((24 * nnum, 24 * nnum), nnum, float(nnum), 0.2, (5.0, 5.0))
    for configured in (15, nnum):
        period, strength = lattice_period([frame], configured)
        assert abs(period - nnum) < 0.02 * nnum and strength >= 12, (configured, period)


def nine_px_scan(shape=(216, 216)):
    """The 9 frames of a 3 x 3 MLA scan of 9-px lenslets (steps of 3 px), uint16."""
    frames = np.stack([ls.render(shape, 9, 9.0, 0.0, (4.0, 4.0), nominal_rect=(3 * r, 3 * c))
                       for r, c in scan_order(3)])
    return np.round(4000 * frames / frames.max()).astype(np.uint16)


def test_realign_refuses_frames_of_lenslets_far_from_nnum(tmp_path):
    """9-px lenslets under the default nnum 15 (outside the old +-25 % search): exit 2, one line
    naming the measured size and the nnum to set."""
    write_raw(tmp_path / "nine.tif", nine_px_scan())
    res = runner.invoke(app, ["realign", str(tmp_path / "nine.tif"), "--scan", "3", "--out",
                              str(tmp_path / "views.tif")])
    assert isinstance(res.exception, ValueError), res.output
    msg = str(res.exception)
    assert "\n" not in msg and re.search(r"measures 9\.\d\d px but nnum is 15", msg), msg
    assert "set nnum = 9" in msg and not (tmp_path / "views.tif").exists()


def test_calibrate_names_the_lenslet_size_it_measures():
    """A white frame of 9-px lenslets calibrated as nnum 15: the period it measures, not 'no
    lenslet grid found'."""
    white = ls.render((216, 216), 9, 9.0, 0.0, (4.0, 4.0), white=True)
    with pytest.raises(ValueError, match=r"measures 9\.\d\d px but nnum is 15; set nnum = 9"):
        calibrate(white, 15)
