"""realign / unrealign / realign_sequence: exact round trips (property-based), the interface
contract for where every sample comes from, the compiled gather against NumPy, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from metasensor.config import SystemConfig
from metasensor.sensor.realign import (
    lenslet_counts,
    realign,
    realign_sequence,
    unrealign,
)
from metasensor.sensor.scan import scan_order

CASES = [(15, 1), (15, 3), (15, 5), (15, 15), (9, 1), (9, 3), (9, 9)]


@st.composite
def setups(draw):
    nnum, p = draw(st.sampled_from(CASES))
    kind = draw(st.sampled_from(["row-major", "serpentine", "random"]))
    order = scan_order(p, "serpentine" if kind == "serpentine" else "row-major")
    if kind == "random":
        order = draw(st.permutations(order))
    moving = draw(st.sampled_from(["mla", "image"]))
    ly = draw(st.integers(1, 3))
    lx = draw(st.integers(1, 3))
    seed = draw(st.integers(0, 2**16))
    return SystemConfig(nnum=nnum, scan=p), list(order), moving, ly, lx, seed


@settings(max_examples=40, deadline=None)
@given(setups())
def test_round_trip_exact(setup):
    cfg, order, moving, ly, lx, seed = setup
    rng = np.random.default_rng(seed)
    p, n = cfg.scan, cfg.nnum
    views = rng.integers(0, 2**16, (n, n, ly * p, lx * p)).astype(np.uint16)
    frames = unrealign(views, cfg, order, moving)
    np.testing.assert_array_equal(realign(frames, cfg, order, moving), views)
    # and the other way, on the pixels inside the blocks (the rest is not sampled)
    extra = rng.integers(0, 3, 2)
    raw = rng.standard_normal((p * p, *(np.array(frames.shape[1:]) + extra))).astype(np.float32)
    back = unrealign(realign(raw, cfg, order, moving), cfg, order, moving, raw.shape[1:])
    inside = unrealign(np.ones((n, n, ly * p, lx * p), bool), cfg, order, moving, raw.shape[1:])
    assert lenslet_counts(raw.shape[1:], cfg, moving) == (ly, lx)
    np.testing.assert_array_equal(back[inside], raw[inside])


@pytest.mark.parametrize("moving", ["mla", "image"])
def test_contract_sample_origin(moving):
    """interface.md: view sample (y, x) came from phase (y % p, x % p), lenslet (y//p, x//p),
    pixel (u, v) of that lenslet's block, which moves by (r, c)*d with the MLA."""
    cfg = SystemConfig(nnum=9, scan=3)
    n, p, d = 9, 3, 3
    order = scan_order(3, "serpentine")
    h, w = 40, 43
    t_, yy, xx = np.meshgrid(np.arange(9), np.arange(h), np.arange(w), indexing="ij")
    frames = (t_ * 10000 + yy * 100 + xx).astype(np.int32)
    views = realign(frames, cfg, order, moving)
    rng = np.random.default_rng(0)
    for _ in range(50):
        u, v = rng.integers(0, n, 2)
        y, x = rng.integers(0, views.shape[2]), rng.integers(0, views.shape[3])
        r, c = y % p, x % p
        t = order.index((r, c))
        sy = (y // p) * n + u + (r * d if moving == "mla" else 0)
        sx = (x // p) * n + v + (c * d if moving == "mla" else 0)
        assert views[u, v, y, x] == frames[t, sy, sx]


def test_compiled_gather_equals_numpy(dtype=np.uint16):
    """The compiled kernels (the raw frames' uint16; other dtypes share the same code)."""
    pytest.importorskip("numba")
    cfg = SystemConfig()
    rng = np.random.default_rng(3)
    frames = rng.integers(0, 4096, (25, 97, 130)).astype(dtype)
    order = scan_order(5, "serpentine")
    for moving in ("mla", "image"):
        a = realign(frames, cfg, order, moving, engine="numpy", dtype=None)
        b = realign(frames, cfg, order, moving, engine="numba", dtype=None)
        assert a.dtype == b.dtype == dtype
        np.testing.assert_array_equal(a, b)
        c = realign(frames, cfg, order, moving)  # float32 by default (interface.md), exact
        assert c.dtype == np.float32
        np.testing.assert_array_equal(c, a.astype(np.float32))
    out = np.empty_like(a)
    assert realign(frames, cfg, order, "image", out=out) is out
    for moving in ("mla", "image"):
        views = realign(frames, cfg, order, moving, dtype=None)
        np.testing.assert_array_equal(
            unrealign(views, cfg, order, moving, frames.shape[1:], engine="numba"),
            unrealign(views, cfg, order, moving, frames.shape[1:], engine="numpy"))


def test_compiled_gather_keeps_torch_threads():
    """A process limited to one torch thread stays so after the compiled kernels: numba's
    OpenMP layer, started in a process whose torch threads were already set up, set OpenMP's
    count to every core, which torch then read as its own."""
    pytest.importorskip("numba")
    import subprocess
    import sys

    code = ("import torch; torch.set_num_threads(1); torch.get_num_threads()\n"  # torch first
            "import numpy as np\n"
            "from metasensor.sensor.gather import gather_views, scatter_views\n"
            "n, p, ly, lx = 15, 5, 8, 8\n"
            "f = np.zeros((p * p, ly * n, lx * n), np.float32)\n"
            "v = np.empty((n, n, ly * p, lx * p), np.float32)\n"
            "o, z = [(r, c) for r in range(p) for c in range(p)], [(0, 0)] * p * p\n"
            "gather_views(f, v, o, z, n, p, ly, lx, engine='numba')\n"
            "scatter_views(v, f, o, z, n, p, ly, lx, engine='numba')\n"
            "print(torch.get_num_threads())\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120)
    assert out.stdout.split()[-1] == "1", out.stdout + out.stderr


def test_realign_sequence_sliding_window():
    cfg = SystemConfig(nnum=9, scan=3)
    order = scan_order(3, "serpentine")
    rng = np.random.default_rng(4)
    seq = rng.integers(0, 1000, (22, 30, 33)).astype(np.uint16)
    for start in (0, 4):
        stacks = []
        for views in realign_sequence(iter(seq), cfg, order, start_phase=start):
            stacks.append(views.copy())
            views[...] = 0  # the caller may modify what it gets
        assert len(stacks) == 22 - 9 + 1
        for t in (0, 5, 13):
            win = np.empty((9, 30, 33), np.uint16)
            for f in range(t, t + 9):
                win[(f + start) % 9] = seq[f]  # slot s holds phase order[s]
            np.testing.assert_array_equal(stacks[t], realign(win, cfg, order))
    periods = list(realign_sequence(seq[:18], cfg, order, sliding=False))
    assert len(periods) == 2
    np.testing.assert_array_equal(periods[1], realign(seq[9:18], cfg, order))


# ------------------------------------------------------------------------------ bad input
def test_bad_frame_count():
    cfg = SystemConfig()
    with pytest.raises(ValueError, match="one 5x5 scan period needs 25"):
        realign(np.zeros((24, 60, 60), np.uint16), cfg)
    with pytest.raises(ValueError, match="not a multiple"):
        list(realign_sequence(np.zeros((30, 60, 60), np.uint16), cfg, sliding=False))
    with pytest.raises(ValueError, match="needs 25"):
        list(realign_sequence(np.zeros((10, 60, 60), np.uint16), cfg))


def test_frames_smaller_than_a_lenslet():
    with pytest.raises(ValueError, match="smaller than one lenslet"):
        realign(np.zeros((25, 20, 60), np.uint16), SystemConfig())
    with pytest.raises(ValueError, match="smaller than one lenslet"):
        realign(np.zeros((1, 10, 10), np.uint16), SystemConfig(scan=1))


@pytest.mark.parametrize("dtype", [np.complex64, bool, object, np.float16])
def test_wrong_dtype(dtype):
    with pytest.raises(TypeError, match="dtype"):
        realign(np.zeros((1, 30, 30), dtype), SystemConfig(scan=1))


def test_nans_rejected_and_input_untouched():
    frames = np.random.default_rng(0).random((9, 40, 40)).astype(np.float32)
    frames[3, 5, 7] = np.nan
    before = frames.copy()
    with pytest.raises(ValueError, match="NaN"):
        realign(frames, SystemConfig(nnum=9, scan=3))
    np.testing.assert_array_equal(frames, before)
    with pytest.raises(ValueError, match="NaN"):
        list(realign_sequence(frames, SystemConfig(nnum=9, scan=3)))


def test_bad_scan_order_and_moving():
    cfg = SystemConfig(nnum=9, scan=3)
    frames = np.zeros((9, 30, 30), np.uint16)
    with pytest.raises(ValueError, match="exactly once"):
        realign(frames, cfg, [(0, 0)] * 9)
    with pytest.raises(ValueError, match="moving"):
        realign(frames, cfg, moving="sensor")
    with pytest.raises(ValueError, match="start_phase"):
        list(realign_sequence(frames, cfg, start_phase=9))


def test_torch_tensor_realigned_on_its_device():
    import torch

    from metasensor.backend import resolve_device

    cfg = SystemConfig(nnum=9, scan=3)
    frames = np.random.default_rng(5).random((9, 40, 44)).astype(np.float32)
    ref = realign(frames, cfg, "serpentine")
    dev = resolve_device(None)  # CUDA when present, else CPU: the same code
    got = realign(torch.from_numpy(frames).to(dev), cfg, "serpentine")
    assert isinstance(got, torch.Tensor) and got.device.type == dev.type
    np.testing.assert_array_equal(got.cpu().numpy(), ref)
    with pytest.raises(ValueError, match="needs 9"):
        realign(torch.zeros(8, 40, 44), cfg)
