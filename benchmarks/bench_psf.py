"""Benchmark of the wave-optics PSF bank: the prototype's 15 x 15 views, one depth.

Each case runs in a fresh process (so its peak resident memory is its own): wall and CPU
seconds of ``view_psfs`` (cache off), peak RSS, the window K and grid, and the time of the FFTs
the bank needs (the same number of fft2 + ifft2 pairs of the same size and batch, through the
bank's own ``_propagate``, torch's FFT as the direct bank's; timed in the
same process right after) with its share of the wall time. Cases: aberration-free; 1 λ r.m.s.
random Noll modes 4-45 (seed 0) with the default 99.5 %-energy window and with K = 75; and the
subsample = 3 bank used by the simulator. ``quick``: the aberration-free bank and the 1 λ bank
at K = 75 only. Target: < 10 s on 2 CPU cores; < 0.5 s on a GPU.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

SRC = Path(__file__).resolve().parent.parent / "src"


def _case(name: str, rms: float, size: int | None, subsample: int, device: str | None) -> dict:
    import numpy as np
    import torch

    from metasensor.backend import resolve_device
    from metasensor.config import SystemConfig
    from metasensor.io.memory import peak_resident_bytes
    from metasensor.optics import psf as psf_mod
    from metasensor.optics.zernike import random_zernike

    torch.set_num_threads(min(2, torch.get_num_threads()))
    cfg = SystemConfig()
    dev = resolve_device(device)
    z = random_zernike(rms, seed=0) if rms > 0 else None
    psf_mod.view_psfs(SystemConfig(nnum=3, mla_pitch=13.8e-6, mla_focal=138e-6, scan=3),
                      size=3, cache=False, device=dev)  # warm-up (imports, kernels)
    if dev.type == "cuda":
        torch.cuda.synchronize()
    t0, c0 = time.perf_counter(), time.process_time()
    bank = psf_mod.view_psfs(cfg, z, 0.0, size=size, subsample=subsample, cache=False,
                             device=dev)
    if dev.type == "cuda":
        torch.cuda.synchronize()
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    k = bank.shape[-1] // subsample
    os_ = psf_mod._default_oversample(cfg, subsample)
    lenslets, n = psf_mod._grid(cfg, k, os_)
    npos = (cfg.nnum * subsample) ** 2
    batch = psf_mod._batch_size(n, npos, dev)
    x = torch.randn(batch, n, n, dtype=torch.complex64, device=dev)
    hz = torch.ones((n, n), dtype=torch.complex64, device=dev)
    t1 = time.perf_counter()
    for _ in range(-(-npos // batch)):
        psf_mod._propagate(x.clone(), hz)  # the direct bank's own FFT pair
    if dev.type == "cuda":
        torch.cuda.synchronize()
    fft = time.perf_counter() - t1
    peak = peak_resident_bytes() / 2**20  # this process's own (an exec resets it)
    if dev.type == "cuda":
        peak = max(peak, torch.cuda.max_memory_allocated() / 2**20)
    return {"case": name, "device": str(dev), "threads": torch.get_num_threads(),
            "K": k, "subsample": subsample, "grid": f"{lenslets} lenslets, {n}^2",
            "positions": npos, "seconds": wall, "cpu_seconds": cpu, "fft_seconds": fft,
            "fft_share": fft / wall, "peak_mb": peak,
            "energy_over_pi4_nnum2": float(np.sum(bank, dtype=np.float64)
                                           / (np.pi / 4 * cfg.nnum**2))}


def run(quick: bool = False, device: str | None = None) -> list[dict]:
    cases = [("aberration-free", 0.0, None, 1),
             ("1 wave rms, modes 4-45, K=75", 1.0, 75, 1)]
    if not quick:
        cases += [("1 wave rms, modes 4-45, default K", 1.0, None, 1),
                  ("aberration-free, subsample 3", 0.0, None, 3)]
    rows = []
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")]))
    for case in cases:
        args = json.dumps([*case, device])
        res = subprocess.run([sys.executable, __file__, "--case", args], env=env,
                             capture_output=True, text=True, check=False)
        if res.returncode != 0:
            raise RuntimeError(f"case {case[0]!r} failed: {res.stderr.strip()[-500:]}")
        rows.append(json.loads(res.stdout.strip().splitlines()[-1]))
    return rows


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    if len(sys.argv) == 3 and sys.argv[1] == "--case":
        print(json.dumps(_case(*json.loads(sys.argv[2]))))
    else:
        for row in run(quick="--quick" in sys.argv):
            print(row)
