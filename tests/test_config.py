"""SystemConfig: defaults, derived quantities, validation (one error per bad parameter), TOML."""

import json
import math

import pytest

import metasensor as ms
from metasensor.config import ConfigError


def test_prototype_defaults_and_derived():
    cfg = ms.SystemConfig()
    assert cfg.nnum == 15 and cfg.scan == 5 and cfg.lenslet_aperture == "circular"
    assert math.isclose(cfg.pixel_pitch, 4.6e-6, rel_tol=1e-12)
    assert math.isclose(cfg.lenslet_fnumber, 10.0)
    assert math.isclose(cfg.image_fnumber, 10.0)
    # system.md: diffraction limit at the MLA ≈ 5 µm at 500 nm (Abbe λ / 2NA)
    assert math.isclose(cfg.replace(wavelength=500e-9).diffraction_limit, 5e-6, rel_tol=1e-9)
    assert math.isclose(cfg.scan_step, 13.8e-6, rel_tol=1e-12)
    assert cfg.scan_step_px == 3
    assert math.isclose(cfg.pupil_radius_px, 7.5, rel_tol=1e-12)
    assert cfg.view_mask().sum() == 113  # the authors' (u-7)² + (v-7)² <= 36
    assert cfg.field_offset_px == 6


def test_pupil_coordinates_are_inverted_image_of_pupil():
    cfg = ms.SystemConfig()
    rx, ry = cfg.pupil_coords()
    assert rx[7, 7] == 0 and ry[7, 7] == 0
    assert rx[7, 14] < 0 and ry[14, 7] < 0  # docs/conventions.md: the lenslet inverts the pupil
    assert math.isclose(abs(rx[7, 0]), 7 / 7.5)


def test_toml_round_trip_exact(tmp_path):
    cfg = ms.SystemConfig(nnum=11, scan=11, mla_pitch=50.6e-6, na=0.0731, obstruction=0.3,
                          lenslet_aperture="square", focal_length=0.135, focus_distance=2.0,
                          sensor_shape=(1000, 1200), bit_depth=16,
                          wavelength=(0.1 + 0.2) * 1e-6)  # not exact in binary
    path = cfg.to_toml(tmp_path / "cfg.toml")
    back = ms.SystemConfig.from_toml(path)
    assert back == cfg
    assert back.to_toml_string() == cfg.to_toml_string()
    assert ms.SystemConfig.from_json(cfg.to_json()) == cfg


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"nnum": 14}, "nnum"),
        ({"nnum": 1}, "nnum"),
        ({"na": 0.0}, "na"),
        ({"na": 1.2}, "na"),
        ({"mla_pitch": -1e-6}, "mla_pitch"),
        ({"mla_focal": 0.0}, "mla_focal"),
        ({"wavelength": float("nan")}, "wavelength"),
        ({"scan": 4}, "scan period 4 does not divide"),
        ({"scan": 0}, "scan"),
        ({"obstruction": 1.0}, "obstruction"),
        ({"lenslet_aperture": "hexagonal"}, "lenslet_aperture"),
        ({"aperture_diameter": 1e-3}, "aperture_diameter"),
        ({"sensor_shape": (10, 10)}, "sensor_shape"),
        ({"bit_depth": 9}, "bit_depth"),
        ({"focal_length": 0.1, "focus_distance": 0.05}, "focus_distance"),
    ],
)
def test_each_invalid_parameter_has_its_own_error(kwargs, word):
    with pytest.raises(ConfigError, match=word) as info:
        ms.SystemConfig(**kwargs)
    assert "\n" not in str(info.value)


def test_unknown_key_and_bad_toml(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[system]\nnnum = 15\ncolour = 'red'\n")
    with pytest.raises(ConfigError, match="colour"):
        ms.SystemConfig.from_toml(bad)
    bad.write_text("[system\nnnum = ")
    with pytest.raises(ConfigError, match="invalid TOML"):
        ms.SystemConfig.from_toml(bad)
    with pytest.raises(ConfigError, match="not found"):
        ms.SystemConfig.from_toml(tmp_path / "missing.toml")
    # the view-stack extras key belongs to JSON descriptions only, not to a TOML system table
    bad.write_text("[system]\nnnum = 15\nmetasensor = 1\n")
    with pytest.raises(ConfigError, match="metasensor"):
        ms.SystemConfig.from_toml(bad)


def test_json_description_with_extras_and_bad_json():
    cfg = ms.SystemConfig(scan=3)
    desc = json.dumps({**cfg.to_dict(), "metasensor": {"scan_order": [[0, 0]]}})
    assert ms.SystemConfig.from_json(desc) == cfg
    with pytest.raises(ConfigError, match="invalid JSON"):
        ms.SystemConfig.from_json("{nnum: 15")
    with pytest.raises(ConfigError, match="must be an object"):
        ms.SystemConfig.from_json("[15]")


def test_optical_digest_ignores_non_optical_fields():
    cfg = ms.SystemConfig()
    assert cfg.optical_digest() == cfg.replace(scan=3, bit_depth=16).optical_digest()
    assert cfg.optical_digest() != cfg.replace(na=0.04).optical_digest()
    assert cfg.digest() != cfg.replace(scan=3).digest()


@pytest.mark.parametrize("line, word", [
    ('sensor_shape = "ab"', "sensor_shape"),
    ("sensor_shape = [100.5, 300]", "sensor_shape"),
    ("sensor_shape = 5", "sensor_shape"),
    ('na = "0.5"', "na"),
    ("scan = 2.5", "scan"),
    ('mla_pitch = "1e-4"', "mla_pitch"),
])
def test_mistyped_toml_values_name_their_key(line, word):
    with pytest.raises(ConfigError, match=word) as info:
        ms.SystemConfig.from_toml_string(f"[system]\n{line}\n")
    assert "\n" not in str(info.value)


def test_integral_float_sensor_shape_is_accepted():
    cfg = ms.SystemConfig.from_toml_string("[system]\nsensor_shape = [300.0, 450]\n")
    assert cfg.sensor_shape == (300, 450)
