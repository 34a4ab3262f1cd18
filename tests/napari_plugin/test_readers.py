"""The plugin's reader: every file kind metasensor writes opens as layers with the right shape,
axes and physical scale (sensor-plane µm) in a headless napari viewer."""

import json

import numpy as np
import pytest
import tifffile
from plugin_helpers import CFG, P_UM

from metasensor.io.views import read_views, write_views


def _open(viewer, path):
    layers = viewer.open(str(path), plugin="metasensor")
    assert layers, f"nothing opened from {path}"
    return layers


def test_manifest_declares_the_reader_and_entry_point():
    import tomllib
    from pathlib import Path

    import npe2

    root = Path(__file__).parents[2]
    pyproject = tomllib.loads((root / "pyproject.toml").read_text())
    assert pyproject["project"]["entry-points"]["napari.manifest"]["metasensor"] == \
        "metasensor.napari:napari.yaml"
    assert "napari/napari.yaml" in pyproject["tool"]["setuptools"]["package-data"]["metasensor"]
    extras = pyproject["project"]["optional-dependencies"]
    assert "metasensor[napari]" in extras["dev"]
    manifest = npe2.PluginManifest.from_file(root / "src/metasensor/napari/napari.yaml")
    assert manifest.name == "metasensor" and manifest.contributions.readers


def test_view_stacks_are_one_4d_layer(make_napari_viewer, capture, tmp_path):
    """TIFF, Zarr, OME-Zarr and OME-TIFF view stacks: one (u, v, y, x) layer each."""
    import zarr

    viewer = make_napari_viewer()
    (layer,) = _open(viewer, capture / "views.tif")
    views = read_views(capture / "views.tif")
    assert layer.data.shape == views.shape == (5, 5, 35, 35)
    np.testing.assert_array_equal(np.asarray(layer.data), views)
    assert tuple(layer.axis_labels) == ("u", "v", "y", "x")
    assert [str(u) for u in layer.units[2:]] == ["micrometer", "micrometer"]
    # view samples d = nnum // scan = 1 px apart; sample (0, 0) at sensor px o + d // 2 = 2
    np.testing.assert_allclose(layer.scale, (1, 1, P_UM, P_UM))
    np.testing.assert_allclose(layer.translate, (0, 0, 2 * P_UM, 2 * P_UM))
    assert viewer.dims.ndim == 4  # the (u, v) sliders
    assert viewer.dims.axis_labels[:2] == ("u", "v")

    views = read_views(capture / "views.tif").astype(np.float32)
    write_views(tmp_path / "views.zarr", views, CFG, extra={"origin": [1.0, 2.0]})
    # an OME-Zarr group: level 0 of a multiscale, physical size 2.5 µm
    root = zarr.open_group(str(tmp_path / "ome.zarr"), mode="w")
    root.create_array("0", data=views)
    root.attrs["ome"] = {"version": "0.5", "multiscales": [{
        "axes": [{"name": "u"}, {"name": "v"}, {"name": "y", "unit": "micrometer"},
                 {"name": "x", "unit": "micrometer"}],
        "datasets": [{"path": "0", "coordinateTransformations": [
            {"type": "scale", "scale": [1, 1, 2.5, 2.5]}]}]}]}
    # an OME-TIFF of nnum² planes with its physical size
    tifffile.imwrite(tmp_path / "views.ome.tif", views.reshape(25, 35, 35), ome=True,
                     metadata={"axes": "ZYX", "PhysicalSizeX": 3.0, "PhysicalSizeY": 3.0})
    (z,) = _open(viewer, tmp_path / "views.zarr")
    assert z.data.shape == (5, 5, 35, 35) and tuple(z.axis_labels) == ("u", "v", "y", "x")
    np.testing.assert_allclose(z.translate[2:], ((1 + 2) * P_UM, (2 + 2) * P_UM))  # origin
    np.testing.assert_array_equal(np.asarray(z.data[2, 3]), views[2, 3])
    (o,) = _open(viewer, tmp_path / "ome.zarr")
    assert o.data.shape == (5, 5, 35, 35)
    np.testing.assert_allclose(o.scale, (1, 1, 2.5, 2.5))
    (t,) = _open(viewer, tmp_path / "views.ome.tif")
    assert t.data.shape == (5, 5, 35, 35)
    np.testing.assert_allclose(t.scale, (1, 1, 3.0, 3.0))
    np.testing.assert_array_equal(np.asarray(t.data), views)


