"""Libraries instead of hand-written code: the cache folder from platformdirs (the platform's
user cache, METASENSOR_CACHE still first), TOML values written by tomli-w, windows from
scipy.signal.windows."""

import sys
import tomllib

import pytest
from platformdirs import user_cache_dir

from metasensor.config import ConfigError, toml_value
from metasensor.optics import cache


def test_cache_folder_is_the_platforms_user_cache(monkeypatch, tmp_path):
    monkeypatch.delenv("METASENSOR_CACHE", raising=False)
    monkeypatch.setattr(cache, "_setting", None)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))  # honoured on Linux
    assert cache.cache_dir() == type(cache.cache_dir())(user_cache_dir("metasensor",
                                                                        appauthor=False))
    if sys.platform.startswith("linux"):
        assert cache.cache_dir() == tmp_path / "xdg" / "metasensor"
    monkeypatch.setenv("METASENSOR_CACHE", str(tmp_path / "mine"))
    assert cache.cache_dir() == tmp_path / "mine"


@pytest.mark.parametrize("value", ["lens 😀 µ", "a\"b\\c\n", 1e-5, 2.0, True, 7,
                                   [(0, 0), (0, 1)], ["x", 1.5]])
def test_toml_values_read_back(value):
    got = tomllib.loads(f"v = {toml_value(value)}")["v"]
    expect = [list(v) if isinstance(v, tuple) else v for v in value] \
        if isinstance(value, list) else value
    assert got == expect and "\n" not in toml_value(value)


def test_calibration_with_a_non_bmp_file_name_reads_back(tmp_path):
    from metasensor.sensor.calibration import Calibration

    calib = Calibration(nnum=15, pitch=15.0, rotation=0.0, center=(7.0, 7.0), lenslets=(8, 8),
                        sensor_shape=(150, 150), flat="flat 😀.tif")
    assert Calibration.from_toml(calib.to_toml(tmp_path / "c.toml")).flat == "flat 😀.tif"


@pytest.mark.parametrize("value", [float("nan"), float("inf"), {"a": 1}, None])
def test_toml_refuses_what_it_cannot_write(value):
    with pytest.raises(ConfigError):
        toml_value(value)


def test_tukey_window_comes_from_scipy(monkeypatch):
    """The DAO's and registration's Tukey window is scipy.signal.windows.tukey (sampled at the
    pixel centres), not a hand-written raised cosine."""
    import numpy as np
    import scipy.signal.windows as windows

    from metasensor.align.shifts import tukey2d

    w = tukey2d((6, 10), alpha=0.5).numpy()
    np.testing.assert_allclose(w[:, 0:1] * w[0:1, :] / w[0, 0], w, rtol=1e-6)  # separable
    np.testing.assert_allclose(w[3], windows.tukey(21, 0.5)[1::2] * windows.tukey(13, 0.5)[7],
                               rtol=1e-6)
    monkeypatch.setattr(windows, "tukey", lambda n, alpha: np.full(n, 0.5))
    assert np.allclose(tukey2d((4, 4)).numpy(), 0.25)  # delegated: the library's values
