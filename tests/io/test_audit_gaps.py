"""The audit's cases that had no test of their own: a fuzzed TIFF whose page headers disagree
(tifffile's "incompatible keyframe"), big-endian frames through the ``realign`` command, the two
messages that did not name their argument ("zero-size array to reduction operation" and "ufunc
'isfinite' not supported", from empty and non-numeric arrays), and ``write_views`` given
extras it cannot store (KeyError/AttributeError-like messages before)."""

import struct

import numpy as np
import pytest
import tifffile
from cli_helpers import refused, run_cli

import metasensor as ms
from metasensor.io.raw import write_raw
from metasensor.io.views import read_views, write_views

CFG = ms.SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)


def _widen_page(src, dst, page=3):
    """Copy ``src`` with page ``page``'s ImageWidth changed (its data untouched)."""
    data = bytearray(src.read_bytes())
    with tifffile.TiffFile(src) as tif:
        tag = tif.pages[page].tags["ImageWidth"]
        fmt = "<H" if tag.dtype == 3 else "<I"
        data[tag.valueoffset:tag.valueoffset + struct.calcsize(fmt)] = \
            struct.pack(fmt, tag.value + 1)
    dst.write_bytes(bytes(data))


def test_pages_that_disagree_with_page_0_are_named(tmp_path):
    views = 1 + np.random.default_rng(0).random((3, 3, 16, 16)).astype(np.float32)
    write_views(tmp_path / "ours.tif", views, CFG)  # a shaped series read from page 0's layout
    tifffile.imwrite(tmp_path / "plain.tif", views.reshape(9, 16, 16), metadata=None)
    frames = np.random.default_rng(1).integers(0, 4000, (9, 30, 30)).astype(np.uint16)
    write_raw(tmp_path / "raw.tif", frames, description=CFG.to_json())
    for name in ("ours.tif", "plain.tif", "raw.tif"):
        _widen_page(tmp_path / name, tmp_path / f"bad_{name}")
    with tifffile.TiffFile(tmp_path / "bad_raw.tif") as tif, \
            pytest.raises(RuntimeError, match="keyframe"):
        tif.asarray()  # what tifffile makes of it; ours was read as if page 3 were intact
    CFG.to_toml(tmp_path / "cfg.toml")
    for args in (["reconstruct", tmp_path / "bad_ours.tif", "--out", tmp_path / "r"],
                 ["reconstruct", tmp_path / "bad_plain.tif", "--config", tmp_path / "cfg.toml",
                  "--out", tmp_path / "r"],
                 ["realign", tmp_path / "bad_raw.tif", "--out", tmp_path / "v.tif"]):
        refused(*args, match=f"{args[1]}: ")
    assert not (tmp_path / "r").exists() and not (tmp_path / "v.tif").exists()
    np.testing.assert_array_equal(read_views(tmp_path / "ours.tif"), views)  # intact: read


def test_big_endian_frames_through_the_realign_command(tmp_path):
    frames = np.random.default_rng(2).integers(0, 4000, (9, 30, 30)).astype(np.uint16)
    tifffile.imwrite(tmp_path / "be.tif", frames.astype(">u2"), byteorder=">",
                     description=CFG.to_json(), metadata=None)
    code, err = run_cli("realign", tmp_path / "be.tif", "--out", tmp_path / "v.tif")
    assert code == 0, err
    np.testing.assert_array_equal(read_views(tmp_path / "v.tif"), ms.realign(frames, CFG))


def test_empty_and_non_numeric_arrays_name_their_argument(tmp_path):
    write_views(tmp_path / "v.tif", 1 + np.zeros((3, 3, 16, 16), np.float32), CFG)
    CFG.to_toml(tmp_path / "c.toml")
    for name, arr in (("s1.npy", np.array(["a", "b"])), ("e1.npy", np.zeros(0)),
                      ("s2.npy", np.array([["a"]])), ("s3.npy", np.array([[["a"]]])),
                      ("e3.npy", np.zeros((0, 0, 0)))):
        np.save(tmp_path / name, arr)
    f = tmp_path
    cases = [
        (["psf", "--config", f / "c.toml", "--zernike", f / "s1.npy", "--out", f / "p.h5"],
         "--zernike"),
        (["psf", "--config", f / "c.toml", "--zernike", f / "e1.npy", "--out", f / "p.h5"],
         "--zernike"),
        (["evaluate", f / "s2.npy", "--out", f / "e"], "s2.npy"),
        (["simulate", "--scene", f / "s2.npy", "--size", "32", "--out", f / "s"], "s2.npy"),
        (["reconstruct", f / "v.tif", "--field-zernike", f / "s3.npy", "--out", f / "r"],
         "--field-zernike"),
        (["reconstruct", f / "v.tif", "--field-zernike", f / "e3.npy", "--out", f / "r"],
         "field_zernike"),
    ]
    for args, match in cases:  # notes may come first (reconstruct's on the aberration)
        code, err = run_cli(*args)
        errors = [ln for ln in err.strip().splitlines() if ln.startswith("error:")]
        assert code == 2 and len(errors) == 1 and err.strip().endswith(errors[0]), (args, err)
        assert match in errors[0], (args, errors[0])
        assert "zero-size array" not in errors[0] and "ufunc" not in errors[0], errors[0]


