"""Pooling the edge refiner's logits along long straight depth edges
(metasensor.depth.edgeruns): which samples are pooled, over what, and what is left alone. The
full-size figures are bench_depth's."""

import numpy as np
import pytest
import torch

from metasensor.depth.edgeruns import pool_along_runs
from metasensor.depth.edges import two_layer_pixels
from metasensor.depth.learned import EdgeRefiner


def _bar_map(rows: int, col: int = 10, width: int = 24):
    """A vertical edge: background 1.0 left of ``col``, front -1.0 from ``col + 1`` on; the
    edge column ``col`` itself alternates between the two layers (as a map that has not decided
    it), rows ``2 .. rows + 1`` of a ``(rows + 4, width)`` map."""
    disp = torch.ones((rows + 4, width))
    disp[2:rows + 2, col + 1:] = -1.0
    disp[2:rows + 2:2, col] = -1.0
    return disp


def _samples(disp, col):
    ys = torch.arange(2, disp.shape[0] - 2)
    xs = torch.full_like(ys, col)
    _, lo, hi, _ = two_layer_pixels(disp, 1.5, 4.0)
    return lo, hi, ys, xs


def _pool(disp, lo, hi, ys, xs, logit, length):
    return pool_along_runs(disp, lo, hi, ys, xs, logit, length, step=0.1)


def test_a_long_straight_run_takes_its_mean_logit():
    disp = _bar_map(60)
    lo, hi, ys, xs = _samples(disp, 10)
    logit = torch.full(ys.shape, 3.0)
    logit[20:32] = -6.0                   # a stretch of confident contrary decisions
    out = _pool(disp, lo, hi, ys, xs, logit, 16)
    assert bool((out > 0).all())          # the run's majority wins everywhere
    # each pooled value is the mean of the clipped logits within ±32 px along the run
    clipped = logit.clamp(-4, 4)
    i = 26
    window = clipped[max(0, i - 32):i + 33]
    assert float(out[i]) == pytest.approx(float(window.mean()), abs=1e-5)
    assert torch.equal(_pool(disp, lo, hi, ys, xs, logit, 0), logit)


def test_another_layer_meeting_the_edge_ends_the_run():
    """A second front object (disparity -1.4) joins the front side of the edge at rows 30-39:
    the layers change by more than ``step`` there, so those ten rows form a run of their own
    (too short to pool) and keep their own logits, while the rest of the column is pooled."""
    disp = _bar_map(60)
    disp[30:40, 11:18] = -1.4
    lo, hi, ys, xs = _samples(disp, 10)
    logit = torch.full(ys.shape, 3.0)
    logit[28:38] = -4.0                   # rows 30-39
    out = _pool(disp, lo, hi, ys, xs, logit, 8)
    assert torch.equal(out[28:38], logit[28:38])
    assert bool((out[:28] > 0).all()) and bool((out[38:] > 0).all())
    # without the layers' continuity the whole column is one run, its mean positive
    loose = pool_along_runs(disp, lo, hi, ys, xs, logit, 8, step=1.0)
    assert bool((loose[28:38] > 0).all())


def test_short_runs_keep_their_own_logits():
    disp = _bar_map(30)                   # 30 px < 2 * 16 + 1
    lo, hi, ys, xs = _samples(disp, 10)
    logit = torch.linspace(-3, 3, ys.numel())
    assert torch.equal(_pool(disp, lo, hi, ys, xs, logit, 16), logit)
    # the same run pooled with a shorter length
    assert not torch.equal(_pool(disp, lo, hi, ys, xs, logit, 8), logit)


def test_curved_edges_are_not_pooled():
    """The rim of a disc of radius 24 px never stays in one column (row, diagonal) for 33 px:
    every logit is its own."""
    yy, xx = np.mgrid[0:64, 0:64]
    inside = np.hypot(yy - 32, xx - 32) <= 24
    disp = torch.from_numpy(np.where(inside, -1.0, 1.0).astype(np.float32))
    rim = inside & ~(np.hypot(yy - 32, xx - 32) <= 23)
    ys, xs = (torch.from_numpy(a) for a in np.nonzero(rim))
    logit = torch.from_numpy(np.random.default_rng(0).normal(0, 3, ys.numel())).float()
    _, lo, hi, _ = two_layer_pixels(disp, 1.5, 4.0)
    out = _pool(disp, lo, hi, ys, xs, logit, 16)
    assert torch.equal(out, logit)


@pytest.mark.parametrize("value", [-1, 65, 1.5])
def test_run_length_is_checked(value):
    with pytest.raises(ValueError, match="run_length"):
        EdgeRefiner(run_length=value)
