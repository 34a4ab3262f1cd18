"""View stacks on disk: TIFF page layout u*nnum+v, metadata round trip, Zarr, bad files."""

import numpy as np
import pytest
import tifffile

import metasensor as ms
from metasensor.io.views import read_config_from_views, read_views, write_views


def test_tiff_layout_and_config_round_trip(tmp_path):
    cfg = ms.SystemConfig(nnum=5, scan=5)
    views = np.arange(5 * 5 * 4 * 6, dtype=np.float32).reshape(5, 5, 4, 6)
    path = write_views(tmp_path / "v.tif", views, cfg)
    pages = tifffile.imread(path)
    np.testing.assert_array_equal(pages[2 * 5 + 3], views[2, 3])  # page u*nnum + v
    np.testing.assert_array_equal(read_views(path), views)
    assert read_config_from_views(path) == cfg
    assert not list(tmp_path.glob(".v.tif*"))  # no temporary left behind


def test_zarr_round_trip(tmp_path):
    cfg = ms.SystemConfig(nnum=3, scan=3)
    views = np.random.default_rng(0).random((3, 3, 8, 8)).astype(np.float32)
    path = write_views(tmp_path / "v.zarr", views, cfg)
    np.testing.assert_array_equal(np.asarray(read_views(path)[:]), views)
    assert read_config_from_views(path) == cfg


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="nnum, nnum, H, W"):
        write_views(tmp_path / "x.tif", np.zeros((3, 4, 5, 5)))
    with pytest.raises(ValueError, match=r"\.tif"):
        write_views(tmp_path / "x.png", np.zeros((3, 3, 5, 5)))
    with pytest.raises(FileNotFoundError):
        read_views(tmp_path / "missing.tif")
    bad = tmp_path / "bad.tif"
    bad.write_bytes(b"II*\x00garbage")
    with pytest.raises(ValueError, match="not a readable TIFF"):
        read_views(bad)
    tifffile.imwrite(tmp_path / "five.tif", np.zeros((5, 4, 4), np.float32))
    with pytest.raises(ValueError, match="not nnum"):
        read_views(tmp_path / "five.tif", nnum=3)


def test_zarr_write_over_a_plain_file_fails_cleanly_and_bad_metadata_is_named(tmp_path):
    cfg = ms.SystemConfig(nnum=3, scan=3)
    target = tmp_path / "v.zarr"
    target.write_text("not a store")
    with pytest.raises(ValueError, match="not a Zarr store"):
        write_views(target, np.zeros((3, 3, 4, 4), np.float32), cfg)
    assert target.read_text() == "not a store"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.zarr"]  # no temporary left
    bad = tmp_path / "bad.tif"
    tifffile.imwrite(bad, np.zeros((9, 4, 4), np.float32), photometric="minisblack",
                     description='{"metasensor": "x"}', metadata=None)
    assert read_config_from_views(bad) is None
    tifffile.imwrite(bad, np.zeros((9, 4, 4), np.float32), photometric="minisblack",
                     description='{"metasensor": {"config": "x"}}', metadata=None)
    with pytest.raises(ValueError, match="not a table"):
        read_config_from_views(bad)


def test_description_is_the_configuration_as_json_and_old_layouts_still_read(tmp_path):
    # interface.md: "metadata (the system configuration) goes into the TIFF's description as JSON"
    import json

    cfg = ms.SystemConfig(nnum=3, scan=3)
    views = np.zeros((3, 3, 4, 4), np.float32)
    path = write_views(tmp_path / "v.tif", views, cfg, extra={"scale": 2.0})
    desc = tifffile.TiffFile(path).pages[0].description
    assert ms.SystemConfig.from_json(desc) == cfg
    meta = json.loads(desc)
    assert meta["scan"] == 3 and meta["metasensor"]["kind"] == "views"
    assert meta["metasensor"]["scale"] == 2.0
    # a bare configuration written by someone else, and this package's older nested layout
    for text in (cfg.to_json(), json.dumps({"metasensor": {"config": cfg.to_dict()}})):
        other = tmp_path / "other.tif"
        tifffile.imwrite(other, views.reshape(9, 4, 4), photometric="minisblack",
                         description=text, metadata=None)
        assert read_config_from_views(other) == cfg


def test_a_given_config_must_sample_like_the_stored_one(tmp_path, capsys):
    from metasensor.io.views import check_against_stored

    cfg = ms.SystemConfig(nnum=3, scan=3)
    with pytest.raises(ValueError, match="scan = 1 but .* scan = 3"):
        check_against_stored(cfg.replace(scan=1), cfg, tmp_path / "c.toml", tmp_path / "v.tif")
    check_against_stored(cfg.replace(na=0.04), cfg, tmp_path / "c.toml", tmp_path / "v.tif")
    assert "na" in capsys.readouterr().err
    check_against_stored(cfg, cfg, tmp_path / "c.toml", tmp_path / "v.tif")
    assert capsys.readouterr().err == ""
