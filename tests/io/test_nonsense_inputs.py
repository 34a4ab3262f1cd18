"""Damaged files and nonsense values end in exit 2 with one line naming the file or the
argument, never a traceback, exit 1, a hang or a plausible wrong result; valid big-endian
frames are accepted (each case reproduced by the audit)."""

import os
import shutil

import h5py
import numpy as np
import pytest
import tifffile
from cli_helpers import refused

import metasensor as ms
from metasensor.config import ConfigError
from metasensor.io.views import read_views, write_views
from metasensor.optics.psf_io import load_psf, save_psf

CFG = ms.SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)


@pytest.fixture(scope="module")
def f(tmp_path_factory):
    root = tmp_path_factory.mktemp("nonsense")
    rng = np.random.default_rng(0)
    views = 1 + rng.random((3, 3, 16, 16)).astype(np.float32)
    write_views(root / "views.tif", views, CFG)
    write_views(root / "tiny.tif", views[:, :, :3, :3], CFG)
    CFG.to_toml(root / "cfg.toml")
    write_views(root / "bad.zarr", views, CFG)  # one chunk replaced by garbage
    chunk = next(p for p in (root / "bad.zarr").rglob("*") if p.is_file() and p.name == "0")
    chunk.write_bytes(b"garbage" * 5)
    write_views(root / "empty.zarr", views, CFG)  # every chunk missing
    shutil.rmtree(root / "empty.zarr" / "c")
    bank = np.full((3, 3, 5, 5), 1 / 25, np.float32)
    save_psf(root / "psf.h5", bank, CFG)
    data = (root / "psf.h5").read_bytes()
    for start in range(512, len(data), 97):  # damaged past the superblock, where h5py noticed
        (root / "fuzzed.h5").write_bytes(data[:start] + b"\xff" * 16 + data[start + 16:])
        try:
            load_psf(root / "fuzzed.h5")
        except ValueError:
            break
    save_psf(root / "nosub.h5", bank, CFG)
    with h5py.File(root / "nosub.h5", "a") as h:
        h.attrs["subsample"] = np.zeros(0)
    save_psf(root / "huge.h5", bank * 1e30, CFG)
    deep = "[" * 100000 + "]" * 100000
    tifffile.imwrite(root / "deep.tif", np.ones((9, 4, 4), np.float32), description=deep,
                     metadata=None)
    (root / "deep.toml").write_text("[system]\nnnum = " + deep + "\n")
    np.save(root / "complex.npy", np.ones((32, 32), np.complex64))
    tifffile.imwrite(root / "complex.tif", np.ones((32, 32), np.complex64))
    write_views(root / "complex_views.tif", views, CFG)
    tifffile.imwrite(root / "complex_views.tif", np.ones((9, 16, 16), np.complex64))
    return root


def test_damaged_files_exit_2_naming_the_file(f):
    cases = [
        (["motion", f / "bad.zarr", "--out", f / "m.tif"], f"{f / 'bad.zarr'}: damaged Zarr"),
        (["reconstruct", f / "empty.zarr", "--config", f / "cfg.toml", "--out", f / "r"],
         "every chunk missing"),
        (["reconstruct", f / "views.tif", "--psf", f / "fuzzed.h5", "--out", f / "r"],
         str(f / "fuzzed.h5")),
        (["reconstruct", f / "views.tif", "--psf", f / "nosub.h5", "--out", f / "r"],
         "'subsample'"),
        (["reconstruct", f / "views.tif", "--psf", f / "huge.h5", "--out", f / "r"],
         "PSF bank"),
        (["depth", f / "deep.tif", "--out", f / "d"], str(f / "deep.tif")),
        (["psf", "--config", f / "deep.toml", "--out", f / "p.h5"], "nested too deeply"),
        (["psf", "--config", f / "cfg.toml", "--zernike", "4:1e300", "--out", f / "p.h5"],
         "--zernike"),
        (["psf", "--config", f / "cfg.toml", "--zernike", "1000000:0.1", "--out", f / "p.h5"],
         "--zernike"),
        (["psf", "--config", f / "cfg.toml", "--zernike", f / "complex.npy", "--out",
          f / "p.h5"], "real numbers"),
        (["evaluate", f / "complex.npy", "--out", f / "e"], "real numbers"),
        (["simulate", "--scene", f / "complex.tif", "--size", "32", "--out", f / "s"],
         "real numbers"),
        (["calibrate-aberration", f / "complex_views.tif", "--config", f / "cfg.toml", "--out",
          f / "s.h5"], "real numbers"),
        (["calibrate-aberration", f / "tiny.tif", "--out", f / "s.h5"], "too small"),
        (["reconstruct", f / "views.tif", "--config", f / "cfg.toml", "--solver", "hqs",
          "--iterations", "3", "--out", f / "r"], "--iterations"),
    ]
    for args, match in cases:
        refused(*args, match=match)
    assert not any((f / name).exists() for name in ("m.tif", "r", "d", "p.h5", "e", "s",
                                                    "s.h5"))


