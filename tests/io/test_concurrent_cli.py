"""Runs writing the same output at the same time: one writes, the others fail at once with one
line (a lock beside the output), and what is left is one run's whole result (the audit: two
``reconstruct --zarr`` runs left an all-zero image, three ``realign --out v.zarr`` runs left 180
of 225 views zero, all exiting 0). Real ``metasensor`` processes, started together."""

import hashlib
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
from metasensor.optics.psf_io import save_psf

CFG = ms.SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)


@pytest.mark.slow  # five interpreters at once: ~80 s on a loaded 2-core machine
def test_concurrent_writers_of_one_output(tmp_path):
    rng = np.random.default_rng(0)
    frames = rng.integers(100, 4000, (9, 90, 90)).astype(np.uint16)
    write_raw(tmp_path / "raw.tif", frames, description=CFG.to_json())
    write_views(tmp_path / "views.tif", 1 + rng.random((3, 3, 30, 30)).astype(np.float32), CFG)
    yy, xx = np.mgrid[-2:3, -2:3]
    bank = np.broadcast_to(np.exp(-(yy**2 + xx**2) / 2.0), (3, 3, 5, 5)).astype(np.float32)
    save_psf(tmp_path / "psf.h5", bank / bank.sum((2, 3), keepdims=True), CFG)
    inputs = {p: hashlib.sha256(p.read_bytes()).hexdigest()
              for p in (tmp_path / "raw.tif", tmp_path / "views.tif", tmp_path / "psf.h5")}
    realign = ["realign", "raw.tif", "--out", "v.zarr"]
    recon = ["reconstruct", "views.tif", "--psf", "psf.h5", "--iterations", "2", "--zarr",
             "--out", "rc"]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2] / "src"),
           "OMP_NUM_THREADS": "1", "METASENSOR_CACHE": str(tmp_path / "cache")}
    procs = [(args, subprocess.Popen([sys.executable, "-m", "metasensor.cli", *args],
                                     cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True))
             for args in (realign, realign, realign, recon, recon)]
    codes = {}
    for args, proc in procs:
        _, err = proc.communicate(timeout=300)
        codes.setdefault(args[0], []).append(proc.returncode)
        if proc.returncode:  # the one way to fail: another run holds the output
            last = err.strip().splitlines()[-1]
            assert proc.returncode == 2 and last.startswith("error: another metasensor run "
                                                            "is writing"), err[-2000:]
    assert 0 in codes["realign"] and 0 in codes["reconstruct"], codes
    expected = np.asarray(ms.realign(frames, CFG))
    np.testing.assert_array_equal(np.asarray(read_views(tmp_path / "v.zarr")[:]), expected)
    import zarr

    image = tifffile.imread(tmp_path / "rc" / "image.tif")
    assert image.max() > 0
    np.testing.assert_array_equal(np.asarray(zarr.open_array(str(tmp_path / "rc" /
                                                                   "image.zarr"))[:]), image)
    assert all(hashlib.sha256(p.read_bytes()).hexdigest() == h for p, h in inputs.items())
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]  # locks, temps
