"""Mosaic pieces at small size: registration against known offsets, exact blending, the pyramid,
the same result through a dask.distributed cluster."""

import numpy as np
import pytest
import zarr
from scipy import ndimage

from metasensor.mosaic import (
    MosaicLayout,
    blend_tiles,
    open_mosaic,
    register_tiles,
    solve_positions,
)


def _texture(shape, seed=5):
    rng = np.random.default_rng(seed)
    return ndimage.gaussian_filter(rng.standard_normal(shape), 1.5) * 100


def _cut(big, layout, jitter, seed=0):
    """Tiles of ``big`` at the nominal origins plus up to ``jitter`` px (tile (0, 0) exact)."""
    rng = np.random.default_rng(seed)
    th, tw = layout.tile_shape
    tiles, true = {}, {}
    for k in layout.indices:
        o = np.array(layout.origin(k), float)
        if k != (0, 0):
            o += rng.uniform(-jitter, jitter, 2)
        yy, xx = np.meshgrid(o[0] + np.arange(th), o[1] + np.arange(tw), indexing="ij")
        tiles[k] = ndimage.map_coordinates(big, [yy, xx], order=3).astype(np.float32)
        true[k] = tuple(o)
    return tiles, true


def _store(tiles, folder):
    paths = {}
    for (i, j), t in tiles.items():
        p = str(folder / f"tile_{i}_{j}.zarr")
        z = zarr.open_array(p, mode="w", shape=t.shape, chunks=(64, 64), dtype="f4",
                            zarr_format=2)
        z[:] = t
        paths[(i, j)] = p
    return paths


def test_registration_within_0_1_px_of_known_offsets():
    layout = MosaicLayout((160, 160), (2, 3), overlap=40)
    tiles, true = _cut(_texture((400, 520)), layout, jitter=2.5)
    pos = solve_positions(register_tiles(tiles, layout), layout)
    err = max(np.hypot(pos[k][0] - true[k][0], pos[k][1] - true[k][1]) for k in layout.indices)
    assert err <= 0.1


