"""The reconstruction default on aberrated and aberration-free captures: ``method="auto"`` (the
command line's default: wave DAO per block, a negligible estimate not applied) against plain ISA
(the default before, ``--dao none``).

Captures: the built-in chart and the camera scene, 256 px in 2 x 2 blocks (quick: the chart
only, 150 px, one block), 30 dB, 5 x 5 scan, the prototype's optics, with no aberration and
with a uniform aberration of 0.5 waves r.m.s. (Noll Z4 : Z5 : Z7 = 0.35 : 0.3 : 0.2), the default
solver (HQS). Rows: scene, aberration (waves r.m.s.), method, SSIM / PSNR against the truth,
seconds, the largest wavefront used and estimated over the blocks (waves r.m.s., Noll 4-45)
and how many blocks applied their estimate. Full mode adds the threshold rows
(:data:`metasensor.recon.dao_choice.NEGLIGIBLE_RMS`): a 150-px chart with 0 / 0.02 / 0.05 λ at
30 dB and 0 / 0.02 λ at 20 dB, DAO always applied (``"wave"``) against none: what DAO estimates
without an aberration (the noise floor) and where applying a small estimate starts to pay.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))

SHAPE = np.array([0.0, 0.0, 0.0, 0.35, 0.3, 0.0, 0.2])  # Noll 1-7, r.m.s. 0.50 λ


def aberration(rms: float) -> np.ndarray | None:
    """The uniform Noll vector of r.m.s. ``rms`` waves (None for 0)."""
    if rms == 0:
        return None
    return SHAPE * (rms / float(np.sqrt(np.sum(SHAPE[3:] ** 2))))


def _row(scene: str, rms: float, method: str, cap, blocks) -> dict:
    import metasensor as ms
    from metasensor.dao.wavefront import zernike_rms

    t0 = time.perf_counter()
    rec = ms.reconstruct(cap.views, cap.config, method=method, blocks=blocks)
    seconds = time.perf_counter() - t0
    img = np.asarray(rec.image)
    z = np.asarray(rec.zernike)
    applied = [a for row in rec.dao_applied for a in row if a is not None]
    dz = rec.dao_zernike
    estimated = (float("nan") if dz is None
                 else max(zernike_rms(v) for v in dz.reshape(-1, dz.shape[-1])))
    return {"scene": scene, "aberration_rms": rms, "method": method,
            "blocks": f"{blocks[0]}x{blocks[1]}",
            "ssim": ms.metrics.ssim(truth=cap.truth, image=img),
            "psnr_db": ms.metrics.psnr(truth=cap.truth, image=img), "seconds": seconds,
            "max_used_rms": max(zernike_rms(v) for v in z.reshape(-1, z.shape[-1])),
            "max_estimated_rms": estimated,
            "blocks_applied": f"{sum(applied)}/{len(applied)}" if applied else "-"}


def _threshold_rows() -> list[dict]:
    """Where applying a small estimate starts to pay, and DAO's estimate on aberration-free
    captures (the noise floor): 150-px chart, one block, DAO always applied against none."""
    import metasensor as ms
    from metasensor.simulation.scenes import load_scene

    rows = []
    for snr, rms_list in ((30, (0.0, 0.02, 0.05)), (20, (0.0, 0.02))):
        for rms in rms_list:
            cap = ms.simulate(load_scene("chart", 150), ms.SystemConfig(),
                              zernike=aberration(rms), snr_db=snr, seed=1, comparison=False)
            for method in ("isa", "wave"):
                rows.append({**_row("chart", rms, method, cap, (1, 1)), "snr_db": snr})
                print(rows[-1], flush=True)
    return rows


def run(quick: bool = False) -> list[dict]:
    import torch

    import metasensor as ms
    from metasensor.simulation.scenes import load_scene

    torch.set_num_threads(1)
    cfg = ms.SystemConfig()
    size, blocks = (150, (1, 1)) if quick else (256, (2, 2))
    rows = []
    for scene in ("chart",) if quick else ("chart", "camera"):
        truth = load_scene(scene, size)
        for rms in (0.0, 0.5):
            cap = ms.simulate(truth, cfg, zernike=aberration(rms), snr_db=30, seed=0,
                              comparison=False)
            for method in ("isa", "auto"):
                rows.append({**_row(scene, rms, method, cap, blocks), "snr_db": 30})
                print(rows[-1], flush=True)
    return rows if quick else rows + _threshold_rows()
