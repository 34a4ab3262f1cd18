"""Runs writing the same output at the same time: one writes, the others fail at once with one
line (a lock beside the output), and what is left is one run's whole result (the audit: two
``reconstruct --zarr`` runs left an all-zero image, three ``realign --out v.zarr`` runs left 180
of 225 views zero, all exiting 0). The PSF cache stays right under concurrent writers of one
entry. Real ``metasensor`` processes: each imports its command first, then all are released at
the same instant, so they truly overlap; the overlap is checked from their own clocks
(CLOCK_MONOTONIC, shared by the processes) and from the refusals, which only a run holding the
lock at that moment can cause."""

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tifffile

import metasensor as ms
from metasensor.io.raw import write_raw
from metasensor.io.views import read_views, write_views
from metasensor.optics.psf_io import load_psf, save_psf

CFG = ms.SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
RUNNER = r"""
import json, sys, time
from pathlib import Path
import metasensor.cli as cli
go, args = Path(sys.argv[1]), sys.argv[2:]
cli.load_commands(cli._COMMANDS[args[0]][0])  # the command's imports, before the start
print("ready", flush=True)
while not go.exists():
    time.sleep(0.001)
t0 = time.monotonic()
sys.argv = ["metasensor", *args]
try:
    cli.main()
    code = 0
except SystemExit as exc:
    code = exc.code if isinstance(exc.code, int) else 1
print(json.dumps([t0, time.monotonic()]), flush=True)
sys.exit(code)
"""


def _race(root: Path, commands: list[list[str]], cache: Path) -> list[tuple[int, str, tuple]]:
    """Start every command, wait until each has imported what it needs, release all at once;
    returns (exit status, stderr, (start, end) on the shared monotonic clock) per command."""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2] / "src"),
           "OMP_NUM_THREADS": "1", "METASENSOR_CACHE": str(cache)}
    go = root / "go"
    procs = [subprocess.Popen([sys.executable, "-c", RUNNER, str(go), *args], cwd=root, env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for args in commands]
    try:
        for proc in procs:
            assert proc.stdout.readline().strip() == "ready", proc.stderr.read()[-2000:]
        go.touch()
        results = []
        for proc in procs:
            out, err = proc.communicate(timeout=300)
            results.append((proc.returncode, err, tuple(json.loads(out.strip().splitlines()[-1]))))
    finally:
        for proc in procs:  # never left running
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        go.unlink(missing_ok=True)
    return results


def _one_wins(results) -> None:
    """One run wrote; every other failed at once, naming the lock another run held then."""
    codes = [code for code, _, _ in results]
    assert codes.count(0) >= 1, results
    for code, err, _ in results:
        if code:
            last = err.strip().splitlines()[-1]
            assert code == 2 and last.startswith("error: another metasensor run is writing"), err
    assert codes.count(2) >= 1, results  # a refusal: the runs met while one held the lock
    (s0, e0), *others = [span for _, _, span in results]
    assert all(s < e0 and s0 < e for s, e in others), results  # overlapping in time


def _digests(*paths: Path) -> dict:
    return {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in paths}


@pytest.fixture
def raw(tmp_path):
    frames = np.random.default_rng(0).integers(100, 4000, (9, 600, 600)).astype(np.uint16)
    write_raw(tmp_path / "raw.tif", frames, description=CFG.to_json())
    return frames


def test_two_realign_runs_of_one_store(tmp_path, raw):
    before = _digests(tmp_path / "raw.tif")
    cmd = ["realign", "raw.tif", "--out", "v.zarr"]
    _one_wins(_race(tmp_path, [cmd, cmd], tmp_path / "cache"))
    np.testing.assert_array_equal(np.asarray(read_views(tmp_path / "v.zarr")[:]),
                                  np.asarray(ms.realign(raw, CFG)))
    assert _digests(tmp_path / "raw.tif") == before
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # locks, temps


@pytest.mark.slow  # eight interpreters: ~60 s on a loaded 2-core machine
def test_three_realign_and_two_reconstruct_runs_and_the_psf_cache(tmp_path, raw):
    rng = np.random.default_rng(1)
    write_views(tmp_path / "views.tif", 1 + rng.random((3, 3, 60, 60)).astype(np.float32), CFG)
    yy, xx = np.mgrid[-2:3, -2:3]
    bank = np.broadcast_to(np.exp(-(yy**2 + xx**2) / 2.0), (3, 3, 5, 5)).astype(np.float32)
    save_psf(tmp_path / "psf.h5", bank / bank.sum((2, 3), keepdims=True), CFG)
    CFG.to_toml(tmp_path / "cfg.toml")
    inputs = _digests(tmp_path / "raw.tif", tmp_path / "views.tif", tmp_path / "psf.h5",
                      tmp_path / "cfg.toml")
    realign = ["realign", "raw.tif", "--out", "v.zarr"]
    _one_wins(_race(tmp_path, [realign] * 3, tmp_path / "cache"))
    np.testing.assert_array_equal(np.asarray(read_views(tmp_path / "v.zarr")[:]),
                                  np.asarray(ms.realign(raw, CFG)))
    recon = ["reconstruct", "views.tif", "--psf", "psf.h5", "--iterations", "2", "--zarr",
             "--out", "rc"]
    _one_wins(_race(tmp_path, [recon] * 2, tmp_path / "cache"))
    import zarr

    image = tifffile.imread(tmp_path / "rc" / "image.tif")
    assert image.max() > 0
    np.testing.assert_array_equal(np.asarray(zarr.open_array(str(tmp_path / "rc" /
                                                                   "image.zarr"))[:]), image)
    # three psf runs, one cache entry: each computes and stores the same key at once
    cache = tmp_path / "psfcache"
    runs = _race(tmp_path, [["psf", "--config", "cfg.toml", "--out", f"p{k}.h5"]
                            for k in range(3)], cache)
    assert [code for code, _, _ in runs] == [0, 0, 0], runs
    (s0, e0), *others = [span for _, _, span in runs]
    assert all(s < e0 and s0 < e for s, e in others), runs
    banks = [load_psf(tmp_path / f"p{k}.h5")[0] for k in range(3)]
    entries = sorted((cache / "psf").iterdir())
    assert [p.suffix for p in entries] == [".npy"], entries  # one entry, no temporary
    cached = np.load(entries[0])
    for b in banks:
        np.testing.assert_array_equal(b, cached)
    assert _digests(*inputs) == inputs
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # locks, temps
