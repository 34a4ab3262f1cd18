"""CLI: metasensor calibrate / realign on a synthetic capture; bad input → one-line errors; the
input files are never modified (checksums before/after)."""

from __future__ import annotations

import hashlib
import re

import lf_synth as ls
import numpy as np
import pytest
import tifffile
from typer.testing import CliRunner

from metasensor.cli import app
from metasensor.io.raw import write_raw
from metasensor.io.views import read_config_from_views, read_views
from metasensor.sensor.calibration import Calibration
from metasensor.sensor.scan import scan_order

N = 15
runner = CliRunner()


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("cap")
    pitch, rot, center = 15.12, 0.4, (21.3, 17.8)
    order = scan_order(3, "serpentine")
    rng = np.random.default_rng(9)
    jit = rng.uniform(-0.25, 0.25, (9, 2))
    jit[order.index((0, 0))] = 0
    shape = (190, 215)
    frames = np.stack([ls.render(shape, N, pitch, rot, center, (r * 5, c * 5), j)
                       for (r, c), j in zip(order, jit, strict=True)])
    raw = np.round(3000 * np.concatenate([frames, frames[:4]])).astype(np.uint16)  # 13 frames
    white = np.round(3000 * ls.render(shape, N, pitch, rot, center, white=True))
    write_raw(root / "white.tif", white.astype(np.uint16))
    write_raw(root / "raw.tif", raw[:9])
    write_raw(root / "raw13.tif", raw)
    write_raw(root / "small.tif", raw[:9, :150, :150])
    return dict(root=root, pitch=pitch, rot=rot, order=order, raw=raw, center=center, jit=jit)


def run(*args):
    result = runner.invoke(app, [str(a) for a in args])
    return result


def test_calibrate_then_realign(capture):
    root = capture["root"]
    sums = {p: digest(root / p) for p in ("white.tif", "raw.tif")}
    res = run("calibrate", root / "white.tif", "--out", root / "calib.toml")
    assert res.exit_code == 0, res.output
    calib = Calibration.from_toml(root / "calib.toml")
    assert abs(calib.pitch - capture["pitch"]) < 0.01
    assert abs(calib.rotation - capture["rot"]) < 0.01
    assert (root / calib.flat).is_file()
    res = run("realign", root / "raw.tif", "--calib", root / "calib.toml", "--scan", 3,
              "--order", "serpentine", "--out", root / "views.tif", "--flat")
    assert res.exit_code == 0, res.output
    views = read_views(root / "views.tif")
    cfg = read_config_from_views(root / "views.tif")
    assert cfg.scan == 3 and views.shape[:2] == (N, N)
    # each frame's grid offset was measured by the CLI (the calibration had none): the views
    # match views rendered on the exact grid (continuous model, lf_synth) to >= 40 dB
    from metasensor.config import SystemConfig
    from metasensor.sensor.rectify import flat_views
    from metasensor.sensor.reuse import adapt

    cfg3 = SystemConfig(scan=3)
    cal3 = adapt(calib, 3, capture["order"])
    truth = 3000 * ls.true_views(cal3, cfg3, capture["pitch"], capture["rot"],
                                 capture["center"], capture["order"], capture["jit"])
    flat = tifffile.imread(root / calib.flat)
    (i0, j0), (ly, lx) = cal3.flat_origin, cal3.lenslets
    fv = flat_views(flat[i0 * N:(i0 + ly) * N, j0 * N:(j0 + lx) * N], N, 3)
    assert views.shape == truth.shape
    bright = fv > 0.5  # flat-fielded views compared where the pupil is bright
    est = views * fv
    psnr = 10 * np.log10(truth.max() ** 2 / np.mean((est[bright] - truth[bright]) ** 2))
    assert psnr >= 40, psnr
    res = run("realign", root / "raw.tif", "--calib", root / "calib.toml", "--scan", 3,
              "--order", "serpentine", "--out", root / "views16.tif", "--dtype", "input")
    assert res.exit_code == 0, res.output
    v16 = read_views(root / "views16.tif")
    assert v16.dtype == np.uint16
    lit = fv > 0.05  # where --flat divided (elsewhere it wrote 0)
    assert np.abs(v16 - read_views(root / "views.tif") * fv)[lit].max() <= 0.51
    assert all(digest(root / p) == s for p, s in sums.items())


