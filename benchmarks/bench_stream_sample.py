"""The stream's default reconstruction projected from a sample of its blocks.

``bench_stream.py`` runs ``metasensor reconstruct views.zarr --blocks 8x8 --zarr`` on the whole
47 MP sensor (30+ min of both cores). This benchmark reconstructs ``N`` of its blocks and
projects the 64 blocks' time from them, so the cost line can be checked in minutes (and on
another machine, e.g. with the process pinned to 2 cores). Each sampled block's window holds
exactly what the stream's store holds there (the tiled astronaut's noise-free views plus the
store's per-view seeded noise, made as ``bench_stream._write_tiled_store`` makes it, only the
window kept) and is reconstructed as the command's default does it, one block of that window
(``metasensor.reconstruct(window, method="auto")``: wave DAO's probe, HQS): the same operator
sizes, probe and solver as the stream's block (its region's pixels differ only within the
overlap). The blocks are grouped by window shape; the largest groups are sampled first (the
block nearest the field's centre of each); a group left unsampled is projected at the sampled
blocks' mean seconds per window sample. Rows: one per sampled block (window, CPU and wall
seconds, whether DAO's estimate was applied, the SSIM of its region without 30 px at the
borders against the tiled truth), then the projection (CPU and wall seconds for all blocks one
after another, as ``--workers 1``; the peak resident memory of this process while the blocks
ran; the 1-min load average before and after). torch's threads: ``--threads`` (default torch's
own). ``--aberration RMS``: the store's content seen through a lens aberration of RMS waves
r.m.s. (a falling spectrum over Noll 4–45, seed 0, ``bench_quality.falling_zernike``; the same
over the field), so that the probe finds it and every block runs wave DAO before HQS: the cost
of the whole sensor's aberrated reconstruction, projected. Usage: ``python
benchmarks/bench_stream_sample.py [--blocks N] [--threads T] [--aberration RMS] [--quick]``,
``python benchmarks/bench_stream.py --blocks-sample N``, or ``run_all.py [--quick]
stream_sample`` (N = 3; quick: the quick stream's 2 x 2 blocks, N = 1). Measured figures:
``docs/decisions.md``.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))
sys.path.insert(0, str(HERE))

import metasensor  # noqa: E402, F401  (first: it sets OpenMP's wait policy before torch loads)

MARGIN_PX = 30  # border of a block's region left out of its SSIM


def _groups(blocks, d: int) -> list[list]:
    """Blocks grouped by window shape, largest group first, each group's block nearest the
    field's centre first."""
    groups = defaultdict(list)
    for b in blocks:
        sy, sx = b.window_samples(d)
        groups[(sy.stop - sy.start, sx.stop - sx.start)].append(b)
    iy = (max(b.index[0] for b in blocks)) / 2
    ix = (max(b.index[1] for b in blocks)) / 2
    out = [sorted(g, key=lambda b: (b.index[0] - iy) ** 2 + (b.index[1] - ix) ** 2)
           for g in groups.values()]
    return sorted(out, key=len, reverse=True)


