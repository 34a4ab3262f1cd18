"""Realign at memory speed: 25 frames of 6,004 x 7,920 uint16 (2.4 GB, the prototype's full
sensor, 5 x 5 scan) against a plain memory copy of the same bytes, in the same run.

Rows: realign (compiled gather and NumPy), memory copy (``np.copyto`` into a preallocated
array), their ratio, peak resident memory over the input size; rectification per frame
(spline vs OpenCV Lanczos). ``quick``: 1/100 of the pixels.
"""

from __future__ import annotations

import time
from functools import partial

import numpy as np

from metasensor.config import SystemConfig
from metasensor.io.memory import peak_resident_bytes, reset_peak_resident
from metasensor.sensor.gather import have_numba
from metasensor.sensor.realign import lenslet_counts, realign


def _best(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _rectify_rows(quick: bool) -> list[dict]:
    from metasensor.sensor.calibration import Calibration
    from metasensor.sensor.rectify import rectify_frame

    side = 600 if quick else 2000
    frame = np.random.default_rng(1).integers(0, 4096, (side, side), dtype=np.uint16)
    ly = int((side - 80) / 15.1)
    calib = Calibration(nnum=15, pitch=15.1, rotation=0.3, center=(30.3, 34.1),
                        lenslets=(ly, ly), sensor_shape=(side, side))
    rows = []
    for method in ("spline", "lanczos", "cubic"):
        sec = _best(partial(rectify_frame, frame, calib, method=method), 2)
        rows.append({"case": f"rectify {side}x{side} ({method})", "seconds": sec,
                     "Mpx_per_s": side * side / sec / 1e6})
    return rows


def run(quick: bool = False) -> list[dict]:
    cfg = SystemConfig()  # nnum 15, scan 5
    shape = (600, 792) if quick else (6004, 7920)
    t = cfg.scan**2
    rng = np.random.default_rng(0)
    reset_peak_resident()  # this benchmark's peak, not that of a runner's earlier benchmarks
    frames = np.empty((t, *shape), np.uint16)
    for k in range(t):
        frames[k] = rng.integers(0, 4096, shape, dtype=np.uint16)
    nbytes = frames.nbytes
    repeat = 3

    buf = np.empty_like(frames)
    copy_s = _best(partial(np.copyto, buf, frames), repeat)
    del buf

    ly, lx = lenslet_counts(shape, cfg)
    realign(frames[:, :200, :200], cfg)  # warm-up: load / compile the kernel
    realign(frames[:, :200, :200], cfg, engine="numba" if have_numba() else "numpy")
    out = np.empty((15, 15, ly * 5, lx * 5), np.uint16)
    engine = "numba" if have_numba() else "numpy"
    realign_s = _best(partial(realign, frames, cfg, out=out, engine=engine), repeat)
    peak = peak_resident_bytes()
    numpy_s = _best(partial(realign, frames, cfg, out=out, engine="numpy"), 1)
    try:
        import numba

        threads = numba.get_num_threads()
    except ImportError:
        threads = 1
    rows = [
        {"case": f"memory copy {t}x{shape[0]}x{shape[1]} uint16", "seconds": copy_s,
         "GB": nbytes / 1e9, "GB_per_s": nbytes / copy_s / 1e9},
        {"case": f"realign ({engine}, {threads} threads)", "seconds": realign_s,
         "GB": nbytes / 1e9, "GB_per_s": nbytes / realign_s / 1e9,
         "ratio_to_copy": realign_s / copy_s, "target_ratio": 2.0},
        {"case": "realign (numpy strided assignment)", "seconds": numpy_s,
         "GB": nbytes / 1e9, "GB_per_s": nbytes / numpy_s / 1e9,
         "ratio_to_copy": numpy_s / copy_s},
        {"case": "peak resident memory / input", "seconds": float("nan"),
         "GB": peak / 1e9, "ratio_to_input": peak / nbytes, "target_ratio": 2.5},
    ]
    del frames, out
    return rows + _rectify_rows(quick)
