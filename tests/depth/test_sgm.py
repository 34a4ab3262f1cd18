"""Semi-global matching over a plane-sweep cost volume: the recursion, its blocks, the
normalisation, and what it buys on hard light fields (thin bars, occlusion edges)."""

import warnings

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.depth import SemiGlobal
from metasensor.depth.evaluate import score
from metasensor.depth.scenes import benchmark_scene
from metasensor.depth.sgm import _scan, normalise_costs, semi_global

STEPS = {4: ((1, 0), (-1, 0), (0, 1), (0, -1)),
         8: ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1))}


def _reference(cost: np.ndarray, p1: float, p2: float, paths: int) -> np.ndarray:
    """SGM written pixel by pixel (Hirschmüller 2008, eq. 13)."""
    k, h, w = cost.shape
    total = np.zeros_like(cost)
    for dy, dx in STEPS[paths]:
        path = np.zeros_like(cost)
        ys = range(h) if dy >= 0 else range(h - 1, -1, -1)
        for y in ys:
            xs = range(w) if dx >= 0 else range(w - 1, -1, -1)
            for x in xs:
                py, px = y - dy, x - dx
                if not (0 <= py < h and 0 <= px < w):
                    path[:, y, x] = cost[:, y, x]
                    continue
                prev = path[:, py, px]
                low = prev.min()
                for d in range(k):
                    cands = [prev[d], low + p2]
                    if d > 0:
                        cands.append(prev[d - 1] + p1)
                    if d < k - 1:
                        cands.append(prev[d + 1] + p1)
                    path[d, y, x] = cost[d, y, x] + min(cands) - low
        total += path
    return total


@pytest.mark.parametrize("paths", [4, 8])
def test_semi_global_matches_the_recursion_and_its_row_blocks(paths):
    rng = np.random.default_rng(0)
    cost = rng.random((5, 7, 6)).astype(np.float32)
    ref = _reference(cost.astype(np.float64), 0.2, 0.7, paths)
    for rows in (2, 3, 256):
        got = semi_global(torch.from_numpy(cost), SemiGlobal(0.2, 0.7, paths),
                          rows=rows).numpy()
        np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-5)
    assert torch.get_num_threads() == 1  # restored (the depth conftest sets one thread)


def test_semi_global_leaves_torchs_thread_setting_alone(monkeypatch):
    """One thread for the scan lines, in this thread only: ``torch.set_num_threads`` is
    process-wide, so semi-global matching must not call it."""
    cost = torch.from_numpy(np.random.default_rng(1).random((6, 9, 8)).astype(np.float32))
    expected = semi_global(cost, SemiGlobal(0.2, 0.7, 8), rows=4)

    def refuse(n):
        raise AssertionError(f"torch.set_num_threads({n}) changes every thread's setting")

    with monkeypatch.context() as m:
        m.setattr(torch, "set_num_threads", refuse)
        got = semi_global(cost, SemiGlobal(0.2, 0.7, 8), rows=4)
    torch.testing.assert_close(got, expected, rtol=0, atol=0)


def test_semi_global_fills_an_untextured_gap_and_keeps_a_one_pixel_bar():
    k, h, w = 9, 12, 20
    cost = np.ones((k, h, w), np.float32)
    cost[6] = 0.0          # background at candidate 6 everywhere ...
    cost[:, :, 8:12] = 1.0  # ... except an untextured gap (flat curves, no vote)
    cost[:, :, 15] = 1.0
    cost[2, :, 15] = 0.0   # and a one-pixel bar at candidate 2
    win = semi_global(torch.from_numpy(cost), SemiGlobal(0.3, 0.5)).argmin(0).numpy()
    assert (win[:, 8:12] == 6).all()  # the gap takes its neighbours' disparity
    assert (win[:, 15] == 2).all()    # the bar is not smoothed away
    assert (np.delete(win, [15], axis=1) == 6).all()


def test_normalise_costs_divides_in_place_and_can_be_undone():
    rng = np.random.default_rng(1)
    cost = torch.from_numpy(rng.random((8, 5, 5)).astype(np.float32) * 10)
    before = cost.clone()
    scale = normalise_costs(cost)
    assert scale.shape == (1, 5, 5)
    assert torch.all(scale > before.mean(0))  # mean plus a positive noise floor
    np.testing.assert_allclose(cost.mul_(scale).numpy(), before.numpy(), rtol=1e-5)


