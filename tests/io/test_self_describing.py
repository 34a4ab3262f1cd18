"""Self-describing view stacks: a TIFF carries ImageJ metadata (µm pixel size, labelled slices)
next to the JSON description, an OME-Zarr store validates with ``ome-zarr``'s reader (axes,
units, scale), and both round-trip exactly. Reference: the pixel size mla_pitch / scan."""

from __future__ import annotations

import json

import numpy as np
import pytest
import tifffile

from metasensor.config import SystemConfig
from metasensor.io.views import read_config_from_views, read_views, stored_extras, write_views

CFG = SystemConfig(nnum=13, scan=3, moving="image")
UM = CFG.mla_pitch / CFG.scan * 1e6


@pytest.mark.parametrize("dtype", ["float32", "uint16"])
def test_tiff_view_stack_reports_axes_and_pixel_size(tmp_path, dtype):
    views = (np.random.default_rng(1).random((13, 13, 6, 7)) * 100).astype(dtype)
    path = write_views(tmp_path / "v.tif", views, CFG, extra={"moving": "image"})
    with tifffile.TiffFile(path) as tif:
        assert tif.is_imagej and len(tif.pages) == 169
        ij = tif.imagej_metadata
        assert ij["unit"] == "um" and ij["Labels"][2 * 13 + 5] == "view u=2 v=5"
        assert tif.pages[0].resolution == pytest.approx((1 / UM, 1 / UM))
        desc = json.loads(tif.pages[0].description)  # the JSON description stays first
        assert desc["nnum"] == 13 and desc["metasensor"]["axes"] == ["u", "v", "y", "x"]
        assert desc["metasensor"]["pixel_size_m"] == pytest.approx(UM * 1e-6)
    assert tifffile.imread(path).shape == (169, 6, 7)  # page u*nnum + v, as ever
    got = read_views(path)
    assert got.dtype == views.dtype and np.array_equal(got, views)
    assert read_config_from_views(path) == CFG


def test_ome_zarr_view_stack_validates_and_round_trips(tmp_path):
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Reader

    views = np.random.default_rng(2).random((13, 13, 9, 12)).astype(np.float32)
    path = write_views(tmp_path / "v.ome.zarr", views, CFG, extra={"moving": "image"})
    nodes = list(Reader(parse_url(str(path)))())
    assert nodes, "ome-zarr's reader found no image"
    meta = nodes[0].metadata
    assert [a["name"] for a in meta["axes"]] == ["c", "y", "x"]
    assert meta["axes"][1]["unit"] == "micrometer"
    assert meta["coordinateTransformations"][0][0]["scale"] == pytest.approx([1.0, UM, UM])
    assert np.array_equal(np.asarray(nodes[0].data[0]), views.reshape(169, 9, 12))
    got = read_views(path)
    assert got.shape == views.shape and np.array_equal(np.asarray(got), views)
    assert read_config_from_views(path) == CFG
    assert stored_extras(path)["moving"] == "image"


def test_info_names_kind_shape_axes_units_and_configuration(tmp_path):
    from typer.testing import CliRunner

    from metasensor.cli import app

    views = np.zeros((13, 13, 4, 5), np.float32)
    write_views(tmp_path / "v.tif", views, CFG, extra={"source": "raw.tif"})
    res = CliRunner().invoke(app, ["info", str(tmp_path / "v.tif")])
    assert res.exit_code == 0, res.output
    out = res.output
    for want in ("kind: views", "shape: (169, 4, 5)", "axes: ['u', 'v', 'y', 'x']",
                 f"pixel size: {UM:.4g} um", "nnum = 13", "moving = image", "source: raw.tif"):
        assert want in out, (want, out)
    res = CliRunner().invoke(app, ["info", str(tmp_path / "v.tif"), "-o", str(tmp_path / "i.txt")])
    assert res.exit_code == 0 and "kind: views" in (tmp_path / "i.txt").read_text()
    CFG.to_toml(tmp_path / "c.toml")
    res = CliRunner().invoke(app, ["info", str(tmp_path / "c.toml")])
    assert "kind: system configuration" in res.output and "scan = 3" in res.output


def test_provenance_records_version_command_checksums_and_settings(tmp_path, monkeypatch):
    import hashlib
    import sys

    from metasensor.io.provenance import provenance

    (tmp_path / "a.tif").write_bytes(b"abc")
    monkeypatch.setattr(sys, "argv", ["/x/metasensor", "reconstruct", "a.tif"])
    p = provenance({"views": tmp_path / "a.tif", "psf": None}, {"blocks": "2x2"})
    assert p["command"] == ["metasensor", "reconstruct", "a.tif"] and p["version"]
    assert p["inputs"] == {"views": {"path": str(tmp_path / "a.tif"),
                                     "sha256": hashlib.sha256(b"abc").hexdigest()}}
    assert p["settings"] == {"blocks": "2x2"}


def test_ome_zarr_rewrite_replaces_own_store_and_keeps_a_users_folder(tmp_path):
    """An OME-Zarr output replaces only an OME-Zarr store this package wrote (renamed away,
    the new one in, then deleted); a user's folder under that name is refused, untouched."""
    from metasensor.io.atomic import is_own_zarr
    from metasensor.io.omezarr import read_ome_zarr, write_ome_zarr

    img = np.random.default_rng(0).random((130, 130)).astype(np.float32)
    out = tmp_path / "r.ome.zarr"
    write_ome_zarr(out, img, 4.6e-6, {"kind": "image"})
    assert is_own_zarr(out)
    write_ome_zarr(out, 2 * img, 4.6e-6, {"kind": "image"})
    assert np.array_equal(np.asarray(read_ome_zarr(out)[0]), 2 * img)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.ome.zarr"]  # no temporary left
    user = tmp_path / "mine.ome.zarr"
    user.mkdir()
    (user / "notes.txt").write_text("keep")
    with pytest.raises(ValueError, match="not a Zarr store written by metasensor"):
        write_ome_zarr(user, img, None, {})
    assert (user / "notes.txt").read_text() == "keep"
