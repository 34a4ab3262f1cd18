"""The fringe ratio at block borders against analytic error fields."""

import numpy as np
import pytest

from metasensor.metrics.fringes import block_borders, border_mask, fringe_ratio


def test_border_mask_marks_width_pixels_either_side():
    m = border_mask((40, 30), [20], [], width=3)
    assert m[17:23].all() and not m[:17].any() and not m[23:].any()
    m = border_mask((40, 30), [], [10, 20], width=2)
    assert m[:, 8:12].all() and m[:, 18:22].all() and m.sum() == 40 * 8


def test_ratio_of_two_known_error_levels():
    truth = np.random.default_rng(0).random((96, 96))
    near = border_mask(truth.shape, [32, 64], [48])
    image = truth + np.where(near, 0.3, 0.1)  # error 0.3 at the borders, 0.1 elsewhere
    assert fringe_ratio(truth=truth, image=image, rows=[32, 64], cols=[48]) == pytest.approx(9.0)
    # white noise of one level everywhere reads about 1
    noisy = truth + np.random.default_rng(1).normal(0, 0.05, truth.shape)
    assert fringe_ratio(truth=truth, image=noisy, rows=[32, 64], cols=[48]) == pytest.approx(
        1.0, abs=0.1)
    assert np.isnan(fringe_ratio(truth=truth, image=truth, rows=[32], cols=[]))
    with pytest.raises(ValueError, match="differs from truth"):
        fringe_ratio(truth=truth, image=truth[:10], rows=[32], cols=[])


def test_block_borders_are_the_cores_interior_edges():
    ys, xs = block_borders((375, 375), (3, 3), 3)
    assert ys == xs == [126, 249]
    assert block_borders((90, 90), (1, 1), 3) == ([], [])
