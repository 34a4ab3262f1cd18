"""Calibration, rectification and realignment on synthetic raw frames of a known, misaligned
lenslet grid (continuous model in lf_synth; tolerances from the issue: pitch 0.01 px, rotation
0.01 deg, centre and per-phase offsets 0.1 px, views PSNR >= 40 dB)."""

from __future__ import annotations

import lf_synth as ls
import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.sensor.calibrate import calibrate, find_grid, flat_field
from metasensor.sensor.calibration import Calibration
from metasensor.sensor.realign import realign
from metasensor.sensor.rectify import flat_views, rectify_frame
from metasensor.sensor.scan import scan_order

N = 15


def psnr(x, ref):
    return 10 * np.log10(ref.max() ** 2 / np.mean((x - ref) ** 2))


def lattice_error(point, center, pitch, rot):
    """Distance [px] from ``point`` to the nearest true lenslet centre."""
    a = ls.matrix(pitch, rot, N) * N
    k = np.linalg.solve(a, np.asarray(point) - center)
    return float(np.linalg.norm(a @ (k - np.round(k))))


def make_capture(seed, scan=5, order="row-major", shape=(300, 320), jitter=0.3):
    rng = np.random.default_rng(seed)
    pitch = rng.uniform(14.7, 15.3)
    rot = rng.uniform(-1, 1)
    center = rng.uniform(8, 40, 2)
    phases = scan_order(scan, order)
    d = N // scan
    jit = rng.uniform(-jitter, jitter, (len(phases), 2))
    jit[phases.index((0, 0))] = 0  # phase (0, 0) defines the grid origin
    scene = ls.scene_fn(seed)
    frames = np.stack([ls.render(shape, N, pitch, rot, center, (r * d, c * d), j, scene)
                       for (r, c), j in zip(phases, jit, strict=True)])
    white = ls.render(shape, N, pitch, rot, center, white=True)
    return dict(pitch=pitch, rot=rot, center=center, jit=jit, phases=phases, frames=frames,
                white=white, scene=scene, d=d)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_find_grid_recovers_pitch_rotation_centre(seed):
    cap = make_capture(seed, scan=1, jitter=0)
    for img in (cap["white"], cap["frames"][0]):  # white frame and textured frame
        g = find_grid(img, N)
        assert abs(g["pitch"] - cap["pitch"]) < 0.01
        assert abs(g["rotation"] - cap["rot"]) < 0.01
        assert lattice_error(g["point"], cap["center"], cap["pitch"], cap["rot"]) < 0.1


@pytest.mark.parametrize(("seed", "order"), [(3, "row-major"), (4, "serpentine")])
def test_calibrate_rectify_realign_matches_truth(seed, order):
    cap = make_capture(seed, order=order)
    calib = calibrate(cap["white"], N, frames=cap["frames"], scan=5, scan_order=order)
    assert abs(calib.pitch - cap["pitch"]) < 0.01
    assert abs(calib.rotation - cap["rot"]) < 0.01
    assert lattice_error(calib.center, cap["center"], cap["pitch"], cap["rot"]) < 0.1
    m = ls.matrix(cap["pitch"], cap["rot"], N)
    true_off = [m @ np.array([r * cap["d"], c * cap["d"]], float) + j
                for (r, c), j in zip(cap["phases"], cap["jit"], strict=True)]
    assert np.abs(np.array(calib.offsets) - np.array(true_off)).max() < 0.1
    # the offset errors against nominal are the jitter (within 0.1 px)
    assert np.abs(calib.offset_errors() - cap["jit"]).max() < 0.1
    # rectify with the measured grid, realign, compare with views rendered on the exact grid;
    # the true rectified centre of lenslet (0, 0) is where the calibration put it
    rect = np.stack([rectify_frame(f, calib, ph) for f, ph in zip(cap["frames"], cap["phases"],
                                                                   strict=True)])
    cfg = SystemConfig(scan=5)
    views = realign(rect, cfg, cap["phases"])
    a = m * N
    k = np.round(np.linalg.solve(a, np.asarray(calib.center) - cap["center"]))
    assert np.abs(a @ k + cap["center"] - np.asarray(calib.center)).max() < 0.1
    true_views = ls.true_views(calib, cfg, cap["pitch"], cap["rot"], cap["center"],
                               cap["phases"], cap["jit"], cap["scene"])
    assert views.shape == true_views.shape
    assert psnr(views, true_views) >= 40