def test_write_views_names_what_it_cannot_store(tmp_path):
    views = np.zeros((3, 3, 4, 4), np.float32)
    for target in ("w.tif", "w.zarr"):
        with pytest.raises(TypeError, match="extra must hold JSON values"):
            write_views(tmp_path / target, views, CFG, extra={"a": object()})
        with pytest.raises(TypeError, match="extra's keys must be strings"):
            write_views(tmp_path / target, views, CFG, extra={1: 2})
        with pytest.raises(TypeError, match="extra must hold JSON values"):
            write_views(tmp_path / target, views, CFG, extra={"a": float("nan")})
    with pytest.raises(TypeError, match="path must be a str or Path"):
        write_views(5, views)
    with pytest.raises(TypeError, match="cfg must be a SystemConfig"):
        write_views(tmp_path / "w.tif", views, {"nnum": 3})
    assert list(tmp_path.iterdir()) == []  # nothing written, no temporary


def test_declared_sizes_are_checked_before_decoding_in_every_reader(tmp_path, monkeypatch):
    """A small compressed TIFF can declare gigabytes (the audit: 6.5 MB declaring 40000² float32
    decoded whole by ``evaluate``, over 6 GB before it was killed): every command's TIFF reader
    compares the declared size with the memory left first (here told only 10 kB is left)."""
    from metasensor.io import tiff
    from metasensor.sensor.calibration import Calibration

    big = np.zeros((64, 64), np.float32)
    tifffile.imwrite(tmp_path / "big.tif", big, compression="zlib")
    frames = np.random.default_rng(3).integers(0, 4000, (9, 30, 30)).astype(np.uint16)
    write_raw(tmp_path / "raw.tif", frames, description=CFG.to_json())
    Calibration(nnum=3, pitch=3.0, rotation=0.0, center=(1.0, 1.0), lenslets=(10, 10),
                sensor_shape=(30, 30), flat="big.tif").to_toml(tmp_path / "c.toml")
    monkeypatch.setattr(tiff, "available_memory", lambda: 10_000)
    f = tmp_path
    for args in (["evaluate", f / "big.tif", "--out", f / "e"],
                 ["simulate", "--scene", f / "big.tif", "--size", "32", "--out", f / "s"]):
        refused(*args, match=f"{f / 'big.tif'}: declares")
    code, err = run_cli("realign", f / "raw.tif", "--calib", f / "c.toml", "--flat", "--out",
                        f / "v.tif")  # the flat field (its progress bar was open: two lines)
    assert code == 2 and err.strip().splitlines()[-1].startswith(f"error: {f / 'big.tif'}: "
                                                                  "declares"), err
    assert not any((f / n).exists() for n in ("e", "s", "v.tif"))


def test_calibrate_aberrations_file_on_a_full_disk_is_one_line(tmp_path, monkeypatch):
    """The audit's SIGSEGV: ``calibrate-aberration --out full/s.h5`` crashed inside h5py on a
    full disk. Its file is built in memory and written with plain I/O, so a full disk is one
    ``OSError`` naming the file and nothing is left behind."""
    import errno
    from pathlib import Path

    from metasensor.dao.system_aberration import SystemAberration

    sa = SystemAberration(zernike=np.zeros((1, 1, 45)), shift_grid=np.zeros((3, 3, 2, 2, 2)),
                          view_shape=(16, 16), config=CFG)

    def full(self, data):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(Path, "write_bytes", full)
    with pytest.raises(OSError, match=r"cannot write .*s\.h5: no space left on the device"):
        sa.save(tmp_path / "s.h5")
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []
    sa.save(tmp_path / "s.h5")  # with room: written and read back
    assert SystemAberration.load(tmp_path / "s.h5").view_shape == (16, 16)
