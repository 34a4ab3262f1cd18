"""Multisite blocks: partition, d-aligned borders, partition-of-unity weights, Zernike per block."""

import numpy as np
import pytest

from metasensor.recon.blocks import (
    Stitcher,
    block_centre_normalised,
    block_weights,
    block_zernikes,
    split_blocks,
)


@pytest.mark.parametrize("blocks", [(1, 1), (2, 3), (4, 4)])
def test_blocks_cover_field_and_weights_sum_to_one(blocks):
    shape, d = (240, 300), 3
    bl = split_blocks(shape, blocks, d, overlap=20, margin=15)
    assert len(bl) == blocks[0] * blocks[1]
    total = np.zeros(shape)
    cores = np.zeros(shape, int)
    for b in bl:
        for v in (*b.core, *b.region, *b.window):
            assert v % d == 0  # aligned to the view sampling
        y0, y1, x0, x1 = b.core
        cores[y0:y1, x0:x1] += 1
        y0, y1, x0, x1 = b.region
        w = block_weights(b, shape)
        assert w.min() >= 0 and w.max() <= 1
        total[y0:y1, x0:x1] += w
    assert (cores == 1).all()  # cores partition the field
    np.testing.assert_allclose(total, 1.0, atol=1e-6)  # weights: a partition of unity


def test_stitching_a_constant_is_seamless():
    shape = (120, 120)
    bl = split_blocks(shape, (3, 3), 3, overlap=20)
    st = Stitcher(shape)
    for b in bl:
        y0, y1, x0, x1 = b.region
        st.add(b, np.full((y1 - y0, x1 - x0), 2.5, np.float32))
    np.testing.assert_allclose(st.out, 2.5, rtol=1e-6)
    with pytest.raises(ValueError, match="expected"):
        st.add(bl[0], np.zeros((3, 3)))


def test_overlap_is_at_least_requested():
    bl = split_blocks((240, 240), (2, 2), 3, overlap=20)
    a, b = bl[0], bl[1]
    assert a.region[3] - b.region[2] >= 20


def test_bad_blocks():
    with pytest.raises(ValueError, match="too small"):
        split_blocks((60, 60), (6, 6), 3, overlap=20)
    with pytest.raises(ValueError, match="whole number"):
        split_blocks((61, 60), (1, 1), 3)
    with pytest.raises(ValueError, match="positive"):
        split_blocks((60, 60), (0, 1), 3)


def test_block_zernikes_matching_grid_callable_and_global():
    shape = (240, 240)
    bl = split_blocks(shape, (2, 2), 3)
    grid = np.arange(2 * 2 * 5, dtype=float).reshape(2, 2, 5)
    z = block_zernikes(bl, shape, (2, 2), field_zernike=grid)
    assert z.shape == (2, 2, 45)
    np.testing.assert_allclose(z[..., :5], grid)
    glob = np.zeros(6)
    glob[3] = 0.5

    def linear(yn, xn):
        return np.stack([yn, xn], axis=-1)

    z2 = block_zernikes(bl, shape, (2, 2), zernike=glob, field_zernike=linear)
    for b in bl:
        yn, xn = block_centre_normalised(b, shape)
        np.testing.assert_allclose(z2[b.index][:2], [yn, xn], atol=1e-6)
        assert z2[b.index][3] == pytest.approx(0.5)
    assert not block_zernikes(bl, shape, (2, 2)).any()
    with pytest.raises(ValueError, match="zernike"):
        block_zernikes(bl, shape, (2, 2), zernike=np.ones((2, 2)))
