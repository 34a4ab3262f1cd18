"""Scene image files (``simulate --scene FILE``): a truncated or corrupt TIFF and an undecodable
PNG are refused with one line naming the file (never page 0 of a cut stack, never imageio's
plugin advice)."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import tifffile

from metasensor.simulation.scenes import load_scene


@pytest.fixture
def png(tmp_path):
    import imageio.v3 as iio

    path = tmp_path / "ok.png"
    iio.imwrite(path, (np.random.default_rng(0).random((40, 40)) * 255).astype(np.uint8))
    return path


def test_truncated_multipage_tiff_scene_refused(tmp_path, caplog):
    stack = tmp_path / "stack.tif"
    tifffile.imwrite(stack, np.random.default_rng(1).random((20, 32, 32)).astype(np.float32),
                     metadata=None)
    data = stack.read_bytes()
    cut = tmp_path / "cut.tif"
    cut.write_bytes(data[: len(data) // 2])
    with caplog.at_level(logging.DEBUG, logger="tifffile"):
        with pytest.raises(ValueError) as info:
            load_scene(str(cut), 32)
    msg = str(info.value)
    assert msg.startswith(f"{cut}: truncated or corrupt TIFF (") and "\n" not in msg
    assert not [r for r in caplog.records if r.name.startswith("tifffile")]


def test_truncated_single_page_tiff_scene_refused(tmp_path):
    one = tmp_path / "one.tif"
    tifffile.imwrite(one, np.random.default_rng(1).random((64, 64)).astype(np.float32))
    data = one.read_bytes()
    cut = tmp_path / "cut1.tif"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="truncated or corrupt TIFF") as info:
        load_scene(str(cut), 32)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("kind", ["half", "junk"])
def test_unreadable_png_scene_is_one_line(png, tmp_path, kind):
    data = png.read_bytes()
    bad = tmp_path / "bad.png"
    bad.write_bytes(data[: len(data) // 2] if kind == "half" else b"not an image" * 30)
    with pytest.raises(ValueError) as info:
        load_scene(str(bad), 32)
    msg = str(info.value)
    assert msg.startswith(f"{bad}: not a readable image (") and "\n" not in msg
    assert "pip install" not in msg


def test_good_scene_files_still_load(png, tmp_path):
    img = load_scene(str(png), 32)
    assert img.shape == (32, 32) and 0 <= img.min() <= img.max() <= 1
    tif = tmp_path / "ok.tif"
    tifffile.imwrite(tif, np.random.default_rng(2).random((48, 48)).astype(np.float32))
    assert load_scene(str(tif), 32).shape == (32, 32)
