"""The space-variant operator: one bank everywhere is the plain operator; weights blend banks."""

import numpy as np
import pytest
import torch

from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
from metasensor.phasespace.space_variant import SpaceVariantOperator, corner_weights, pad_banks
from recon_standin import one_torch_thread  # noqa: F401


def _banks(n=2, v=5, k=9):
    return [np.random.default_rng(s).random((v, k, k)).astype(np.float32) for s in range(n)]


def test_one_bank_everywhere_is_the_plain_operator():
    g = make_geometry((8, 7), 3, 4)
    bank = _banks(1)[0]
    plain = PhaseSpaceOperator(bank, g, device="cpu")
    sv = SpaceVariantOperator([bank, bank], np.full((2, *g.domain), 0.5, np.float32), g,
                              device="cpu")
    x = torch.rand(g.domain, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(sv.forward(x), plain.forward(x), rtol=1e-4, atol=1e-4)
    y = plain.forward(x)
    torch.testing.assert_close(sv.adjoint(y), plain.adjoint(y), rtol=1e-4, atol=1e-4)
    mask = torch.ones(g.grid, dtype=torch.bool)
    torch.testing.assert_close(sv.sensitivity(mask), plain.sensitivity(mask), rtol=1e-4,
                               atol=1e-3)
    assert sv.norm(iterations=20) == pytest.approx(plain.norm(iterations=20), rel=1e-4)


def test_weights_pick_each_bank_where_they_are_one():
    g = make_geometry((8, 8), 3, 4)
    a, b = _banks(2)
    w = np.zeros((2, *g.domain), np.float32)
    w[0, :, : g.domain[1] // 2] = 1.0
    w[1] = 1.0 - w[0]
    sv = SpaceVariantOperator([a, b], w, g, device="cpu")
    x = torch.rand(g.domain, generator=torch.Generator().manual_seed(1))
    left = x * torch.from_numpy(w[0])
    want = PhaseSpaceOperator(a, g, device="cpu").forward(left) + PhaseSpaceOperator(
        b, g, device="cpu").forward(x - left)
    torch.testing.assert_close(sv.forward(x), want, rtol=1e-4, atol=1e-4)


def test_corner_weights_are_a_bilinear_partition_of_unity():
    g = make_geometry((10, 10), 3, 3)
    w = corner_weights(g, (30, 60), (36, 54, 66, 84))
    assert w.shape == (4, *g.domain) and (w >= 0).all()
    np.testing.assert_allclose(w.sum(0), 1.0, atol=1e-6)
    oy, ox = g.offset
    # field pixel (36, 66) (the core's first pixel, centre 0.5 px inside) is almost all (y0, x0)
    assert w[0, 36 - 30 + oy, 66 - 60 + ox] == pytest.approx((1 - 0.5 / 18) ** 2, rel=1e-6)
    # beyond the core the weights stay at the edge's value
    np.testing.assert_allclose(w[:, 0, :], w[:, 36 - 30 + oy - 1, :])
    with pytest.raises(ValueError, match="core"):
        corner_weights(g, (0, 0), (5, 5, 0, 3))
    # a 3 x 3 grid of points: hats, a partition of unity; 2 x 2 of it sums to the corners'
    w3 = corner_weights(g, (30, 60), (36, 54, 66, 84), points=3)
    assert w3.shape == (9, *g.domain) and (w3 >= 0).all()
    np.testing.assert_allclose(w3.sum(0), 1.0, atol=1e-6)
    centre = 45 - 30 + oy, 75 - 60 + ox  # field pixel (45, 75): centre 0.5 px past the middle
    assert w3[4][centre] == pytest.approx((1 - 0.5 / 9) ** 2, rel=1e-6)
    np.testing.assert_allclose(corner_weights(g, (30, 60), (36, 54, 66, 84), points=2), w)
    with pytest.raises(ValueError, match="points"):
        corner_weights(g, (0, 0), (0, 9, 0, 9), points=1)


def test_bad_banks_and_weights_are_refused():
    g = make_geometry((6, 6), 3, 4)
    a, b = _banks(2)
    with pytest.raises(ValueError, match="partition of unity"):
        SpaceVariantOperator([a, b], np.ones((2, *g.domain), np.float32), g, device="cpu")
    with pytest.raises(ValueError, match="one shape"):
        SpaceVariantOperator([a, b[:, 1:-1, 1:-1]], np.full((2, *g.domain), 0.5), g)
    same = pad_banks([a, b[:, 1:-1, 1:-1]])
    assert same[1].shape == a.shape and same[1][:, 0].sum() == 0
