"""The whole sensor's cost: a sensor-sized capture streamed from Zarr through multisite blocks
into Zarr.

The claim measured: ``metasensor reconstruct views.zarr --blocks 8x8 --zarr`` reconstructs the
prototype's whole field without holding its field of views in memory at once. The views of the
CMV50000 (7,920 x 6,004 px: 527 x 399 lenslets fully on the sensor at every phase of a 5 x 5
scan) are ``(15, 15, 1995, 2635)`` float32, 4.7 GB, for a 5,985 x 7,905-px (47.3 MP) image.

The store is written plane by plane (never held whole). Its content is a capture of a periodic
scene: the astronaut at 315 px (21 lenslets) tiled 3 x 3 is simulated (aberration-free, 5 x 5
scan), and the noise-free views of its middle tile (105 samples a side, consistent with the
periodic scene because the PSFs reach far less than a tile) are tiled over the field, plus fresh
Gaussian noise with the signal-dependent variance a·signal + b fitted to that capture's 30 dB
photon and read noise (seeded per view), so the store compresses like a real one.
A child process runs the command and reports its own peak resident memory and CPU time, once per
mode: the command's default (no options: the sparse-gradient solver, HQS, after ``--dao auto``'s
per-block aberration probe), then ``--quality fast`` (the preview: Richardson-Lucy, 5
iterations, the streaming benchmark's setting, no aberration estimate). Rows: views bytes
(logical and on disk), peak RSS and its ratio to the views, wall and CPU time, seconds per
megapixel, the 1-minute load average before and after, and the SSIM of a 4 x 4-tile crop in the
middle against the tiled truth, next to the middle tile of the 3 x 3-tile capture reconstructed
in one piece (with the same settings). A full run writes ``results/stream.json`` after each row
(``"partial": true`` until the last). ``--blocks-sample N`` reconstructs N of the blocks only
and projects the whole (``bench_stream_sample.py``). Measured figures: ``docs/decisions.md``.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))
sys.path.insert(0, str(HERE))  # _paths: where figures go

from _paths import output_path  # noqa: E402

FULL = {"sensor": (6004, 7920), "blocks": "8x8"}
QUICK = {"sensor": (1204, 1204), "blocks": "2x2"}
TILE_PX = 315  # 21 lenslets
ITERATIONS = 5
# the command's default, then the preview (the streaming benchmark's setting)
MODES = {"default": [], "fast": ["--quality", "fast"]}

# the child's own peak: VmHWM (ru_maxrss would carry this process's peak over into the child)
_CHILD = """
import resource, sys
from metasensor.cli import app
from metasensor.io.memory import peak_resident_bytes
try:
    app(args=sys.argv[1:], standalone_mode=False)
