"""One wave-DAO iteration on a block: seconds, and the ratio to the FFTs it needs (same run).

One iteration = the intermediate image, the forward prediction of every view and the sub-pixel
shift measurement (:class:`metasensor.dao.block.DaoBlock`), for both estimators of the
image: "isa" (the default: the block's phase-space Richardson–Lucy, 5 iterations, 16 subsets; its
FFT reference counts 5 per-view full-size convolution pairs, as a conventional ISA needs them)
and "views" (the paper's: Krishnan–Fergus deconvolution of every used view, 113 for the
prototype, on the pixel grid, and their signal-weighted mean; "isa" makes one iteration per
update, "views" three). PSF regeneration
(``view_psfs``, the optics stage, once per update) is timed separately. The FFT
reference times the real FFTs of the same sizes and counts on the same device ("views": per view 6 β
steps × (2 forward + 1 inverse) + 1 for the data, 1 inverse for the prediction, 1 inverse for
the known-region weights of the prediction, and the correlation's complex FFTs; "isa": the same
without the β steps and the data spectrum). Not timed: the
shift precisions that weight the Zernike fit (once per update: one
real FFT pair per view on the scan-step grid, 1/9 of the pixel grid's area for a 5×5 scan).

The PSFs are those of a 1 λ r.m.s. random aberration (modes 4–45, seed 0), on two windows: the
DAO default (``psf_size="auto"``, :func:`metasensor.dao.estimate.psf_window`: ray reach over the
used views + one lenslet + 10 λ/NA) and ``view_psfs``' default (99.5 % of all views' light,
K = 413 here). Accuracy of the two windows: ``run_dao`` (3 updates) on a simulated 1 λ capture
(the simulator's own full-window, 3×-subsampled PSFs), residual r.m.s. of modes 4–45.
Full mode: a 2,000 × 2,000-pixel block (the issue's figure; auto window only) and the accuracy
rows (camera, 255 × 255 px); quick: 300 × 300, timing only.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))


def _fft_reference(n_views: int, grid: tuple[int, int], view: tuple[int, int], betas: int,
                   device, isa_iterations: int = 0) -> float:
    """Seconds of the FFTs one iteration needs: per view, ``betas`` Krishnan–Fergus steps and the
    data spectrum (the "views" estimator; betas = 0: none), ``isa_iterations`` forward/adjoint
    pairs of a per-view full-size convolution (the "isa" estimator, counted as a conventional ISA
    needs them), then the prediction, the known-region weights and the correlation."""
    import torch

    x = torch.randn((min(n_views, 16), *grid), device=device)
    v = torch.randn((min(n_views, 16), *view), device=device)
    reps = int(np.ceil(n_views / x.shape[0]))
    t0 = time.perf_counter()
    for _ in range(reps):
        for _ in range(betas):
            s = torch.fft.rfft2(x)
            s2 = torch.fft.rfft2(x)
            x = torch.fft.irfft2(s + s2, s=grid)
        if betas:
            torch.fft.rfft2(x)  # data spectrum
        for _ in range(isa_iterations):
            x = torch.fft.irfft2(torch.fft.rfft2(x), s=grid)
        s = torch.fft.rfft2(x)
        torch.fft.irfft2(s, s=grid)  # prediction
        torch.fft.irfft2(s, s=grid)  # known-region weights of the prediction
        for _ in range(3):  # correlation: two forward, one inverse complex FFT
            torch.fft.fft2(v)
    if device.type == "cuda":
        torch.cuda.synchronize()
    return time.perf_counter() - t0


def _iteration(cfg, bank, size: int, dev, rng, estimator: str = "views") -> dict:
    import torch
    from scipy.ndimage import gaussian_filter

    from metasensor.dao.block import DaoBlock
    from metasensor.solvers.splitting import beta_schedule

    d = cfg.scan_step_px
    h = size // d
    used = cfg.view_mask()
    views = np.stack([gaussian_filter(rng.random((h, h)), 2).astype(np.float32)
                      for _ in range(int(used.sum()))])
    tv = torch.as_tensor(views, device=dev)
    del views
    blk = DaoBlock(tv, cfg, used, 5e4, 16)
    t0 = time.perf_counter()
    blk.set_psfs(bank)
    if estimator == "isa":
        image = blk.estimate_isa()
    else:
        image = blk.estimate(torch.zeros((tv.shape[0], 2), device=dev))
    if dev.type == "cuda":
        torch.cuda.synchronize()
    t_est = time.perf_counter() - t0
    t0 = time.perf_counter()
    blk.measure(image, 50.0)
    if dev.type == "cuda":
        torch.cuda.synchronize()
    t_meas = time.perf_counter() - t0
    total = t_est + t_meas
    if estimator == "isa":
        t_fft = _fft_reference(tv.shape[0], blk.shape, (h, h), 0, dev, isa_iterations=5)
    else:
        t_fft = _fft_reference(tv.shape[0], blk.shape, (h, h), len(beta_schedule()), dev)
    return {"estimator": estimator, "block_px": size, "views": int(used.sum()),
            "device": dev.type,
            "bank_K": int(bank.shape[-1]), "kernel_K": int(blk.kernels.shape[-1]),
            "fft_grid": list(blk.shape), "chunk": blk.chunk, "cached_spectra": blk.otf is not None,
            "estimate_s": t_est, "shift_measure_s": t_meas, "iteration_s": total,
            "fft_s": t_fft, "ratio_to_fft": total / t_fft, "threads": torch.get_num_threads()}


def _accuracy(cfg, z, windows) -> list[dict]:
    import metasensor as ms
    from metasensor.dao.estimate import run_dao
    from metasensor.dao.wavefront import zernike_rms
    from metasensor.simulation.scenes import load_scene

    cap = ms.simulate(load_scene("camera", 255), cfg, zernike=z, snr_db=30, seed=0,
                      comparison=False)
    rows = []
    for name, size in windows:
        t0 = time.perf_counter()
        res = run_dao(cap.views, cfg, method="wave", max_iter=3, tol=0.0, psf_size=size)
        rows.append({"accuracy": name, "block_px": 255, "updates": len(res.history),
                     "residual_rms": zernike_rms(res.zernike - z),
                     "history": [round(h, 4) for h in res.history], "psf_size": res.psf_size,
                     "dao_s": time.perf_counter() - t0})
    return rows


def run(quick: bool = False) -> list[dict]:
    import metasensor as ms
    from metasensor.backend import resolve_device
    from metasensor.dao.banks import psf_window
    from metasensor.optics.zernike import random_zernike

    cfg = ms.SystemConfig()
    dev = resolve_device(None)
    z = random_zernike(1.0, seed=0)
    windows = [("auto", psf_window(cfg, z))] + ([("view_psfs default", None)] if quick else [])
    rows = []
    for name, k in windows:
        t0 = time.perf_counter()
        bank = ms.view_psfs(cfg, z, size=k, cache=False)
        t_psf = time.perf_counter() - t0
        for estimator in ("isa", "views"):
            row = {"window": name, "view_psfs_s": t_psf}
            row.update(_iteration(cfg, bank, 300 if quick else 2000, dev,
                                  np.random.default_rng(0), estimator))
            rows.append(row)
        del bank
    if not quick:
        rows += _accuracy(cfg, z, [("auto", "auto"), ("view_psfs default", None)])
    return rows


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    for row in run("--quick" in sys.argv):
        print(row)
