"""Blocks through Dask: a dask.distributed LocalCluster gives the local result; Zarr in and out."""

import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.recon.api import reconstruct
from recon_standin import gaussian_psfs, one_torch_thread, synth_views  # noqa: F401

CFG = SystemConfig(nnum=5, scan=5)  # d = 1: small and fast


@pytest.fixture(scope="module")
def capture():
    rng = np.random.default_rng(3)
    bank = gaussian_psfs(nnum=5, radius=4)
    scene = 0.5 + rng.random((80, 80)).astype(np.float32)
    views, truth = synth_views(scene, bank, 1, border=10)
    return views, truth, bank


@pytest.mark.parametrize("solver", ["rl", "hqs"])
def test_localcluster_equals_local(capture, solver):
    # Tolerance from the issue: max |diff| <= 1e-5 (same float32 code on the same CPU), for both
    # ISA solvers (HQS is the default where the scan step allows).
    from distributed import LocalCluster

    views, _, bank = capture
    kw = dict(psf=bank, blocks=(2, 2), overlap=8, view_radius=2.5, solver=solver,
              **({"iterations": 3} if solver == "rl" else {}))
    local = reconstruct(views, CFG, **kw).image
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                      dashboard_address=None) as cluster:
        remote = reconstruct(views, CFG, scheduler=cluster.scheduler_address, **kw).image
    assert np.abs(remote - local).max() <= 1e-5
    assert np.abs(local).max() > 0.1


def test_zarr_in_and_out(capture, tmp_path):
    # Views read lazily block by block from a zarr store; the image stitched into a zarr array.
    import zarr

    from metasensor.io.views import read_views, write_views

    views, _, bank = capture
    write_views(tmp_path / "v.zarr", views, CFG)
    lazy = read_views(tmp_path / "v.zarr")
    assert not isinstance(lazy, np.ndarray)
    out = zarr.open_array(str(tmp_path / "img.zarr"), mode="w", shape=views.shape[2:],
                          chunks=(32, 32), dtype="f4", fill_value=0.0)
    kw = dict(psf=bank, iterations=2, blocks=(2, 2), overlap=8)
    rec = reconstruct(lazy, CFG, out=out, **kw)
    ref = reconstruct(views, CFG, **kw).image
    assert rec.image is out
    np.testing.assert_allclose(np.asarray(out[:]), ref, atol=1e-6)


def test_local_blocks_run_in_completion_order():
    # a slow block does not hold back the others: with 2 workers the fast tasks' results are
    # handed on while the slow one still runs (no barrier per batch)
    import threading
    import time

    from metasensor.recon.parallel import run_tasks

    release = threading.Event()
    order = []

    def func(task):
        if task == "slow":
            release.wait(5.0)
        return task

    def on_result(result):
        order.append(result)
        if len(order) == 3:
            release.set()

    t0 = time.perf_counter()
    run_tasks(func, ["slow", "a", "b", "c"], on_result, num_workers=2)
    assert order[:3] == ["a", "b", "c"] and order[3] == "slow"
    assert time.perf_counter() - t0 < 4.0


def test_local_workers_split_the_torch_threads_and_give_them_back():
    # Local threads share the process's intra-op threads: two workers run one thread each
    # while they run (no oversubscription), and the count is restored afterwards.
    import torch

    from metasensor.recon.parallel import run_tasks

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        seen, out = [], []
        run_tasks(lambda t: (seen.append(torch.get_num_threads()), t)[1], range(4), out.append,
                  num_workers=2)
        assert sorted(out) == [0, 1, 2, 3] and seen == [1, 1, 1, 1]
        assert torch.get_num_threads() == 2
        seen.clear()
        run_tasks(lambda t: seen.append(torch.get_num_threads()), range(2), out.append)
        assert seen == [2, 2]
    finally:
        torch.set_num_threads(before)


def test_two_local_workers_never_set_up_two_blocks_at_once(capture):
    # Each block's set-up (bank, operator, solver set-up) holds a gate until its solver's first
    # step: the banks of two workers are never made at the same time (their memory peaks would
    # add up), and the image is the one of a single worker.
    import threading
    import time

    views, _, bank = capture
    lock, active, most = threading.Lock(), [0], [0]

    def psf_fn(cfg, zernike, device):
        with lock:
            active[0] += 1
            most[0] = max(most[0], active[0])
        time.sleep(0.3)
        with lock:
            active[0] -= 1
        return bank

    kw = dict(psf_fn=psf_fn, blocks=(2, 2), overlap=8, view_radius=2.5, solver="rl",
              iterations=2)
    two = reconstruct(views, CFG, num_workers=2, **kw)
    assert most[0] == 1
    np.testing.assert_array_equal(two.image, reconstruct(views, CFG, **kw).image)


def test_local_workers_are_one_per_thread_as_far_as_memory_holds_them(monkeypatch):
    # One block per torch thread on the CPU, but no more than half the free memory holds at
    # BLOCK_BYTES_PER_WINDOW_BYTE times a window each, and at least one.
    import torch

    from metasensor.io import memory
    from metasensor.recon import parallel

    before = torch.get_num_threads()
    torch.set_num_threads(4)
    try:
        per_block = parallel.BLOCK_BYTES_PER_WINDOW_BYTE * 100
        monkeypatch.setattr(memory, "memory_room", lambda: 2 * per_block * 10)
        assert parallel.local_workers(64, "cpu") == 4  # no window: threads only
        assert parallel.local_workers(64, "cpu", window_bytes=100) == 4
        monkeypatch.setattr(memory, "memory_room", lambda: 2 * per_block * 3)
        assert parallel.local_workers(64, "cpu", window_bytes=100) == 3
        assert parallel.local_workers(2, "cpu", window_bytes=100) == 2  # blocks
        monkeypatch.setattr(memory, "memory_room", lambda: per_block)
        assert parallel.local_workers(64, "cpu", window_bytes=100) == 1
    finally:
        torch.set_num_threads(before)


def test_auto_workers_are_counted_from_the_largest_window_on_local_runs_only(monkeypatch):
    # num_workers="auto": local_workers(blocks, device, largest window's float32 bytes); "sync"
    # and a cluster keep their own (None); a given count is left as it is.
    from metasensor.recon import api, parallel
    from metasensor.recon.blocks import split_blocks
    from metasensor.recon.options import ReconOptions

    seen = []
    monkeypatch.setattr(parallel, "local_workers",
                        lambda n, device=None, window_bytes=None: seen.append(
                            (n, window_bytes)) or 3)
    blocks = split_blocks((60, 90), (2, 3), 3, overlap=6, margin=5)
    area = max((b.window[1] - b.window[0]) * (b.window[3] - b.window[2]) for b in blocks)
    auto = ReconOptions(num_workers="auto")
    assert api._resolve_workers(auto, blocks, (5, 5, 20, 30), 3).num_workers == 3
    assert seen == [(6, 25 * 4 * area // 9)]
    for scheduler in ("sync", "tcp://127.0.0.1:8786"):
        opts = ReconOptions(num_workers="auto", scheduler=scheduler)
        assert api._resolve_workers(opts, blocks, (5, 5, 20, 30), 3).num_workers is None
    given = ReconOptions(num_workers=2)
    assert api._resolve_workers(given, blocks, (5, 5, 20, 30), 3) is given
    assert len(seen) == 1
