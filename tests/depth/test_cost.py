"""Plane-sweep cost volume: bilinear and cubic resampling, minimum at the true disparity, view
groups."""

import numpy as np
import pytest
import torch
from scipy import ndimage

from metasensor.depth.cost import CostVolume
from metasensor.depth.filters import box_mean
from metasensor.depth.geometry import view_offsets


def _stack(n=5, shape=(40, 44), disparity=0.0, seed=0):
    rng = np.random.default_rng(seed)
    tex = ndimage.gaussian_filter(rng.random((shape[0] + 40, shape[1] + 40)), 2.0)
    au, av = view_offsets(n)
    views = np.empty((n * n, *shape), dtype=np.float32)
    for i, (a, b) in enumerate(zip(au.ravel(), av.ravel(), strict=True)):
        # view content at p + δ a equals the centre's at p: V(p) = T(p − δ a)
        sh = ndimage.shift(tex, (disparity * a, disparity * b), order=3, mode="nearest")
        views[i] = sh[20:20 + shape[0], 20:20 + shape[1]]
    return torch.from_numpy(views), au.ravel(), av.ravel()


def test_shifted_matches_scipy_linear_interpolation():
    views, au, av = _stack()
    cv = CostVolume(views, au, av, centre=12, max_disparity=1.0, resampling="linear")
    out = torch.empty(cv.shape)
    tmp = torch.empty((cv.shape[0] + 1, cv.shape[1]))
    for dy, dx in ((0.3, -1.7), (-2.0, 0.25), (1.5, 1.5), (0.0, 0.0)):
        got = cv.shifted(3, dy, dx, out, tmp).numpy() + float(views.mean())  # stored less mean
        # sample at p + (dy, dx) = scipy's shift by −(dy, dx), linear (order 1), interior only
        ref = ndimage.shift(views[3].numpy().astype(np.float64), (-dy, -dx), order=1)
        np.testing.assert_allclose(got[4:-4, 4:-4], ref[4:-4, 4:-4], atol=1e-5)


def test_shifted_cubic_matches_torch_bicubic_and_keeps_a_thin_bar():
    views, au, av = _stack()
    cv = CostVolume(views, au, av, centre=12, max_disparity=1.0)  # cubic by default
    h, w = cv.shape
    out = torch.empty(cv.shape)
    tmp = torch.empty((h + 1) * (w + 3))
    for dy, dx in ((0.3, -1.7), (-2.0, 0.25), (1.5, 1.5), (0.0, 0.0), (0.0, 0.6)):
        got = cv.shifted(3, dy, dx, out, tmp) + views.mean()
        ys = torch.arange(h, dtype=torch.float32)[:, None] + dy
        xs = torch.arange(w, dtype=torch.float32)[None, :] + dx
        grid = torch.stack([(2 * xs / (w - 1) - 1).expand(h, w),
                            (2 * ys / (h - 1) - 1).expand(h, w)], dim=-1)[None]
        ref = torch.nn.functional.grid_sample(views[3][None, None], grid, mode="bicubic",
                                              align_corners=True)[0, 0]
        np.testing.assert_allclose(got[4:-4, 4:-4], ref[4:-4, 4:-4], atol=1e-5)
    # a one-sample bar shifted by half a sample: bilinear halves its contrast, cubic keeps more
    bar = torch.zeros((1, 16, 16))
    bar[0, :, 8] = 1.0
    peaks = {}
    for mode in ("linear", "cubic"):
        cv = CostVolume(bar, [0.0], [0.0], centre=0, max_disparity=1.0, resampling=mode)
        peaks[mode] = float(cv.shifted(0, 0.0, 0.5, torch.empty((16, 16)),
                                       torch.empty(17 * 19)).max()) + float(bar.mean())
    assert peaks["linear"] == pytest.approx(0.5)
    assert peaks["cubic"] == pytest.approx(0.59375)  # Keys weight at half a sample, a = -0.75
    with pytest.raises(ValueError, match="resampling"):
        CostVolume(views, au, av, centre=12, max_disparity=1.0, resampling="sinc")


@pytest.mark.parametrize("cost", ["variance", "sad"])
@pytest.mark.parametrize("occlusion", [False, True])
def test_cost_minimum_at_true_disparity(cost, occlusion):
    # integer true disparity: the aligned views are exact copies, the raw cost is 0 there
    true = 1.0
    views, au, av = _stack(disparity=true)
    cands = np.linspace(-1.5, 1.5, 31)  # step 0.1: the true value is a candidate
    cv = CostVolume(views, au, av, centre=12, max_disparity=1.5, cost=cost, occlusion=occlusion)
    vol = cv.volume(cands)
    k = int(np.argmin(np.abs(cands - true)))
    winner = cands[vol[:, 5:-5, 5:-5].argmin(0).numpy()]
    assert np.all(np.abs(winner - true) < 1e-9)
    assert float(vol[k, 5:-5, 5:-5].max()) < 1e-4 * float(vol[:, 5:-5, 5:-5].mean())
    # fractional disparity: after a 7 x 7 box aggregation the winner is the nearest candidate
    views, au, av = _stack(disparity=0.63)
    cv = CostVolume(views, au, av, centre=12, max_disparity=1.5, cost=cost, occlusion=occlusion)
    vol = cv.volume(cands, aggregate=lambda c: box_mean(c, 3))
    winner = cands[vol[:, 5:-5, 5:-5].argmin(0).numpy()]
    assert np.mean(np.abs(winner - 0.6) < 1e-9) > 0.95


def test_group_matrix_rows_average_their_views():
    views, au, av = _stack(n=7, shape=(8, 8))
    cv = CostVolume(views, au, av, centre=24, max_disparity=0.5, occlusion=True)
    m = cv.group_matrix.numpy()
    assert m.shape == (5, 9)
    # each row averages: weight × number of views in the group = 1
    np.testing.assert_allclose(m @ cv.count, 1.0, rtol=1e-6)
    # the full pupil holds all 49 views; each half 4 rows of 7 = 28
    assert (m[0] > 0).sum() == 9 and 1 / m[0].max() == pytest.approx(49)
    for row in m[1:]:
        assert 1 / row.max() == pytest.approx(28)
    with pytest.raises(ValueError, match="cost"):
        CostVolume(views, au, av, centre=24, max_disparity=0.5, cost="ncc")
