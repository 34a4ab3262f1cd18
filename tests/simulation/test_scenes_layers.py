"""Built-in scenes and the field/depth partitions of unity."""

import numpy as np
import pytest

from metasensor.simulation.layers import build_components, depth_layers, field_grid
from metasensor.simulation.scenes import (
    SCENES,
    checkerboard,
    load_scene,
    point_grid,
    resolution_chart,
)


def test_chart_has_slanted_edges_star_and_bars():
    chart = resolution_chart(512)
    assert chart.shape == (512, 512) and chart.dtype == np.float32
    assert 0.0 <= chart.min() < 0.1 and 0.9 < chart.max() <= 1.0
    # slanted edge: the dark square's left edge column moves along the rows by tan(5°)
    sq = chart[20:110, 0:128] < 0.5
    first = np.array([np.argmax(r) for r in sq[10:80]], float)
    slope = np.polyfit(np.arange(first.size), first, 1)[0]
    assert abs(abs(slope) - np.tan(np.radians(5))) < 0.02
    # Siemens star: many dark/light transitions around a circle at the centre
    t = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    ring = chart[(256 + 60 * np.sin(t)).astype(int), (256 + 60 * np.cos(t)).astype(int)] < 0.5
    assert 30 <= np.count_nonzero(np.diff(ring.astype(int))) <= 40


@pytest.mark.parametrize("name", ["chart", "checkerboard", "points", "point", "uniform",
                                  "camera", "astronaut"])
def test_load_scene_shapes(name):
    img = load_scene(name, 96)
    assert img.shape == (96, 96) and img.dtype == np.float32
    assert np.isfinite(img).all() and img.min() >= 0


def test_scene_helpers_and_errors(tmp_path):
    assert checkerboard(32, 8)[0, 0] != checkerboard(32, 8)[0, 8]
    assert point_grid(64, 16).sum() == 16
    assert "chart" in SCENES
    with pytest.raises(ValueError, match="unknown scene"):
        load_scene("nope", 64)
    with pytest.raises(FileNotFoundError):
        load_scene(str(tmp_path / "missing.tif"), 64)
    import tifffile

    tifffile.imwrite(tmp_path / "a.tif", np.arange(100, dtype=np.uint16).reshape(10, 10))
    img = load_scene(str(tmp_path / "a.tif"), 20)
    assert img.shape == (20, 20) and abs(img.max() - 1) < 0.1


def test_field_weights_are_a_partition_of_unity():
    grid = np.random.default_rng(0).random((3, 4, 6))
    comps, _ = build_components((90, 100), None, grid, None)
    total = sum(c.weight for c in comps)
    np.testing.assert_allclose(total, 1.0, atol=1e-6)
    for c in comps:  # the box holds all of the weight
        y0, y1, x0, x1 = c.box
        assert np.isclose(c.weight[y0:y1 + 1, x0:x1 + 1].sum(), c.weight.sum())
    # a callable field map is evaluated at the block centres
    g = field_grid(lambda yn, xn: np.stack([yn, xn], -1), (90, 100), (2, 2))
    np.testing.assert_allclose(g[..., 0], [[-0.5, -0.5], [0.5, 0.5]])


def test_depth_layers():
    depth = np.zeros((20, 20))
    depth[:, 10:] = 1e-4
    planes, w = depth_layers(depth, (20, 20))
    np.testing.assert_allclose(planes, [0, 1e-4])
    assert np.array_equal(w[1], depth > 0)
    smooth = np.linspace(0, 1e-3, 400).reshape(20, 20)
    planes, w = depth_layers(smooth, (20, 20), max_planes=5)
    assert planes.size == 5
    np.testing.assert_allclose(w.sum(0), 1, atol=1e-12)
    np.testing.assert_allclose((w * planes[:, None, None]).sum(0), smooth, atol=1e-12)
    with pytest.raises(ValueError, match="depth map shape"):
        depth_layers(np.zeros((3, 3)), (20, 20))
