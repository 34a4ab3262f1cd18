"""Truncated or corrupt view-stack TIFFs: one ``ValueError`` line naming the file (never
tifffile's logged warnings, never a misleading "1 pages is not nnum²"), from the reader and from
every command that reads a view stack."""

from __future__ import annotations

import json
import logging
import sys

import numpy as np
import pytest
import tifffile

import metasensor as ms
from metasensor.io.raw import open_raw
from metasensor.io.tiff import read_tiff
from metasensor.io.views import read_config_from_views, read_views, write_views

NNUM = 15


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    root = tmp_path_factory.mktemp("trunc")
    cfg = ms.SystemConfig(nnum=NNUM, scan=5)
    views = np.random.default_rng(3).random((NNUM, NNUM, 9, 11)).astype(np.float32)
    path = write_views(root / "views.tif", views, cfg)
    return path, views


def _cut(src, dst, nbytes):
    data = src.read_bytes()
    dst.write_bytes(data[:nbytes])
    return dst


def _tifffile_records(caplog):
    return [r for r in caplog.records if r.name.startswith("tifffile")]


@pytest.mark.parametrize("where", ["half", "last_ifds", "tail", "page0"])
@pytest.mark.parametrize("mmap", [False, True])
def test_read_views_names_a_truncated_stack(stack, tmp_path, caplog, where, mmap):
    path, _ = stack
    size = path.stat().st_size
    nbytes = {"half": size // 2, "last_ifds": size - 100, "tail": size - 3000,
              "page0": 300}[where]
    bad = _cut(path, tmp_path / "cut.tif", nbytes)
    before = bad.read_bytes()
    with caplog.at_level(logging.DEBUG, logger="tifffile"):
        with pytest.raises(ValueError) as info:
            read_views(bad, mmap=mmap)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{bad}: ")
    assert "truncated or corrupt TIFF" in msg or "not a readable TIFF" in msg
    assert "nnum²" not in msg
    assert not _tifffile_records(caplog)  # tifffile's own warnings kept off the user's screen
    assert bad.read_bytes() == before


def test_read_config_from_a_truncated_stack_is_quiet(stack, tmp_path, caplog):
    path, _ = stack
    bad = _cut(path, tmp_path / "cut.tif", path.stat().st_size // 2)
    with caplog.at_level(logging.DEBUG, logger="tifffile"):
        assert read_config_from_views(bad).nnum == NNUM  # page 0 is intact
        with pytest.raises(ValueError, match=r"truncated or corrupt TIFF \(after page 1"):
            read_views(bad, nnum=NNUM)
    assert not _tifffile_records(caplog)


def test_fewer_pages_than_the_description_names(tmp_path):
    """A page chain that ends cleanly but short of the view_shape the description names."""
    cfg = ms.SystemConfig(nnum=3, scan=3)
    views = np.zeros((3, 3, 4, 5), np.float32)
    write_views(tmp_path / "full.tif", views, cfg)
    with tifffile.TiffFile(tmp_path / "full.tif") as tif:
        desc = tif.pages[0].description
    assert json.loads(desc)["metasensor"]["view_shape"] == [3, 3, 4, 5]
    short = tmp_path / "short.tif"
    tifffile.imwrite(short, np.zeros((5, 4, 5), np.float32), description=desc, metadata=None)
    with pytest.raises(ValueError, match=r"truncated or corrupt TIFF \(5 of the 9 pages"):
        read_views(short)
    with pytest.raises(ValueError, match=r"truncated or corrupt TIFF \(5 of the 9 pages"):
        read_views(short, nnum=3)


def test_shaped_tiffs_whole_or_cut(tmp_path):
    data = np.arange(9 * 4 * 6, dtype=np.uint16).reshape(9, 4, 6)
    plain = tmp_path / "plain.tif"
    tifffile.imwrite(plain, data)  # tifffile's shaped description, one IFD per page
    np.testing.assert_array_equal(read_views(plain), data.reshape(3, 3, 4, 6))
    one_ifd = tmp_path / "one_ifd.tif"
    tifffile.imwrite(one_ifd, data, truncate=True)  # a valid single-IFD contiguous layout
    np.testing.assert_array_equal(read_tiff(one_ifd), data)
    cut = _cut(one_ifd, tmp_path / "one_ifd_cut.tif", one_ifd.stat().st_size - 100)
    with pytest.raises(ValueError, match="truncated or corrupt TIFF"):
        read_tiff(cut)
    ij = tmp_path / "ij.tif"
    tifffile.imwrite(ij, data, imagej=True)
    np.testing.assert_array_equal(read_tiff(ij), data)


def test_intact_stack_and_raw_frames_still_read(stack):
    path, views = stack
    np.testing.assert_array_equal(read_views(path), views)
    np.testing.assert_array_equal(read_views(path, mmap=True), views)
    with open_raw(path) as raw:  # raw frames share the check: an intact file opens
        assert raw.shape == (NNUM * NNUM, *views.shape[2:])


def test_raw_frames_truncated_message(stack, tmp_path):
    path, _ = stack
    bad = _cut(path, tmp_path / "cut.tif", path.stat().st_size // 2)
    with pytest.raises(ValueError, match=r"^.*cut\.tif: truncated or corrupt TIFF \(") as info:
        open_raw(bad)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("command", [
    ["reconstruct", "{views}", "--out", "{out}"],
    ["depth", "{views}", "--out", "{out}"],
    ["motion", "{views}", "--out", "{out}.tif"],
    ["calibrate-aberration", "{views}", "--out", "{out}"],
])
def test_commands_on_a_truncated_stack_say_one_line(stack, tmp_path, monkeypatch, capsys,
                                                    caplog, command):
    from metasensor.cli import main

    path, _ = stack
    bad = _cut(path, tmp_path / "views.tif", path.stat().st_size // 2)
    argv = [a.format(views=bad, out=tmp_path / "out") for a in command]
    monkeypatch.setattr(sys, "argv", ["metasensor", *argv])
    with caplog.at_level(logging.DEBUG, logger="tifffile"):
        with pytest.raises(SystemExit) as info:
            main()
    assert info.value.code not in (0, None)
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err], err
    assert err.startswith(f"error: {bad}: truncated or corrupt TIFF ("), err
    assert not _tifffile_records(caplog)
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.tif").exists()


def test_lenient_config_read_still_refuses_a_cut_first_page(stack, tmp_path, capsys):
    """strict=False (a caller with its own configuration) ignores a foreign stored
    configuration with a note, but a file cut inside page 0's tags is an error, not a note."""
    path, _ = stack
    bad = _cut(path, tmp_path / "cut.tif", 200)
    with pytest.raises(ValueError, match="truncated or corrupt TIFF"):
        read_config_from_views(bad, strict=False)
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"II*\x00garbage")
    with pytest.raises(ValueError, match="not a readable TIFF"):
        read_config_from_views(junk, strict=False)
    assert "note:" not in capsys.readouterr().err


def test_depth_with_own_config_on_a_cut_stack_says_one_line(stack, tmp_path, monkeypatch,
                                                            capsys):
    from metasensor.cli import main

    path, _ = stack
    cfg = tmp_path / "cfg.toml"
    cfg.write_text(f"nnum = {NNUM}\nscan = 5\n")
    bad = _cut(path, tmp_path / "views.tif", 200)
    monkeypatch.setattr(sys, "argv", ["metasensor", "depth", str(bad), "--config", str(cfg),
                                      "--out", str(tmp_path / "out")])
    with pytest.raises(SystemExit) as info:
        main()
    assert info.value.code not in (0, None)
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and "truncated or corrupt TIFF" in err, err