def test_frames_calibration_and_result_folders(make_napari_viewer, capture, tmp_path):
    """Raw frames, a capture folder, a calibration's grid, and reconstruct/depth outputs."""
    from metasensor.io.views import description
    from metasensor.sensor.calibration import Calibration

    viewer = make_napari_viewer()
    (frames,) = _open(viewer, capture / "frames.tif")
    assert frames.data.shape == (25, 40, 40) and tuple(frames.axis_labels) == ("t", "y", "x")
    np.testing.assert_allclose(frames.scale, (1, P_UM, P_UM))
    layers = _open(viewer, capture)
    kinds = [la.metadata["metasensor"]["kind"] for la in layers]
    assert kinds == ["frames", "views", "truth"]
    truth = layers[2]
    assert truth.data.shape == (35, 35)
    np.testing.assert_allclose(truth.translate, (2 * P_UM, 2 * P_UM))  # o = 2 px

    calib = Calibration(nnum=5, pitch=5.0, rotation=0.0, center=(2.0, 2.0), lenslets=(7, 7),
                        sensor_shape=(40, 40))
    calib.to_toml(tmp_path / "calib.toml")
    CFG.to_toml(tmp_path / "config.toml")
    (grid,) = _open(viewer, tmp_path / "calib.toml")
    assert grid._type_string == "shapes" and len(grid.data) == 8 + 8
    assert set(grid.shape_type) == {"line"}
    np.testing.assert_allclose(grid.scale, (P_UM, P_UM))
    # the first row border runs along sensor row -0.5 from column -0.5 to 34.5
    np.testing.assert_allclose(grid.data[0], [[-0.5, -0.5], [-0.5, 34.5]])

    # a reconstruct folder (image.tif + zernike.npy) with a depth map: the image, the grid of
    # wavefront maps and the disparity, each on its grid
    res = tmp_path / "result"
    res.mkdir()
    image = np.random.default_rng(0).random((35, 35)).astype(np.float32)
    desc = description(CFG, kind="image", method="wave", origin=[1.0, 0.0])
    tifffile.imwrite(res / "image.tif", image, description=json.dumps(desc), metadata=None)
    z = np.zeros((2, 3, 45), np.float32)
    z[1, 2, 4] = 0.5  # Noll 5 (oblique astigmatism) in the lower-right block
    np.save(res / "zernike.npy", z)
    disp = np.ones((35, 35), np.float32)
    tifffile.imwrite(res / "disparity.tif", disp, metadata=None,
                     description=json.dumps({"metasensor": {"kind": "disparity"}}))
    layers = _open(viewer, res)
    by_kind = {la.metadata["metasensor"]["kind"]: la for la in layers}
    assert set(by_kind) == {"image", "disparity", "wavefront"}
    img = by_kind["image"]
    np.testing.assert_array_equal(img.data, image)
    np.testing.assert_allclose(img.translate, ((1 + 2) * P_UM, 2 * P_UM))
    wf = by_kind["wavefront"]
    assert wf.data.shape == (2 * 35, 3 * 35)  # 33-px maps, 2 px apart
    np.testing.assert_allclose(np.asarray(wf.data.shape) * wf.scale, np.array(image.shape) * P_UM)
    assert np.nanmax(np.abs(wf.data[:35, :70])) == 0  # flat blocks
    assert np.nanmax(np.abs(wf.data[35:, 70:])) > 0.5  # 0.5 λ r.m.s. astigmatism peaks higher
    assert by_kind["disparity"].data.shape == (35, 35)


@pytest.mark.parametrize("name", ["notes.txt", "empty"])
def test_reader_declines_foreign_paths(tmp_path, name):
    from metasensor.napari.readers import get_reader

    (tmp_path / name).mkdir() if name == "empty" else (tmp_path / name).write_text("x")
    assert get_reader(str(tmp_path / name)) is None


def test_a_foreign_prototype_sized_stack_says_its_scan_was_assumed(make_napari_viewer, tmp_path):
    """A 15 x 15 view stack with no configuration: the reader takes the prototype's 5 x 5 scan
    for the samples' spacing, and the layer's name says so (a plain 15 x 15 light field would
    otherwise show 5 times too fine without a word)."""
    tifffile.imwrite(tmp_path / "lf.tif", np.ones((225, 8, 8), np.float32), metadata=None)
    viewer = make_napari_viewer()
    (layer,) = _open(viewer, tmp_path / "lf.tif")
    assert layer.data.shape == (15, 15, 8, 8)
    assert layer.name == "lf (scan 5 x 5 assumed)"
