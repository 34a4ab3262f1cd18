"""Raw frame streams from multi-page TIFF: exact frames, streaming (memory map or page by page),
truncated/corrupt files rejected with one line, the file never modified."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import tifffile

from metasensor.io.raw import open_raw, write_raw


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def frames(rng):
    return rng.integers(0, 4096, (7, 31, 45)).astype(np.uint16)


@pytest.mark.parametrize("mmap", [True, False])
def test_stream_frames(tmp_path, frames, mmap):
    path = write_raw(tmp_path / "raw.tif", frames)
    before = digest(path)
    with open_raw(path, mmap=mmap) as raw:
        assert raw.shape == frames.shape and raw.dtype == np.uint16 and len(raw) == 7
        assert (raw._mm is not None) == mmap  # uncompressed files are memory-mapped
        for t, frame in enumerate(raw):
            np.testing.assert_array_equal(frame, frames[t])
        frame = raw[2]
        frame[:] = 0  # a copy: writing to it never touches the file
        np.testing.assert_array_equal(raw.read(1, 4), frames[1:4])
        np.testing.assert_array_equal(raw[-1], frames[-1])
        with pytest.raises(IndexError):
            raw[7]
    assert digest(path) == before


def test_compressed_pages_decoded_one_by_one(tmp_path, frames):
    path = tmp_path / "raw_zlib.tif"
    tifffile.imwrite(path, frames, compression="zlib")
    with open_raw(path) as raw:
        assert raw._mm is None
        np.testing.assert_array_equal(np.stack(list(raw)), frames)


@pytest.mark.parametrize("cut", [100, 3000, 20000])
def test_truncated_tiff(tmp_path, frames, cut):
    path = write_raw(tmp_path / "raw.tif", frames)
    data = path.read_bytes()
    bad = tmp_path / "cut.tif"
    bad.write_bytes(data[: len(data) - cut] if cut != 100 else data[:cut])
    before = digest(bad)
    with pytest.raises(ValueError, match="truncated") as info:
        open_raw(bad)
    assert "\n" not in str(info.value)
    assert digest(bad) == before


def test_not_a_tiff_and_missing(tmp_path):
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"hello, this is not a tiff at all" * 10)
    with pytest.raises(ValueError, match="not a readable TIFF"):
        open_raw(junk)
    with pytest.raises(FileNotFoundError, match="not found"):
        open_raw(tmp_path / "missing.tif")


def test_rgb_pages_rejected(tmp_path):
    path = tmp_path / "rgb.tif"
    tifffile.imwrite(path, np.zeros((2, 20, 20, 3), np.uint8), photometric="rgb")
    with pytest.raises(ValueError, match="2-D greyscale"):
        open_raw(path)


@pytest.mark.parametrize("mmap", [True, False])
def test_one_ifd_contiguous_series_gives_every_frame(tmp_path, mmap):
    # tifffile truncate=True / ImageJ over 4 GB: one IFD for all frames (was read as 1 frame)
    frames = (np.arange(9 * 32 * 40) % 4000).reshape(9, 32, 40).astype(np.uint16)
    tifffile.imwrite(tmp_path / "ij.tif", frames, imagej=True, truncate=True)
    with open_raw(tmp_path / "ij.tif", mmap=mmap) as raw:
        assert raw.shape == (9, 32, 40)
        np.testing.assert_array_equal(raw.read(), frames)
        np.testing.assert_array_equal(raw[5], frames[5])