def test_scan_adds_into_total_and_leaves_the_costs():
    cost = torch.rand(4, 3, 5)
    keep = cost.clone()
    total = torch.ones_like(cost)
    _scan(cost, total, 2, False, 0.1, 0.4)
    assert torch.equal(cost, keep)
    assert torch.equal(total[:, :, 0], 1 + cost[:, :, 0])  # a path starts with the cost


@pytest.mark.parametrize("p1,p2,paths", [(0.5, 0.5, 4), (0.0, 1.0, 4), (0.3, float("inf"), 4),
                                         ("a", 1.0, 4), (0.3, 0.5, 6)])
def test_semi_global_penalties_are_validated(p1, p2, paths):
    with pytest.raises(ValueError, match="p1|p2|paths"):
        SemiGlobal(p1, p2, paths)


def test_estimate_depth_refuses_other_smoothing():
    sv = benchmark_scene("planes", nnum=5, size=32, max_disparity=1.0, seed=0)
    with pytest.raises(TypeError, match="smoothing must be a SemiGlobal or None"):
        ms.estimate_depth(sv.views, sv.config, smoothing="sgm")


def _estimate(sv, **kw):
    n = sv.config.nnum
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return ms.estimate_depth(sv.views, sv.config, view_mask=np.ones((n, n), bool), **kw)


def _border_mask(truth):
    m = np.zeros(truth.shape, bool)
    m[15:-15, 15:-15] = True
    return m


def test_hard_planes_meet_the_benchmark_lines():
    """Two fronto-parallel planes 4.8 view px per view step apart (9 x 9 views, 40 dB): the
    window aggregation alone spread the near plane over the far one at the edge (MSE x 100
    about 50 at this size)."""
    sv = benchmark_scene("planes", nnum=9, size=96, max_disparity=3.0, snr_db=40.0, seed=1)
    m = _border_mask(sv.disparity)
    s = score(_estimate(sv).disparity, sv.disparity, m)
    assert s["badpix"] <= 0.10 and 100 * s["mse"] <= 2.0, s


def test_thin_bars_survive_and_the_span_covers_them():
    """Bars 1.5-4.5 view px wide in front of a slanted background (5 x 5 views, 192 px): the
    coarse span search lost the near bars (span -0.6 .. 3.7, truth -3 .. 2.7) and a window
    aggregation gives most bar pixels the background's disparity."""
    sv = benchmark_scene("thin", nnum=5, size=192, max_disparity=3.0, snr_db=40.0, seed=1)
    res = _estimate(sv)
    assert res.candidates[0] <= sv.disparity.min() and res.candidates[-1] >= sv.disparity.max()
    m = _border_mask(sv.disparity)
    bars = m & (sv.disparity < 0.5)  # the background lies at +0.9 .. +2.7
    err = np.abs(res.disparity - sv.disparity)
    assert np.mean(err[bars] < 0.5) >= 0.8
    window = _estimate(sv, smoothing=None)
    assert np.mean(np.abs(window.disparity - sv.disparity)[bars] < 0.5) < 0.6


def test_occlusion_edges_stay_sharp():
    """Three textured discs in front of a slanted background (7 x 7 views, 96 px): the window
    aggregation alone spreads each disc over its edge (MSE x 100 about 49 at this size)."""
    sv = benchmark_scene("occluders", nnum=7, size=96, max_disparity=3.0, snr_db=40.0, seed=1)
    m = _border_mask(sv.disparity)
    # the sweep's decision alone (without the re-decision of edge pixels, depth.edges)
    s = score(_estimate(sv, edges=None, refiner=None).disparity, sv.disparity, m)
    s_window = score(_estimate(sv, smoothing=None, edges=None, refiner=None).disparity,
                     sv.disparity, m)
    assert s["badpix"] <= 0.10, s
    assert s["mse"] <= 0.2 and s["mse"] <= 0.4 * s_window["mse"], (s, s_window)
