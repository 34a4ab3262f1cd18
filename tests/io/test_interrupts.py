"""Ctrl-C and kill -9 at any point of a write leave each output complete (old or new) or
absent, the inputs byte-identical, and (Ctrl-C) no temporary; a killed run's temporaries are
removed by the next run. Writers in real subprocesses replace a Zarr store, a TIFF, a result
folder and a shared PSF-cache entry in a loop and are interrupted at several points (the audit:
a half-deleted store under the final name 4 of 4 times, temporaries left 7 of 10 times)."""

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import as_at_a_terminal

from metasensor.io.atomic import StagedFolder, atomic_write_text
from metasensor.io.views import read_views, write_views

WRITER = r"""
import sys
import time
from pathlib import Path
import numpy as np
from metasensor.io.atomic import StagedFolder, atomic_write_text
from metasensor.io.views import write_views
from metasensor.optics import cache
root, shared = Path(sys.argv[1]), Path(sys.argv[2])
src = np.load(root / "in.npy")  # the input, read on every pass
print("ready", flush=True)
k = 0
t0 = time.monotonic()
while time.monotonic() - t0 < 300:  # never outlive a test run that was itself killed
    k += 1
    cache.store("bank", src, folder=shared)  # all writers share one cache entry
    got = cache.load("bank", folder=shared)
    if got is not None and not np.array_equal(got, src):
        sys.exit("cache returned a wrong bank")
    views = np.broadcast_to(src + k, (5, 5, *src.shape)).astype(np.float32)
    write_views(root / "v.zarr", views)
    write_views(root / "v.tif", views)
    staged = StagedFolder(root / "res", ["a.npy", "b.txt"])
    np.save(staged.path / "a.npy", np.full(3, k))
    atomic_write_text(staged.path / "b.txt", str(k))
    staged.commit()
"""


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _check_outputs(root: Path, src: np.ndarray) -> None:
    """Every output is absent or complete and self-consistent."""
    for name in ("v.zarr", "v.tif"):
        if (root / name).exists():
            diff = np.asarray(read_views(root / name)[:]) - src
            assert np.ptp(diff) == 0 and diff.flat[0] >= 1, name  # one whole pass's views
    if (root / "res").exists():
        assert sorted(p.name for p in (root / "res").iterdir()) == ["a.npy", "b.txt"]
        assert int(np.load(root / "res" / "a.npy")[0]) == int((root / "res" / "b.txt").read_text())


def _hidden(root: Path) -> list[str]:
    return sorted(p.name for p in root.iterdir() if p.name.startswith("."))


def test_an_interrupted_writer_leaves_complete_outputs_or_none(tmp_path):
    # the default suite's share: one Ctrl-C early in a pass, one kill -9 later
    _interrupt_writers(tmp_path, ((0.05, signal.SIGINT), (0.6, signal.SIGKILL)))


@pytest.mark.slow  # four interpreters: ~17 s at a load of 6 on 2 cores
def test_interrupted_writers_leave_complete_outputs_or_none(tmp_path):
    # interrupt points after start, each writer at another; Ctrl-C and kill -9
    _interrupt_writers(tmp_path, ((0.05, signal.SIGINT), (0.3, signal.SIGKILL),
                                  (0.6, signal.SIGINT), (1.0, signal.SIGKILL)))


@pytest.mark.slow
def test_many_interrupt_points(tmp_path):
    rng = np.random.default_rng(7)
    for k in range(5):  # 20 more interrupts at random points of the writers' first 2 s
        sigs = (signal.SIGINT, signal.SIGKILL) * 2
        plan = tuple((float(t), s) for t, s in zip(rng.uniform(0, 2, 4), sigs, strict=True))
        (tmp_path / str(k)).mkdir()
        _interrupt_writers(tmp_path / str(k), plan)


def _interrupt_writers(tmp_path, plan):
    src_dir = str(Path(__file__).resolve().parents[2] / "src")
    env = {**os.environ, "PYTHONPATH": src_dir, "OMP_NUM_THREADS": "1"}
    shared = tmp_path / "cache"
    runs = []
    for i, (_, sig) in enumerate(plan):
        root = tmp_path / f"w{i}"
        root.mkdir()
        src = np.random.default_rng(0).integers(0, 1000, (64, 64)).astype(np.float32)
        np.save(root / "in.npy", src)
        proc = subprocess.Popen([sys.executable, "-c", WRITER, str(root), str(shared)],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                                preexec_fn=as_at_a_terminal)  # Ctrl-C not inherited as ignored
        runs.append((root, src, _digest(root / "in.npy"), proc, sig))
    for (_, _, _, proc, sig), (delay, _) in zip(runs, plan, strict=True):
        assert proc.stdout.readline().strip() == "ready", proc.stderr.read()[-2000:]
        time.sleep(delay)
        proc.send_signal(sig)
    for root, src, before, proc, sig in runs:
        _, err = proc.communicate(timeout=60)
        assert "cache returned a wrong bank" not in err
        assert _digest(root / "in.npy") == before  # the input untouched
        _check_outputs(root, src)
        if sig == signal.SIGINT:  # every exit path Python sees removes its temporaries
            assert proc.returncode != 0 and "KeyboardInterrupt" in err, err[-2000:]
            assert _hidden(root) == [], _hidden(root)
        # the next run removes what a killed one left (its pid is gone), then writes whole
        write_views(root / "v.zarr", np.broadcast_to(src + 1, (5, 5, 64, 64)))
        write_views(root / "v.tif", np.broadcast_to(src + 1, (5, 5, 64, 64)))
        staged = StagedFolder(root / "res", ["a.npy", "b.txt"])
        np.save(staged.path / "a.npy", np.full(3, 1))
        atomic_write_text(staged.path / "b.txt", "1")
        staged.commit()
        assert _hidden(root) == [], _hidden(root)
        _check_outputs(root, src)
    from metasensor.optics import cache

    assert np.array_equal(cache.load("bank", folder=shared), runs[0][1])  # whole and right
    cache.store("bank", runs[0][1], folder=shared)  # the next writer clears killed ones' files
    assert [p.name for p in shared.rglob("*")] == ["psf", "bank.npy"]  # no temporary left