def _windows(blocks, clean: np.ndarray, shape: tuple[int, int], var, d: int) -> list[np.ndarray]:
    """The store's content (``bench_stream._write_tiled_store``) in each block's window."""
    n = clean.shape[0]
    reps = (-(-shape[0] // clean.shape[2]), -(-shape[1] // clean.shape[3]))
    slices = [b.window_samples(d) for b in blocks]
    out = [np.empty((n, n, sy.stop - sy.start, sx.stop - sx.start), np.float32)
           for sy, sx in slices]
    for u in range(n):
        for v in range(n):
            rng = np.random.default_rng([u, v])
            noise = rng.standard_normal(shape, dtype=np.float32)
            plane = np.tile(clean[u, v], reps)[:shape[0], :shape[1]]
            for (sy, sx), win in zip(slices, out, strict=True):
                p = plane[sy, sx]
                std = np.sqrt(np.float32(var[0]) * p + np.float32(var[1]))
                win[u, v] = np.maximum(p + noise[sy, sx] * std, 0.0)
    return out


class _Peak:
    """The process's resident memory, sampled every 20 ms while running."""

    def __init__(self) -> None:
        self.peak, self._stop = 0, threading.Event()
        self._page = os.sysconf("SC_PAGE_SIZE")
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            with open("/proc/self/statm") as f:
                self.peak = max(self.peak, int(f.read().split()[1]) * self._page)
            time.sleep(0.02)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def _residual_waves(rec, zernike) -> float | None:
    """r.m.s. (waves) of DAO's estimate minus the true aberration over DAO's modes (Noll 4–45:
    piston and tilts only move the image); None without DAO or aberration."""
    from metasensor.dao.wavefront import zernike_rms

    if zernike is None or rec.dao_zernike is None:
        return None
    est = np.asarray(rec.dao_zernike[0, 0], np.float64)
    n = max(est.size, zernike.size)
    a, b = np.zeros(n), np.zeros(n)
    a[:est.size], b[:zernike.size] = est, zernike
    return zernike_rms(a - b)


def _block_row(block, window, cfg, truth, d: int, zernike=None) -> dict:
    import metasensor as ms
    from metasensor.metrics import ssim

    c0, t0 = time.process_time(), time.perf_counter()
    rec = ms.reconstruct(window, cfg, method="auto")
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    sy, sx = block.window_samples(d)
    h, w = rec.image.shape
    ty, tx = truth.shape
    rows = (np.arange(h) + sy.start * d) % ty
    cols = (np.arange(w) + sx.start * d) % tx
    tiled = truth[rows][:, cols]
    m = MARGIN_PX
    quality = ssim(truth=tiled[m:-m, m:-m], image=rec.image[m:-m, m:-m],
                   data_range=float(truth.max() - truth.min()))
    return {"block": str(block.index), "window_samples": f"{h // d}x{w // d}", "cpu_s": cpu,
            "wall_s": wall, "dao": rec.method, "dao_applied": bool(rec.dao_applied[0][0]),
            "ssim_region": quality, "dao_residual_waves": _residual_waves(rec, zernike)}


def run(quick: bool = False, blocks: int | None = None, threads: int | None = None,
        aberration: float = 0.0) -> list[dict]:
    import torch

    import bench_stream as bs
    import metasensor as ms
    from metasensor.recon.blocks import split_blocks
    from metasensor.recon.options import ReconOptions
    from metasensor.sensor.realign import lenslet_counts

    case = bs.QUICK if quick else bs.FULL
    n_sample = blocks if blocks is not None else (1 if quick else 3)
    cfg = ms.SystemConfig()
    d = cfg.scan_step_px
    zernike = None
    if aberration:
        from bench_quality import falling_zernike

        zernike = falling_zernike(float(aberration), seed=0)
    cap, clean, var, _ = bs.tiled_capture(cfg, zernike)
    t = bs.TILE_PX // d
    truth = cap.truth[bs.TILE_PX:2 * bs.TILE_PX, bs.TILE_PX:2 * bs.TILE_PX]
    clean = clean[:, :, t:2 * t, t:2 * t]
    del cap
    shape = tuple(n * cfg.scan for n in lenslet_counts(case["sensor"], cfg))
    grid = tuple(int(v) for v in case["blocks"].split("x"))
    all_blocks = split_blocks((shape[0] * d, shape[1] * d), grid, d,
                              overlap=ReconOptions().overlap, margin=cfg.nnum)
    groups = _groups(all_blocks, d)
    sampled = [g[0] for g in groups[:max(int(n_sample), 1)]]
    windows = _windows(sampled, clean, shape, var, d)
    if threads is not None:
        torch.set_num_threads(int(threads))
    used = torch.get_num_threads()
    load0 = os.getloadavg()[0]
    rows = []
    with _Peak() as peak:
        for block, window in zip(sampled, windows, strict=True):
            rows.append(_block_row(block, window, cfg, truth, d, zernike))
    rows.append(_projection(rows, groups, sampled, d, peak.peak, load0, case, grid, used))
    rows[-1]["aberration_rms_waves"] = float(aberration)
    return rows


def _projection(rows, groups, sampled, d, peak, load0, case, grid, threads) -> dict:
    """All blocks one after another: each group at its sampled block's seconds, the others at
    the sampled mean per window sample."""
    def samples(b) -> int:
        sy, sx = b.window_samples(d)
        return (sy.stop - sy.start) * (sx.stop - sx.start)

    per = {id(b): r for b, r in zip(sampled, rows, strict=True)}
    area = sum(samples(b) for b in sampled)
    rate = {k: sum(r[k] for r in rows) / area for k in ("cpu_s", "wall_s")}
    total = {"cpu_s": 0.0, "wall_s": 0.0}
    for g in groups:
        row = per.get(id(g[0]))
        for k in total:
            total[k] += len(g) * (row[k] if row is not None else rate[k] * samples(g[0]))
    return {"block": "projection", "sensor_px": f"{case['sensor'][0]}x{case['sensor'][1]}",
            "blocks": f"{grid[0]}x{grid[1]}", "blocks_sampled": len(rows),
            "torch_threads": threads,
            "projected_cpu_s": total["cpu_s"], "projected_wall_s": total["wall_s"],
            "peak_rss_gb": peak / 1e9,
            "load_1min_before_after": [load0, os.getloadavg()[0]]}


def main(argv: list[str]) -> int:
    import argparse
    import json

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--blocks", type=int, default=None, help="blocks to reconstruct")
    parser.add_argument("--threads", type=int, default=None, help="torch threads")
    parser.add_argument("--quick", action="store_true", help="the quick stream's blocks")
    parser.add_argument("--aberration", type=float, default=0.0,
                        help="lens aberration [waves r.m.s.] of the store's content")
    parser.add_argument("--out", default=None, help="JSON file (default results/...)")
    args = parser.parse_args(argv)
    from metasensor.io.atomic import atomic_write_text
    from run_all import machine

    t0 = time.perf_counter()
    if not (args.aberration >= 0.0 and np.isfinite(args.aberration)):
        parser.error(f"--aberration must be a finite number >= 0, got {args.aberration}")
    rows = run(quick=args.quick, blocks=args.blocks, threads=args.threads,
               aberration=args.aberration)
    for r in rows:
        print(r)
    name = "stream_sample_quick.json" if args.quick else "stream_sample.json"
    if args.aberration:
        name = name.replace(".json", "_aberrated.json")
    out = Path(args.out) if args.out else HERE / "results" / name
    payload = {"benchmark": "stream_sample", "quick": args.quick, "machine": machine(),
               "seconds_total": time.perf_counter() - t0, "rows": rows}
    atomic_write_text(out, json.dumps(payload, indent=2, default=float))
    print(f"-> {out}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main(sys.argv[1:]))