def test_flat_field_follows_the_pupil():
    cap = make_capture(5, scan=1, jitter=0)
    calib = calibrate(cap["white"], N)
    flat = flat_field(cap["white"], calib)
    assert flat.shape == (calib.lenslets[0] * N, calib.lenslets[1] * N)
    fv = flat_views(flat, N, 1)
    # analytic: the pupil image A(u - 7, v - 7) normalised at its bright level
    u = np.arange(N) - 7
    ref = ls.pupil(u[:, None], u[None, :])
    prof = fv.mean(axis=(2, 3))
    assert np.abs(prof / prof.max() - ref / ref.max()).max() < 0.02


def test_exact_grid_is_a_plain_crop(rng):
    frames = rng.integers(0, 4000, (9, 60, 66)).astype(np.uint16)
    calib = Calibration(nnum=15, pitch=15.0, rotation=0.0, center=(7.0, 7.0), lenslets=(3, 3),
                        sensor_shape=(60, 66), scan=3, scan_order=tuple(scan_order(3)))
    assert calib.is_exact()
    for t, ph in enumerate(scan_order(3)):
        rect = rectify_frame(frames[t], calib, ph)
        d = (ph[0] * 5, ph[1] * 5)
        np.testing.assert_array_equal(rect[d[0]:d[0] + 45, d[1]:d[1] + 45],
                                      frames[t, d[0]:d[0] + 45, d[1]:d[1] + 45])


def test_calibration_toml_round_trip(tmp_path):
    cap = make_capture(6, scan=3, jitter=0.2)
    calib = calibrate(cap["white"], N, frames=cap["frames"], scan=3)
    path = calib.to_toml(tmp_path / "calib.toml")
    back = Calibration.from_toml(path)
    assert back == calib
    assert "measured - nominal" in path.read_text()


def test_bad_calibration_inputs(tmp_path):
    from metasensor.sensor.rectify import check_fits

    cap = make_capture(7, scan=1, jitter=0, shape=(200, 210))
    calib = calibrate(cap["white"], N)
    with pytest.raises(ValueError, match="calibration is for 200x210 frames, got 180x210"):
        rectify_frame(cap["white"][:180], calib)
    with pytest.raises(ValueError, match="nnum 15"):
        check_fits(calib, (200, 210), nnum=9)
    with pytest.raises(ValueError, match="no lenslet grid"):
        calibrate(np.random.default_rng(0).random((200, 210)) * 0 + 1.0, N)
    with pytest.raises(ValueError, match="too small"):
        calibrate(cap["white"][:30, :30], N)
    bad = cap["white"].copy()
    bad[3, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        calibrate(bad, N)
    with pytest.raises(TypeError, match="dtype|image"):
        calibrate(cap["white"].astype(np.complex64), N)
    path = tmp_path / "c.toml"
    path.write_text("[calibration]\nnnum = 15\npitch = 15.0\n")
    with pytest.raises(ValueError, match="incomplete calibration"):
        Calibration.from_toml(path)
    path.write_text("not = [toml")
    with pytest.raises(ValueError, match="invalid calibration TOML"):
        Calibration.from_toml(path)
    with pytest.raises(FileNotFoundError):
        Calibration.from_toml(tmp_path / "missing.toml")
    # a calibration whose grid would put lenslet blocks off this sensor
    off = calib.replace(center=(calib.center[0] - 40.0, calib.center[1]))
    with pytest.raises(ValueError, match="does not fit"):
        rectify_frame(cap["white"], off)


def test_calibration_tolerates_shot_noise():
    """Poisson noise at 300 photons peak (SNR ~17) on a 300 x 320 frame: the issue's
    tolerances still hold (measured errors ~4x below them)."""
    cap = make_capture(11)
    rng = np.random.default_rng(0)

    def noisy(a):
        return rng.poisson(300 * a).astype(np.float64)

    calib = calibrate(noisy(cap["white"]), N, frames=[noisy(f) for f in cap["frames"]], scan=5)
    m = ls.matrix(cap["pitch"], cap["rot"], N)
    true_off = [m @ np.array([r * 3, c * 3], float) + j
                for (r, c), j in zip(cap["phases"], cap["jit"], strict=True)]
    assert abs(calib.pitch - cap["pitch"]) < 0.01
    assert abs(calib.rotation - cap["rot"]) < 0.01
    assert lattice_error(calib.center, cap["center"], cap["pitch"], cap["rot"]) < 0.1
    assert np.abs(np.array(calib.offsets) - np.array(true_off)).max() < 0.1
