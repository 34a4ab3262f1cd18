"""Impossible parameters across stages get one-line ValueErrors naming what is wrong (found by
an audit of the public API; each case used to be accepted or to fail deep inside)."""

import numpy as np
import pytest

import metasensor as ms
from metasensor.dao.estimate import run_dao
from metasensor.simulation.scenes import load_scene

CFG5 = ms.SystemConfig(nnum=5, scan=5)


@pytest.mark.parametrize("kw, match", [({"radius": -1}, "radius"), ({"eps": -1}, "eps"),
                                       ({"refine_iterations": -1}, "refine_iterations"),
                                       ({"fill_radius": 0}, "fill_radius"),
                                       ({"disparity_range": (1, 2, 3)}, "disparity_range")])
def test_depth_parameters(kw, match):
    v = np.random.default_rng(0).random((5, 5, 20, 20)).astype(np.float32)
    with pytest.raises(ValueError, match=match):
        ms.estimate_depth(v, CFG5, **kw)


def test_unrealign_rejects_complex_and_non_finite_views():
    v = np.ones((5, 5, 10, 10), np.float32)
    with pytest.raises(ValueError, match="real numbers"):
        ms.unrealign(v.astype(np.complex64), CFG5)
    v[0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        ms.unrealign(v, CFG5)


@pytest.mark.parametrize("kw, match", [({"scale": -1.0}, "scale"),
                                       ({"scale": float("nan")}, "scale"),
                                       ({"zernike": np.zeros((3, 3))}, "1-D"),
                                       ({"scan": 5.7}, "scan")])
def test_simulate_parameters(kw, match):
    with pytest.raises(ValueError, match=match):
        ms.simulate(load_scene("chart", 96), ms.SystemConfig(), comparison=False, **kw)


@pytest.mark.parametrize("kw, match", [({"lam": -1.0}, "lam"), ({"tol": float("nan")}, "tol"),
                                       ({"tol": -0.1}, "tol"), ({"chunk": 0}, "chunk")])
def test_dao_parameters(kw, match):
    cfg = ms.SystemConfig()
    with pytest.raises(ValueError, match=match):
        run_dao(np.ones((15, 15, 20, 20), np.float32), cfg, **kw)


def test_dao_tol_zero_runs_every_update():
    # tol = 0 means "never stop early" (the slow 3 λ acceptance test runs that way); the
    # parameter audit once refused it, which only the slow suite noticed
    # (a flat block's first update is ~1e-3 λ: the default tol stops there, tol = 0 goes on)
    views = np.ones((15, 15, 20, 20), np.float32)
    assert len(run_dao(views, ms.SystemConfig(), max_iter=2).history) == 1
    assert len(run_dao(views, ms.SystemConfig(), tol=0.0, max_iter=2).history) == 2


def test_reconstruct_needs_a_few_samples():
    with pytest.raises(ValueError, match="too small"):
        ms.reconstruct(np.ones((15, 15, 1, 1), np.float32), ms.SystemConfig())


@pytest.mark.parametrize("kw, match", [({"scatter": "x"}, "scatter"),
                                       ({"threshold": float("nan")}, "threshold"),
                                       ({"chunk": 0}, "chunk"),
                                       ({"flow_view": "middle"}, "flow_view"),
                                       ({"flow_view": (20, 20)}, "flow_view")])
def test_motion_options(kw, match):
    from metasensor.motion.correct import correct_motion_views

    views = np.ones((5, 5, 60, 60), np.float32)
    with pytest.raises(ValueError, match=match):
        correct_motion_views(views, None, **kw)
    if "chunk" not in kw and "flow_view" not in kw:
        with pytest.raises(ValueError, match=match):
            ms.correct_motion(views[2, 2], None, **kw)


@pytest.mark.parametrize("change, match", [({"center": (float("nan"), 7.0)}, "center"),
                                           ({"scan": 0, "scan_order": ()}, "scan"),
                                           ({"scan_order": ((0, 0),) * 25}, "once"),
                                           ({"sensor_shape": (-96, 96)}, "sensor_shape")])
def test_calibration_values(change, match):
    from metasensor.sensor.calibration import Calibration

    base = dict(nnum=15, pitch=15.0, rotation=0.0, center=(7.0, 7.0), lenslets=(4, 4),
                sensor_shape=(96, 96), scan=5, moving="mla",
                scan_order=tuple((r, c) for r in range(5) for c in range(5)))
    Calibration(**base)  # the valid one
    with pytest.raises(ValueError, match=match):
        Calibration(**{**base, **change})


# --- a second audit (550 bad-input cases on the CLI and the API): the cases it found ---

def test_api_names_the_bad_argument():
    frames = np.zeros((25, 60, 60), np.uint16)
    with pytest.raises(TypeError, match="cfg must be a SystemConfig"):
        ms.realign(frames, None)
    with pytest.raises(TypeError, match="cfg must be a SystemConfig"):
        ms.view_psfs(None)
    with pytest.raises(TypeError, match="cfg must be a SystemConfig"):
        ms.widefield_psf(None)
    with pytest.raises(TypeError, match="zernike"):
        ms.view_psfs(ms.SystemConfig(), zernike="abc")
    with pytest.raises(TypeError, match="dtype"):
        ms.realign(frames, ms.SystemConfig(), dtype="bogus")


@pytest.mark.parametrize("kw, err, match", [({"seed": -1}, ValueError, "seed"),
                                            ({"seed": "x"}, ValueError, "seed"),
                                            ({"snr_db": "30"}, TypeError, "snr_db"),
                                            ({"psf": np.ones((3, 3, 5, 5))}, TypeError, "psf")])
def test_simulate_run_options(kw, err, match):
    with pytest.raises(err, match=match):
        ms.simulate(load_scene("chart", 96), ms.SystemConfig(), comparison=False, **kw)


@pytest.mark.parametrize("kw, match", [({"iterations": 2.5}, "iterations"),
                                       ({"num_workers": 0}, "num_workers"),
                                       ({"num_workers": "two"}, "num_workers"),
                                       ({"subsets": 1000}, "subsets")])
def test_reconstruct_counts(kw, match):
    with pytest.raises(ValueError, match=match):
        ms.reconstruct(np.ones((15, 15, 8, 8), np.float32), ms.SystemConfig(), **kw)


def test_depth_upper_bounds():
    v = np.random.default_rng(0).random((5, 5, 20, 20)).astype(np.float32)
    with pytest.raises(ValueError, match="candidates"):  # a 10^7-plane cost volume: 25 GB
        ms.estimate_depth(v, CFG5, candidates=10_000_000)
    with pytest.raises(ValueError, match="radius"):
        ms.estimate_depth(v, CFG5, radius=100_000)


def test_motion_inputs():
    view = np.ones((60, 60), np.float32)
    with pytest.raises(TypeError, match="real numbers"):
        ms.correct_motion(view.astype(np.complex64), None)
    with pytest.raises(ValueError, match="max_ratio"):
        ms.correct_motion(view, None, max_ratio=-1)
    with pytest.raises(TypeError, match="scan_order"):
        ms.correct_motion(view, 5)


def test_config_file_empty_or_binary(tmp_path):
    from metasensor.config import ConfigError

    empty, binary = tmp_path / "empty.toml", tmp_path / "binary.toml"
    empty.write_text("  \n")
    binary.write_bytes(b"\xff\xfe\x00junk")
    with pytest.raises(ConfigError, match="empty.toml is empty"):
        ms.SystemConfig.from_toml(empty)
    with pytest.raises(ConfigError, match="binary.toml is not a TOML text file"):
        ms.SystemConfig.from_toml(binary)


def test_atomic_write_names_the_target_not_a_temporary(tmp_path):
    from metasensor.io.atomic import atomic_write_text

    (tmp_path / "folder").mkdir()
    with pytest.raises(OSError, match=r"cannot write .*folder: it is a folder"):
        atomic_write_text(tmp_path / "folder", "x")
    (tmp_path / "file").write_text("x")
    with pytest.raises(OSError, match=r"cannot write .*file[/\\]out.txt"):
        atomic_write_text(tmp_path / "file" / "out.txt", "x")  # parent is a file
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "folder"]  # no temporaries
