"""Bad input to the slanted-edge MTF: one-line ValueError/TypeError naming the problem."""

import numpy as np
import pytest

from metasensor.metrics import slanted_edge_mtf
from metasensor.metrics import synthetic as S


@pytest.fixture(scope="module")
def img():
    return S.render_gaussian_edge_supersampled((64, 64), 5.0, 0.6, factor=8)


def one_line(exc):
    assert "\n" not in str(exc.value)


def test_nan_and_shapes(img):
    bad = img.copy()
    bad[10, 10] = np.nan
    with pytest.raises(ValueError, match="NaN") as e:
        slanted_edge_mtf(bad)
    one_line(e)
    with pytest.raises(ValueError, match="2-D"):
        slanted_edge_mtf(img[0])
    with pytest.raises(TypeError, match="numeric"):
        slanted_edge_mtf(np.full((64, 64), "a"))


def test_bad_roi(img):
    for roi in [(10, 10, 0, 64), (0, 64, 30, 20), (0, 80, 0, 64), (-1, 10, 0, 10), (1, 2, 3)]:
        with pytest.raises(ValueError, match="roi") as e:
            slanted_edge_mtf(img, roi=roi)
        one_line(e)
    with pytest.raises(ValueError, match="too small"):
        slanted_edge_mtf(img, roi=(0, 5, 0, 64))


def test_no_edge(img):
    with pytest.raises(ValueError, match="no edge") as e:
        slanted_edge_mtf(np.full((64, 64), 0.5))
    one_line(e)
    noise = np.random.default_rng(0).normal(0.5, 0.05, (64, 64))
    with pytest.raises(ValueError, match="no edge"):
        slanted_edge_mtf(noise)
    with pytest.raises(ValueError, match="no edge"):  # a flat part of the edge image
        slanted_edge_mtf(img, roi=(0, 64, 0, 16))


def test_edge_not_slanted():
    straight = np.zeros((64, 64))
    straight[:, 32:] = 1.0
    with pytest.raises(ValueError, match="tilted") as e:
        slanted_edge_mtf(straight)
    one_line(e)


def test_bad_options(img):
    with pytest.raises(ValueError, match="window"):
        slanted_edge_mtf(img, window="kaiser")
    with pytest.raises(ValueError, match="oversample"):
        slanted_edge_mtf(img, oversample=0)
    with pytest.raises(ValueError, match="pixel_pitch"):
        slanted_edge_mtf(img, pixel_pitch=-1.0)


def test_input_not_modified(img):
    before = img.copy()
    slanted_edge_mtf(img)
    np.testing.assert_array_equal(img, before)