def test_realign_sliding_window_writes_one_stack_per_frame(capture):
    root = capture["root"]
    res = run("realign", root / "raw13.tif", "--scan", 3, "--order", "serpentine",
              "--sliding", "--out", root / "slide" / "v.tif")
    assert res.exit_code == 0, res.output
    files = sorted((root / "slide").glob("v_*.tif"))
    assert len(files) == 13 - 9 + 1
    first = read_views(files[0])
    assert first.dtype == np.float32 and first.shape[:2] == (N, N)  # --dtype float32 default
    # each window stores the phases in the order its frames were taken (for motion correction)
    from metasensor.io.views import stored_extras

    order = capture["order"]
    for k in (0, 1, 4):
        taken = [tuple(q) for q in stored_extras(files[k])["scan_order"]]
        assert taken == order[k:] + order[:k], k
    res = run("realign", root / "raw.tif", "--scan", 3, "--order", "serpentine", "--dtype",
              "input", "--out", root / "v_input.tif")  # the raw type: half the bytes, same values
    assert res.exit_code == 0, res.output
    same = read_views(root / "v_input.tif")
    run("realign", root / "raw.tif", "--scan", 3, "--order", "serpentine", "--out",
        root / "v_float.tif")
    assert same.dtype == np.uint16
    np.testing.assert_array_equal(same, read_views(root / "v_float.tif"))


def test_realign_bad_inputs(capture, tmp_path):
    root = capture["root"]
    if not (root / "calib.toml").exists():
        run("calibrate", root / "white.tif", "--out", root / "calib.toml")
    before = digest(root / "raw13.tif")
    cases = [
        (["realign", root / "raw13.tif", "--scan", 3, "--out", tmp_path / "v.tif"],
         "not a multiple"),
        (["realign", root / "small.tif", "--calib", root / "calib.toml", "--scan", 3,
          "--out", tmp_path / "v.tif"], "calibration is for"),
        (["realign", root / "raw.tif", "--scan", 4, "--out", tmp_path / "v.tif"],
         "does not divide"),
        (["realign", root / "raw.tif", "--scan", 3, "--order", "0,0;1,1",
          "--out", tmp_path / "v.tif"], "scan_order"),
        (["realign", root / "raw13.tif", "--scan", 3, "--sliding", "--out", root / "raw13.tif"],
         "overwrite the input"),
        (["calibrate", root / "raw13.tif", "--out", tmp_path / "c.toml"], "pages"),
    ]
    data = (root / "raw.tif").read_bytes()
    (tmp_path / "cut.tif").write_bytes(data[: len(data) - 5000])
    cases.append((["realign", tmp_path / "cut.tif", "--scan", 3, "--out", tmp_path / "v.tif"],
                  "truncated"))
    for args, text in cases:
        res = run(*args)
        assert res.exit_code != 0, args
        msg = str(res.exception)
        assert text in msg and "\n" not in msg, (args, msg)
    assert digest(root / "raw13.tif") == before
    assert not (tmp_path / "v.tif").exists()


def test_calibrate_multipage_measures_offsets(capture, tmp_path):
    res = run("calibrate", capture["root"] / "raw.tif", "--scan", 3, "--order", "serpentine",
              "--out", tmp_path / "c.toml", "--no-flat", "--figure", tmp_path / "c.png")
    assert res.exit_code == 0, res.output
    calib = Calibration.from_toml(tmp_path / "c.toml")
    assert calib.offsets is not None and calib.flat is None
    assert np.abs(calib.offset_errors()).max() < 0.35
    assert "measured - nominal" in res.output
    assert (tmp_path / "c.png").stat().st_size > 1000
    # the measured offsets are used by realign (--offsets calib) and written as Zarr
    res = run("realign", capture["root"] / "raw.tif", "--calib", tmp_path / "c.toml", "--scan",
              3, "--order", "serpentine", "--offsets", "calib", "--out", tmp_path / "v.zarr")
    assert res.exit_code == 0, res.output
    views = read_views(tmp_path / "v.zarr")
    assert views.shape == (N, N, calib.lenslets[0] * 3, calib.lenslets[1] * 3)


def test_nan_frames_rejected(tmp_path):
    frames = np.ones((9, 60, 60), np.float32)
    frames[2, 3, 4] = np.nan
    tifffile.imwrite(tmp_path / "nan.tif", frames)
    res = run("realign", tmp_path / "nan.tif", "--scan", 3, "--out", tmp_path / "v.tif")
    assert res.exit_code != 0 and "NaN" in str(res.exception)


