"""DAO on a large block: the whole window against its most detailed sub-window.

``reconstruct`` estimates each block's wavefront on the block's most detailed sub-window of at
most ``dao_samples`` view samples per side (``ReconOptions.dao_samples``,
:func:`metasensor.recon.probe.probe_window`) and applies it to the whole block. This measures
what that costs in accuracy and saves in time and memory on one block of the size the 47 MP
sensor's 8 x 8 grid gives (about 300 samples a side): the astronaut scene, 900 px (quick:
450 px), a random 1 λ r.m.s. aberration (Noll 4-45, falling spectrum, seed 3), 30 dB per
frame; ``run_dao`` with its defaults but three updates always (``tol=0``), one torch thread,
each window in its own process (its peak resident memory is its own). Rows: window (samples
per side), seconds, peak resident memory (GB) and its rise over the process after loading the
views, wavefront error against the truth (waves r.m.s., Noll 4-45) and each update's r.m.s.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))

RMS, SEED, SNR_DB = 1.0, 3, 30.0


def _capture(size: int, path: Path) -> None:
    import numpy as np

    import metasensor as ms
    from metasensor.optics.zernike import random_zernike
    from metasensor.simulation.scenes import load_scene

    cap = ms.simulate(load_scene("astronaut", size), ms.SystemConfig(),
                      zernike=random_zernike(RMS, seed=SEED), snr_db=SNR_DB, seed=SEED,
                      comparison=False)
    np.save(path, cap.views)


def _peak_gb() -> float:
    """This process's own peak resident memory (GB; an ``exec`` resets it)."""
    from metasensor.io.memory import peak_resident_bytes

    return peak_resident_bytes() / 1e9


def _case(path: str, samples: int) -> dict:
    """One DAO run on the capture at ``path``, in this process (``samples`` 0: the whole)."""
    import numpy as np
    import torch

    torch.set_num_threads(1)
    import metasensor as ms
    from metasensor.dao.estimate import DaoOptions, run_dao
    from metasensor.dao.wavefront import zernike_rms
    from metasensor.optics.zernike import random_zernike
    from metasensor.recon.probe import probe_window

    views = np.load(path)
    win = probe_window(views, samples) if samples else views
    base = _peak_gb()
    t0 = time.perf_counter()
    res = run_dao(win, ms.SystemConfig(), DaoOptions(max_iter=3, tol=0.0))
    sec = time.perf_counter() - t0
    peak = _peak_gb()
    truth = random_zernike(RMS, seed=SEED)
    n = max(len(truth), len(res.zernike))
    err = np.zeros(n)
    err[:len(res.zernike)] += res.zernike
    err[:len(truth)] -= truth
    return {"window": "x".join(map(str, win.shape[-2:])), "seconds": sec, "peak_rss_gb": peak,
            "rise_gb": peak - base, "residual_rms": float(zernike_rms(err)),
            "updates": [round(float(h), 4) for h in res.history]}


def run(quick: bool = False) -> list[dict]:
    size = 450 if quick else 900
    windows = (48, 0) if quick else (96, 160, 0)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "views.npy"
        _capture(size, path)
        for samples in windows:
            out = subprocess.run([sys.executable, __file__, "--case", str(path), str(samples)],
                                 check=True, capture_output=True, text=True,
                                 env={**os.environ, "OMP_NUM_THREADS": "1"})
            row = json.loads(out.stdout.strip().splitlines()[-1])
            rows.append({"case": f"astronaut {size} px, {RMS:g} λ, {SNR_DB:g} dB",
                         "dao_samples": samples or None, **row})
    return rows


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    if sys.argv[1:2] == ["--case"]:
        print(json.dumps(_case(sys.argv[2], int(sys.argv[3]))))
    else:
        for row in run(quick="--quick" in sys.argv):
            print(row)