def test_blending_is_exact_on_integer_tiles_and_writes_a_pyramid(tmp_path):
    layout = MosaicLayout((96, 128), (2, 2), overlap=24)
    big = _texture(layout.shape).astype(np.float32)
    tiles = {k: big[o[0]:o[0] + 96, o[1]:o[1] + 128]
             for k in layout.indices for o in [layout.origin(k)]}
    paths = _store(tiles, tmp_path)
    pos = {k: tuple(float(v) for v in layout.origin(k)) for k in layout.indices}
    out = blend_tiles(paths, pos, layout.shape, tmp_path / "m.zarr", ramp=16, chunk=64)
    level0 = open_mosaic(out)[:]
    # every pixel, the mosaic's outermost ring included, is covered and exact
    assert np.allclose(level0, big, rtol=0, atol=1e-4)
    meta = zarr.open_group(str(out), mode="r").attrs["multiscales"][0]
    assert [d["path"] for d in meta["datasets"]] == ["0", "1", "2"]
    level1 = open_mosaic(out, 1)[:]
    assert level1.shape == (layout.shape[0] // 2, layout.shape[1] // 2)
    assert np.allclose(level1, level0[:level1.shape[0] * 2, :level1.shape[1] * 2].reshape(
        level1.shape[0], 2, level1.shape[1], 2).mean(axis=(1, 3)), atol=1e-4)
    assert np.array_equal(zarr.open_array(paths[(0, 0)], mode="r")[:], tiles[(0, 0)])
    assert not list(tmp_path.glob(".m.zarr.*"))
    # an earlier mosaic is replaced; anything else is not
    blend_tiles(paths, pos, layout.shape, out, ramp=16, chunk=64)
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(ValueError, match="not replaced"):
        blend_tiles(paths, pos, layout.shape, tmp_path / "mine", ramp=16, chunk=64)
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"


def test_subpixel_blend_of_registered_tiles_has_no_seam(tmp_path):
    from metasensor.mosaic.seams import seam_ratio

    layout = MosaicLayout((128, 128), (2, 2), overlap=32)
    big = _texture((260, 260))
    tiles, _ = _cut(big, layout, jitter=1.5, seed=3)
    pos = solve_positions(register_tiles(tiles, layout), layout)
    out = blend_tiles(_store(tiles, tmp_path), pos, layout.shape, tmp_path / "m.zarr",
                      ramp=24, chunk=64)
    c = 4  # the mosaic's own edges (uncovered where tiles moved inwards) are not seams
    img = open_mosaic(out)[c:-c, c:-c]
    truth = big[c:img.shape[0] + c, c:img.shape[1] + c]
    ys = [int(round(pos[(1, 0)][0])) - c, 128 - c]  # where the lower tile starts, the upper ends
    xs = [int(round(pos[(0, 1)][1])) - c, 128 - c]
    assert seam_ratio(img, ys, xs) <= seam_ratio(truth, ys, xs) + 0.05
    assert np.abs(img - truth).max() < 0.05 * np.abs(truth).max()


def test_blending_on_the_covered_rectangle_leaves_no_empty_rim(tmp_path):
    layout = MosaicLayout((128, 128), (2, 2), overlap=32)
    big = _texture((260, 260))
    tiles, true = _cut(big, layout, jitter=1.5, seed=3)
    pos = solve_positions(register_tiles(tiles, layout), layout)
    # nominal canvas: a tile that moved inwards leaves mosaic pixels no tile reaches
    full = open_mosaic(blend_tiles(_store(tiles, tmp_path), pos, layout.shape,
                                   tmp_path / "full.zarr", ramp=24, chunk=64))[:]
    y0, x0, y1, x1 = layout.covered(pos)
    assert (y0, x0) == (max(int(np.ceil(pos[(0, j)][0] - 1e-6)) for j in range(2)),
                        max(int(np.ceil(pos[(i, 0)][1] - 1e-6)) for i in range(2)))
    assert y1 <= min(true[(1, j)][0] for j in range(2)) + 128 + 0.1
    assert x1 <= min(true[(i, 1)][1] for i in range(2)) + 128 + 0.1
    placed = {k: (v[0] - y0, v[1] - x0) for k, v in pos.items()}
    img = open_mosaic(blend_tiles(_store(tiles, tmp_path), placed, (y1 - y0, x1 - x0),
                                  tmp_path / "box.zarr", ramp=24, chunk=64))[:]
    assert img.shape == (y1 - y0, x1 - x0)
    truth = big[y0:y1, x0:x1]
    # (the tiles' first two rows or columns sampled outside `big` where they moved to < 0)
    assert np.abs(img - truth)[2:, 2:].max() < 0.05 * np.abs(truth).max()
    rim = np.concatenate([img[0], img[-1], img[:, 0], img[:, -1]])
    assert np.all(rim != 0)  # every rim pixel has a tile's data
    assert np.allclose(img, full[y0:y1, x0:x1], atol=1e-5)
    assert (np.abs(full) < 1e-9).sum() > 0  # the nominal canvas did have an empty rim
    with pytest.raises(ValueError, match="lack tile"):
        layout.covered({(0, 0): (0.0, 0.0)})


@pytest.mark.slow
def test_local_cluster_equals_local_threads(tmp_path):
    from distributed import LocalCluster

    layout = MosaicLayout((96, 96), (2, 2), overlap=24)
    tiles, _ = _cut(_texture((200, 200)), layout, jitter=1.0)
    paths = _store(tiles, tmp_path)
    pos = solve_positions(register_tiles(tiles, layout), layout)
    a = open_mosaic(blend_tiles(paths, pos, layout.shape, tmp_path / "a.zarr", chunk=64))[:]
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False) as cluster:
        b = open_mosaic(blend_tiles(paths, pos, layout.shape, tmp_path / "b.zarr", chunk=64,
                                    scheduler=cluster))[:]
    assert np.abs(a - b).max() <= 1e-5