@pytest.mark.parametrize("kw, name", [
    ({"wavelength": 1e-3}, "wavelength"), ({"wavelength": 1e-15}, "wavelength"),
    ({"na": 0.999999}, "na"), ({"nnum": 101, "scan": 1}, "nnum"),
    ({"mla_pitch": 1e-300}, "mla_pitch"), ({"mla_focal": 1e300}, "mla_focal"),
    ({"mla_pitch": 10**400}, "mla_pitch"), ({"aperture_diameter": 1e-300}, "aperture_diameter"),
])
def test_configurations_outside_physical_ranges_are_refused(kw, name):
    with pytest.raises(ConfigError, match=name):
        ms.SystemConfig(**kw)


def test_big_endian_frames_and_bounded_reads(tmp_path, monkeypatch):
    frames = np.random.default_rng(1).integers(0, 4000, (9, 30, 30)).astype(np.uint16)
    np.testing.assert_array_equal(ms.realign(frames.astype(">u2"), CFG), ms.realign(frames, CFG))
    tifffile.imwrite(tmp_path / "be.tif", frames.astype(">u2"), byteorder=">")
    from metasensor.io.raw import open_raw

    with open_raw(tmp_path / "be.tif") as raw:
        np.testing.assert_array_equal(ms.realign(raw.read(), CFG), ms.realign(frames, CFG))
    # a file declaring more data than memory holds is refused before decoding
    from metasensor.io import tiff

    monkeypatch.setattr(tiff, "available_memory", lambda: 1000)
    with pytest.raises(ValueError, match="more than the"):
        read_views(tmp_path / "be.tif")
    os.mkfifo(tmp_path / "pipe.npy")
    refused("reconstruct", tmp_path / "be.tif", "--field-zernike", tmp_path / "pipe.npy",
            "--out", tmp_path / "r", match="not a regular file")


def test_a_disparity_range_beyond_the_views_is_refused():
    views = np.random.default_rng(0).random((3, 3, 20, 20)).astype(np.float32)
    with pytest.raises(ValueError, match="disparity_range"):
        ms.estimate_depth(views, CFG, disparity_range=(-1e6, 1e6))


def test_a_description_that_is_not_utf8_is_named_once(tmp_path, capsys):
    import json

    from metasensor.io.views import read_config_from_views, stored_extras

    meta = {**CFG.to_dict(), "metasensor": {"unit": "UNIT"}}
    raw = json.dumps(meta).encode().replace(b"UNIT", "µm".encode("cp1252"))
    tifffile.imwrite(tmp_path / "latin.tif", np.ones((9, 4, 4), np.float32), description=raw,
                     metadata=None)
    assert read_config_from_views(tmp_path / "latin.tif") == CFG
    assert stored_extras(tmp_path / "latin.tif") == {"unit": "µm"}
    assert capsys.readouterr().err.count("not UTF-8") == 1
