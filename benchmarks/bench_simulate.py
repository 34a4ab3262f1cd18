"""Simulator benchmark: a 2,048² chart, 5×5 scan, field-dependent aberration in 4×4 blocks,
SNR 30 dB (target < 60 s and < 4 GB on 2 CPU cores).

Each case runs in a fresh subprocess (peak RSS: that process's own, ``peak_resident_bytes``). The
fine PSF banks (``view_psfs(subsample=3)``, the optics stage's cost, cached on disk after the first
call) are timed separately: one real bank is computed (``psf_bank_s``) and handed to the simulator
for all 16 blocks through ``simulate(psf=...)`` (rendering cost does not depend on the bank's
content), so ``simulate_s`` is the simulator's own time with its banks in hand; the cold-cache CPU
total is ``simulate_cpu_s + 16 · psf_bank_cpu_s`` (cache off). ``simulate_cpu_s`` is its
CPU time (all threads; on a shared machine the wall time also counts waiting for the CPU).
Reference costs in the same process: one
``rfft2`` + ``irfft2`` of the scene, one copy of the views array.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def _child(size: int, nnum: int, blocks: int, scan: int) -> dict:
    import time

    import numpy as np
    import torch

    torch.set_num_threads(int(os.environ.get("BENCH_THREADS", "2")))
    import metasensor as ms
    from metasensor.io.memory import peak_resident_bytes
    from metasensor.simulation.capture import simulate
    from metasensor.simulation.kernels import fine_view_bank
    from metasensor.simulation.scenes import resolution_chart

    if nnum == 15:
        cfg = ms.SystemConfig(scan=scan)
    else:
        cfg = ms.SystemConfig(nnum=nnum, mla_pitch=4.6e-6 * nnum, mla_focal=46e-6 * nnum,
                              scan=scan)
    scene = resolution_chart(size)
    rng = np.random.default_rng(0)
    grid = np.zeros((blocks, blocks, 15))
    grid[..., 3:] = rng.normal(size=(blocks, blocks, 12))
    grid *= 0.5 / np.sqrt((grid**2).sum(-1, keepdims=True))  # 0.5 waves r.m.s. per block
    rss0 = peak_resident_bytes() / 2**30  # GiB
    from metasensor.optics.psf import view_psfs

    t0, c0 = time.perf_counter(), time.process_time()
    view_psfs(cfg, grid[0, 0], 0.0, subsample=3, cache=False)  # cold cost of one fine bank
    t_psf, c_psf = time.perf_counter() - t0, time.process_time() - c0
    bank = fine_view_bank(cfg, grid[0, 0], 0.0)

    def provider(cfg_, z, depth, phase=None, device=None):
        return bank

    t0, c0 = time.perf_counter(), time.process_time()
    cap = simulate(scene, cfg, field_zernike=grid, snr_db=30.0, psf=provider)
    t_sim, c_sim = time.perf_counter() - t0, time.process_time() - c0
    rss = peak_resident_bytes() / 2**30
    x = torch.from_numpy(scene)
    t0 = time.perf_counter()
    torch.fft.irfft2(torch.fft.rfft2(x), s=x.shape)
    t_fft = time.perf_counter() - t0
    t0 = time.perf_counter()
    _ = cap.views.copy()
    t_copy = time.perf_counter() - t0
    return {"case": f"{size}² nnum={nnum} scan={scan} blocks={blocks}x{blocks} snr=30",
            "simulate_s": round(t_sim, 2), "simulate_cpu_s": round(c_sim, 2),
            "psf_bank_s": round(t_psf, 2), "psf_bank_cpu_s": round(c_psf, 2),
            "cold_total_cpu_s": round(c_sim + blocks * blocks * c_psf, 1),
            "peak_rss_GB": round(rss, 3), "rss_after_import_GB": round(rss0, 3),
            "snr_measured_db": round(cap.snr_db, 3), "views": "x".join(map(str, cap.views.shape)),
            "fft_pair_s": round(t_fft, 3), "views_copy_s": round(t_copy, 3),
            "sim_over_fft_pair": round(t_sim / t_fft, 1),
            "threads": torch.get_num_threads()}


def _run_case(size: int, nnum: int, blocks: int, scan: int) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("BENCH_THREADS", "2"))
    src = str(HERE.parent / "src")
    env["PYTHONPATH"] = src + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--child", str(size),
                          str(nnum), str(blocks), str(scan)], env=env, capture_output=True,
                         text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(out.stderr.strip().splitlines()[-1] if out.stderr else "failed")
    return json.loads(out.stdout.strip().splitlines()[-1])


def run(quick: bool = False) -> list[dict]:
    if quick:
        return [_run_case(512, 5, 4, 5)]
    return [_run_case(2048, 15, 4, 5)]


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        size, nnum, blocks, scan = (int(a) for a in sys.argv[2:6])
        print(json.dumps(_child(size, nnum, blocks, scan)))
    else:
        for row in run(quick="--quick" in sys.argv):
            print(row)
