"""Why multisite wave DAO fails on the plastic wrap: the wrap's change inside a block.

The plastic-wrap scenario's capture (``metasensor.scenarios.plastic_wrap``: the bar chart with
the near object, 240 px, 4 x 4 field sites, SNR 30 dB, seed 0) is simulated for wraps of one
statistic (3 waves r.m.s. over three sheets, correlation 0.25 D) whose footprints spread over
the field by ``spread`` pupil diameters (0: every field point sees the same wrap). Rows:

- ``fit``: the wrap's wavefront at the strongest 4 x 4 site: its Noll 4-45 r.m.s. and what a
  Noll 1-45 (and 1-91) fit leaves (waves r.m.s. over the pupil): whether 45 modes can hold it.
- ``dao``: per spread, per block: the wrap's change across the block
  (:meth:`~metasensor.scenarios.screens.PlasticWrap.block_variation`), and DAO run on the block's
  views (the window ``reconstruct`` gives it) from zero and, for some spreads, from the true
  site vector, ``max_iter`` updates with ``tol=0``: every update's r.m.s. distance from the
  truth at the block centre (Noll 4-45, waves), the shift fit's residual (pixels) and whether
  the divergence guard refused an update.
- ``oracle``: per spread, the reconstruction (HQS, 4 x 4 blocks, one bank per block) with the
  TRUE site vectors, and with the space-variant model (banks at the block corners): resolved
  frequency over 4 x 4 regions (mean, worst) and SSIM, against the 2D sensor's.

``--quick``: spreads 0.6 and 0.15, one block, no oracle.
"""

from __future__ import annotations

import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))

MODES = range(4, 46)


def _wrap(spread: float):
    from metasensor.scenarios.plastic_wrap import PlasticWrapSettings

    return replace(PlasticWrapSettings().wrap, spread=spread)


def fit_row() -> dict:
    from metasensor.optics.field import block_centres_normalised
    from metasensor.optics.zernike import fit_zernike, wavefront

    wrap = _wrap(0.6)
    yn, xn = block_centres_normalised(4, 4)
    z = wrap.field_zernike()(yn, xn)
    rms = np.sqrt((z[..., 3:] ** 2).sum(-1))
    i, j = np.unravel_index(int(rms.argmax()), rms.shape)
    w = wrap.wavefront(float(yn[i, j]), float(xn[i, j]))
    k = -1 + (np.arange(w.shape[0]) + 0.5) * 2 / w.shape[0]
    x, y = np.meshgrid(k, k, indexing="xy")
    disk = x * x + y * y <= 1
    left = {}
    for jmax in (45, 91):
        c = fit_zernike(w, x, y, jmax=jmax, modes=range(1, jmax + 1))
        left[jmax] = float(np.std((w - wavefront(c, x, y))[disk]))
    return {"case": "fit", "site": [int(i), int(j)], "noll_4_45_rms": float(rms[i, j]),
            "wavefront_rms": float(np.std(w[disk])), "residual_after_45": left[45],
            "residual_after_91": left[91]}


def _capture(spread: float):
    import metasensor as ms
    from metasensor.scenarios.plastic_wrap import near_object_scene

    cfg = ms.SystemConfig()
    scene, depth, _ = near_object_scene(240, 1.0e-3)
    cap = ms.simulate(scene, cfg, field_zernike=_wrap(spread).field_zernike(), depth=depth,
                      snr_db=30.0, seed=0, field_blocks=(4, 4))
    return cap, ms.realign(cap.frames, cap.config, cap.scan_order)


def _dao(views, cfg, block, truth, init, max_iter: int) -> dict:
    from metasensor.dao.estimate import run_dao
    from metasensor.dao.wavefront import zernike_rms

    sy, sx = block.window_samples(cfg.scan_step_px)
    win = np.asarray(views[:, :, sy, sx], np.float32)
    t0 = time.process_time()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = run_dao(win, cfg, init=init, max_iter=max_iter, tol=0.0)
    refused = any("DAO stopped" in str(w.message) for w in caught)
    return {"error_per_update": [zernike_rms(e - truth, MODES) for e in res.estimates],
            "fit_residual_px": list(res.fits), "refused": refused,
            "cpu_s": time.process_time() - t0}


def dao_rows(spreads, blocks, truth_starts, max_iter: int = 4) -> list[dict]:
    import torch

    import metasensor as ms
    from metasensor.dao.wavefront import zernike_rms
    from metasensor.recon.blocks import split_blocks

    torch.set_num_threads(1)
    cfg = ms.SystemConfig()
    rows = []
    for spread in spreads:
        cap, views = _capture(spread)
        d = cfg.scan_step_px
        shape = (views.shape[2] * d, views.shape[3] * d)
        variation = _wrap(spread).block_variation((4, 4))
        grid = np.asarray(cap.field_zernike)
        for b in split_blocks(shape, (4, 4), d, overlap=20, margin=cfg.nnum):
            if b.index not in blocks:
                continue
            truth = grid[b.index][:45]
            row = {"case": "dao", "spread": spread, "block": list(b.index),
                   "block_variation_waves": float(variation[b.index]),
                   "true_rms_waves": zernike_rms(truth, MODES),
                   "from_zero": _dao(views, cfg, b, truth, None, max_iter)}
            if spread in truth_starts:
                row["from_truth"] = _dao(views, cfg, b, truth, truth, max_iter)
            rows.append(row)
            print(row, flush=True)
    return rows


def oracle_rows(spreads) -> list[dict]:
    import metasensor as ms
    from metasensor.metrics import ssim
    from metasensor.scenarios.measure import field_resolution

    rows = []
    for spread in spreads:
        cap, views = _capture(spread)
        truth = cap.truth
        rng = float(truth.max() - truth.min())
        row = {"case": "oracle", "spread": spread}
        images = {"2D sensor": cap.sensor2d}
        for name, sv in (("true per-block banks", False), ("true, space-variant", True)):
            rec = ms.reconstruct(views, cap.config, method="isa", field_zernike=cap.field_zernike,
                                 blocks=(4, 4), space_variant=sv)
            images[name] = np.asarray(rec.image)
        for name, img in images.items():
            m = field_resolution(img, truth, (4, 4))
            row[name] = {"resolved_mean_cpp": float(m.mean()), "resolved_worst_cpp": float(m.min()),
                         "ssim": ssim(truth=truth, image=img, data_range=rng)}
        rows.append(row)
        print(row, flush=True)
    return rows


def run(quick: bool = False) -> list[dict]:
    rows = [fit_row()]
    if quick:
        return rows + dao_rows((0.6, 0.15), [(1, 0)], (0.6,), max_iter=3)
    rows += dao_rows((0.0, 0.1, 0.15, 0.3, 0.6), [(0, 0), (1, 0), (1, 1)], (0.15, 0.6))
    return rows + oracle_rows((0.6, 0.15, 0.1))


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    import json

    print(json.dumps(run(quick="--quick" in sys.argv), indent=1, default=float))