finally:
    use = resource.getrusage(resource.RUSAGE_SELF)
    print("PEAK_RSS_KB " + str(peak_resident_bytes() // 1024) + " CPU_S "
          + str(use.ru_utime + use.ru_stime))
"""


def modes() -> list[str]:
    """The modes to run: every one of :data:`MODES`, or those named in ``STREAM_MODES``
    (comma-separated, e.g. ``default``: a re-measurement of one row, ``rerun.py stream``)."""
    import os

    names = [m for m in os.environ.get("STREAM_MODES", "").split(",") if m] or list(MODES)
    unknown = [m for m in names if m not in MODES]
    if unknown:
        raise SystemExit(f"STREAM_MODES: unknown mode(s) {unknown}; choose from {list(MODES)}")
    return names


def _write_tiled_store(path: Path, small: np.ndarray, shape: tuple[int, int], cfg,
                       var: tuple[float, float]) -> None:
    """A (nnum, nnum, *shape) zarr store of ``small`` tiled periodically plus Gaussian noise of
    variance ``var[0] * signal + var[1]``, one view at a time."""
    import zarr

    n = small.shape[0]
    arr = zarr.open_array(str(path), mode="w", shape=(n, n, *shape), dtype="f4",
                          chunks=(1, 1, 1024, 1024))
    reps = (-(-shape[0] // small.shape[2]), -(-shape[1] // small.shape[3]))
    for u in range(n):
        for v in range(n):
            rng = np.random.default_rng([u, v])
            plane = np.tile(small[u, v], reps)[:shape[0], :shape[1]]
            std = np.sqrt(np.float32(var[0]) * plane + np.float32(var[1]))
            noise = rng.standard_normal(shape, dtype=np.float32) * std
            arr[u, v] = np.maximum(plane + noise, 0.0)
    arr.attrs.update({"metasensor": {"kind": "views", "view_shape": [n, n, *shape],
                                     "config": cfg.to_dict()}})


def _write_partial(rows: list[dict], partial: bool) -> None:
    """results/stream.json after each row of a full run (run_all.py rewrites it at the end)."""
    from metasensor.io.atomic import atomic_write_text
    from run_all import machine

    payload = {"benchmark": "stream", "quick": False, "partial": partial, "machine": machine(),
               "rows": rows}
    atomic_write_text(HERE / "results" / "stream.json", json.dumps(payload, indent=2,
                                                                   default=float))


def _du(path: Path) -> int:
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file())


def tiled_capture(cfg, zernike=None):
    """The astronaut tiled 3 x 3, simulated at 30 dB and noise-free (through the lens
    aberration ``zernike``, Noll vector in waves r.m.s., where given: the same over the field);
    returns the noisy capture, the clean views, the noise's (gain, variance floor) fitted
    against the clean views (DN², the floor at least the quantisation's 1/12) and the noise's
    r.m.s. (DN)."""
    import metasensor as ms
    from metasensor.simulation.scenes import load_scene

    scene = np.tile(load_scene("astronaut", TILE_PX), (3, 3))
    cap = ms.simulate(scene, cfg, zernike=zernike, snr_db=30.0, seed=0, comparison=False)
    clean = ms.simulate(scene, cfg, zernike=zernike, seed=0, comparison=False).views
    resid2 = ((cap.views - clean) ** 2).ravel()
    var = np.linalg.lstsq(np.stack([clean.ravel(), np.ones(clean.size)], 1), resid2,
                          rcond=None)[0]
    var = (max(float(var[0]), 0.0), max(float(var[1]), 1.0 / 12.0))
    return cap, clean, var, float(np.sqrt(resid2.mean()))


def run(quick: bool = False) -> list[dict]:

    import metasensor as ms
    from metasensor.sensor.realign import lenslet_counts

    case = QUICK if quick else FULL
    cfg = ms.SystemConfig()
    d = cfg.scan_step_px
    cap, clean, var, sigma = tiled_capture(cfg)
    t = TILE_PX // d  # view samples per tile
    clean = clean[:, :, t:2 * t, t:2 * t]
    truth = cap.truth[TILE_PX:2 * TILE_PX, TILE_PX:2 * TILE_PX]
    shape = tuple(n * cfg.scan for n in lenslet_counts(case["sensor"], cfg))
    image_shape = (shape[0] * d, shape[1] * d)
    work = Path(tempfile.mkdtemp(prefix="ms-stream-"))
    try:
        store = work / "views.zarr"
        t0 = time.perf_counter()
        _write_tiled_store(store, clean, shape, cfg, var)
        write_s = time.perf_counter() - t0
        rows = []
        for mode in modes():
            rows.append(_reconstruct_row(store, work / f"result-{mode}", mode, case, cfg, cap,
                                         truth, shape, image_shape, write_s, sigma, var))
            if not quick:
                _write_partial(rows, len(rows) < len(modes()))
        return rows
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _reconstruct_row(store, out, mode, case, cfg, cap, truth, shape, image_shape, write_s,
                     sigma, var) -> dict:
    """Run ``metasensor reconstruct`` on the store in a child process in ``mode`` (a key of
    :data:`MODES`) and measure it."""
    import os

    import zarr

    import metasensor as ms
    from metasensor.metrics import ssim

    args = ["reconstruct", str(store), "--out", str(out), "--blocks", case["blocks"],
            *MODES[mode], "--zarr"]
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", _CHILD, *args], capture_output=True,
                          text=True, check=False)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"reconstruct failed: {proc.stderr.strip()[-2000:]}")
    tail = proc.stdout.rsplit("PEAK_RSS_KB", 1)[1].split()
    peak_kb, cpu_s = int(tail[0]), float(tail[2])
    summary = json.loads((out / "summary.json").read_text())
    image = zarr.open_array(str(out / "image.zarr"), mode="r")
    # a crop of 4 x 4 tiles in the middle, against the tiled truth
    ty, tx = truth.shape
    side = min(4 * ty, image_shape[0], image_shape[1]) // ty * ty
    y0 = (image_shape[0] // 2) // ty * ty - side // 2 // ty * ty
    x0 = (image_shape[1] // 2) // tx * tx - side // 2 // tx * tx
    crop = np.asarray(image[y0:y0 + side, x0:x0 + side])
    tiled = np.tile(truth, (side // ty, side // tx))
    rng = float(truth.max() - truth.min())
    solver = "hqs" if mode == "default" else "rl"
    kw = {"iterations": ITERATIONS} if solver == "rl" else {}
    method = "auto" if mode == "default" else "none"
    alone = ms.reconstruct(cap.views, cfg, method=method, solver=solver, **kw).image
    alone = alone[TILE_PX:2 * TILE_PX, TILE_PX:2 * TILE_PX]
    views_bytes = int(np.prod((cfg.nnum, cfg.nnum, *shape))) * 4
    row = {"sensor_px": f"{case['sensor'][0]}x{case['sensor'][1]}",
           "image_px": f"{image_shape[0]}x{image_shape[1]}",
           "megapixels": image_shape[0] * image_shape[1] / 1e6,
           "noise_rms": sigma, "noise_var_fit": [round(v, 4) for v in var],
           "views_gb": views_bytes / 1e9, "store_gb": _du(store) / 1e9,
           "blocks": case["blocks"], "mode": mode, "solver": solver, "dao": summary.get(
               "method"),
           "iterations": ITERATIONS if solver == "rl" else None,
           "peak_rss_gb": peak_kb * 1024 / 1e9,
           "rss_over_views": peak_kb * 1024 / views_bytes,
           "write_store_s": write_s, "wall_s": wall, "recon_s": summary["seconds"],
           "cpu_s": cpu_s, "load_1min_before_after": [load0, os.getloadavg()[0]],
           "s_per_mp": summary["seconds"] / (image_shape[0] * image_shape[1] / 1e6),
           "finite_nonneg": bool(np.isfinite(crop).all() and crop.min() >= 0),
           "ssim_crop": ssim(truth=tiled, image=crop, data_range=rng),
           "ssim_middle_tile_alone": ssim(truth=truth, image=alone, data_range=rng)}
    if case is FULL:
        dest = output_path(f"stream_reconstruction_{solver}.png")
        shutil.copyfile(out / "reconstruction.png", dest)
    shutil.rmtree(out, ignore_errors=True)
    return row


if __name__ == "__main__":  # pragma: no cover
    from _usage import exit_on_help

    exit_on_help(__doc__)
    if "--blocks-sample" in sys.argv:  # a sample of the blocks, projected (bench_stream_sample)
        from bench_stream_sample import main

        i = sys.argv.index("--blocks-sample")
        rest = sys.argv[1:i] + sys.argv[i + 2:]
        raise SystemExit(main(["--blocks", sys.argv[i + 1], *rest]))
    for r in run(quick="--quick" in sys.argv):
        print(r)
