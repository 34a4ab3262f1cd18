"""Field-dependent Zernike maps: exact at block centres, bilinear between, clamped outside."""

import numpy as np
import pytest

from metasensor.optics.field import block_centres_normalised, evaluate_field_zernike


def test_grid_interpolation_exact_at_centres_and_linear_between():
    rng = np.random.default_rng(0)
    grid = rng.normal(size=(3, 4, 10))
    yc, xc = block_centres_normalised(3, 4)
    np.testing.assert_allclose(evaluate_field_zernike(grid, yc, xc), grid, atol=1e-12)
    mid = evaluate_field_zernike(grid, (yc[0, 0] + yc[1, 0]) / 2, (xc[0, 0] + xc[0, 1]) / 2)
    np.testing.assert_allclose(mid, grid[:2, :2].mean(axis=(0, 1)), atol=1e-12)
    corner = evaluate_field_zernike(grid, -1.0, 1.0)  # beyond the outermost centre: clamped
    np.testing.assert_allclose(corner, grid[0, -1], atol=1e-12)


def test_single_block_and_callable_and_errors():
    grid = np.ones((1, 1, 5))
    assert evaluate_field_zernike(grid, np.zeros((2, 2)), np.zeros((2, 2))).shape == (2, 2, 5)
    f = lambda yn, xn: np.stack([yn, xn], axis=-1)  # noqa: E731
    np.testing.assert_allclose(evaluate_field_zernike(f, 0.5, -0.5), [0.5, -0.5])
    with pytest.raises(ValueError, match="by, bx, J"):
        evaluate_field_zernike(np.ones((2, 5)), 0.0, 0.0)
    with pytest.raises(ValueError, match="NaN"):
        evaluate_field_zernike(np.full((1, 1, 3), np.nan), 0.0, 0.0)
