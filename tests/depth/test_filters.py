"""Box and guided filters against direct computations."""

import numpy as np
import torch

from metasensor.depth.filters import GuidedFilter, box_mean


def _direct_box(x, r):
    h, w = x.shape
    out = np.empty_like(x)
    for i in range(h):
        for j in range(w):
            out[i, j] = x[max(0, i - r):i + r + 1, max(0, j - r):j + r + 1].mean()
    return out


def test_box_mean_matches_direct_clipped_window():
    rng = np.random.default_rng(0)
    x = rng.random((13, 17)).astype(np.float32)
    for r in (1, 3, 8):
        got = box_mean(torch.from_numpy(x), r).numpy()
        np.testing.assert_allclose(got, _direct_box(x, r), rtol=1e-5, atol=1e-6)
    batched = box_mean(torch.from_numpy(np.stack([x, 2 * x])), 2).numpy()
    np.testing.assert_allclose(batched[1], 2 * batched[0], rtol=1e-6)


def test_guided_filter_limits():
    rng = np.random.default_rng(1)
    guide = torch.from_numpy(rng.random((32, 32)).astype(np.float32))
    p = torch.from_numpy(rng.random((32, 32)).astype(np.float32))
    # a constant is kept exactly (a = 0, b = constant)
    np.testing.assert_allclose(GuidedFilter(guide, 3)(torch.full((32, 32), 2.5)).numpy(), 2.5,
                               rtol=1e-5)
    # eps → 0 with p = guide: the filter reproduces the guide (a = 1, b = 0), to 1e-3
    g0 = GuidedFilter(guide, 3, eps=1e-8)
    gn = (guide - guide.mean()) / guide.std()
    np.testing.assert_allclose(g0(gn).numpy(), gn.numpy(), atol=1e-3)
    # eps → ∞: a → 0 and the result is the box mean of the box mean of p
    ginf = GuidedFilter(guide, 3, eps=1e9)
    np.testing.assert_allclose(ginf(p).numpy(), box_mean(box_mean(p, 3), 3).numpy(), atol=1e-5)


def test_guided_filter_keeps_a_step_edge_that_the_box_filter_blurs():
    step = torch.zeros((20, 40))
    step[:, 20:] = 1.0
    noisy = step + 0.05 * torch.from_numpy(np.random.default_rng(2).standard_normal((20, 40))
                                           .astype(np.float32))
    gf = GuidedFilter(step, 4, eps=1e-3)(noisy)
    box = box_mean(noisy, 4)
    # at the columns next to the edge the box filter mixes both sides (error ~0.3-0.5)
    assert float((gf[:, 18:22] - step[:, 18:22]).abs().mean()) < 0.05
    assert float((box[:, 18:22] - step[:, 18:22]).abs().mean()) > 0.2