def test_realign_takes_config_order_and_moving_stored_in_the_frames(tmp_path):
    # frames written with this package's description (as `simulate` writes them): a 3 x 3
    # serpentine scan of a nnum = 9 system, realigned with no options, equals the views
    import json

    import metasensor as ms
    from metasensor.io.views import description, stored_extras

    cfg = ms.SystemConfig(nnum=9, mla_pitch=9 * 4.6e-6, mla_focal=9 * 46e-6, scan=3)
    order = scan_order(3, "serpentine")
    views = np.random.default_rng(0).integers(0, 4000, (9, 9, 30, 36)).astype(np.uint16)
    frames = ms.unrealign(views, cfg, order)
    desc = description(cfg, kind="frames", scan_order=[list(p) for p in order], moving="mla")
    write_raw(tmp_path / "frames.tif", frames, description=json.dumps(desc))
    res = run("realign", tmp_path / "frames.tif", "--out", tmp_path / "v.tif")
    assert res.exit_code == 0, res.output
    np.testing.assert_array_equal(read_views(tmp_path / "v.tif"), views)
    assert read_config_from_views(tmp_path / "v.tif") == cfg
    assert [tuple(p) for p in stored_extras(tmp_path / "v.tif")["scan_order"]] == order
    # an explicit --order still wins (and, being wrong here, changes the views)
    res = run("realign", tmp_path / "frames.tif", "--order", "row-major", "--out",
              tmp_path / "w.tif")
    assert res.exit_code == 0, res.output
    assert not np.array_equal(read_views(tmp_path / "w.tif"), views)


def test_config_checks_against_what_the_frames_store(tmp_path):
    # frames stored as a 3 x 3 scan: --scan 5 cannot realign them; an unreadable stored
    # configuration is ignored when --config is given
    import json

    import metasensor as ms
    from metasensor.io.views import description

    cfg = ms.SystemConfig(nnum=15, scan=3)
    frames = np.zeros((9, 60, 60), np.uint16)
    write_raw(tmp_path / "f.tif", frames, description=json.dumps(description(cfg)))
    res = run("realign", tmp_path / "f.tif", "--scan", 5, "--out", tmp_path / "v.tif")
    assert res.exit_code != 0 and "scan" in str(res.exception)
    stale = {"metasensor": {"config": {**cfg.to_dict(), "old_field": 1}}}
    write_raw(tmp_path / "g.tif", frames, description=json.dumps(stale))
    cfg.to_toml(tmp_path / "c.toml")
    res = run("realign", tmp_path / "g.tif", "--config", tmp_path / "c.toml", "--out",
              tmp_path / "w.tif")
    assert res.exit_code == 0, res.output
    res = run("realign", tmp_path / "g.tif", "--out", tmp_path / "x.tif")
    assert res.exit_code != 0 and "old_field" in str(res.exception)


def test_realign_refuses_frames_in_another_scan_order(capture, tmp_path):
    """Serpentine frames realigned in the default row-major order: frames 3 and 5 measure 5 px
    (more than half the 5-px scan step) from their nominal phases. Exit 2, one line naming
    them and the order they fit; the right order realigns."""
    root = capture["root"]
    res = run("calibrate", root / "white.tif", "--out", tmp_path / "calib.toml", "--no-flat")
    assert res.exit_code == 0, res.output
    res = run("realign", root / "raw.tif", "--calib", tmp_path / "calib.toml", "--scan", 3,
              "--out", tmp_path / "v.tif")
    assert isinstance(res.exception, ValueError), res.output
    msg = str(res.exception)
    assert "\n" not in msg and re.match(r"frames 3, 5 sit [45]\.\d px", msg) and msg.endswith(
        "not in row-major order (they fit serpentine); pass --scan-order serpentine"), msg
    assert not (tmp_path / "v.tif").exists()
    res = run("realign", root / "raw.tif", "--calib", tmp_path / "calib.toml", "--scan", 3,
              "--order", "serpentine", "--out", tmp_path / "v.tif")
    assert res.exit_code == 0, res.output


def test_realign_refuses_a_later_frame_off_its_phase(capture, tmp_path):
    """The second scan period taken in reverse: frame 9 (phase (0, 0)) holds phase (2, 2)."""
    raw = capture["raw"][:9]
    write_raw(tmp_path / "raw18.tif", np.concatenate([raw, raw[::-1]]))
    res = run("calibrate", capture["root"] / "white.tif", "--out", tmp_path / "calib.toml",
              "--no-flat")
    assert res.exit_code == 0, res.output
    res = run("realign", tmp_path / "raw18.tif", "--calib", tmp_path / "calib.toml", "--scan",
              3, "--order", "serpentine", "--out", tmp_path / "v.tif")
    assert isinstance(res.exception, ValueError), res.output
    assert re.match(r"frame 9 sits [45]\.\d px from its nominal", str(res.exception))


def test_calibrate_refuses_frames_in_another_scan_order(capture, tmp_path):
    res = run("calibrate", capture["root"] / "raw.tif", "--scan", 3, "--out",
              tmp_path / "c.toml", "--no-flat")
    assert isinstance(res.exception, ValueError), res.output
    assert "(they fit serpentine); pass --scan-order serpentine" in str(res.exception)
    assert not (tmp_path / "c.toml").exists()
