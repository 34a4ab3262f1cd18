"""ISA speed (phase-space Richardson–Lucy, and the default sparse-gradient solver ``solvers.hqs``):
wall time vs the time of the FFTs it needs.

Full mode (the issue): 2,010 x 2,010-pixel output (134 x 134 lenslets, nnum 15, 5x5 scan, d = 3),
113 views, 5 iterations, one block. Two FFT references, timed in the same run at the same sizes
on the same device:
- ``fft_own_s``: exactly the FFT calls our iteration makes (per subset one full rfft2 + irfft2; per
  view the small transforms of the folded spectra: an inverse FFT along y of (My, Nx/2+1), an
  inverse real FFT along x of (My, Nx), and a small FFT2 (My, Mx));
- ``fft_conventional_s``: what a per-view full-size FFT convolution needs (the authors' way, on
  views up-sampled to the image grid): per view one inverse and one forward full-size real FFT per
  iteration (+ the per-subset pair).
Ratios ``wall / fft``. Variants: the default ordered subsets (16) at full size; simultaneous (1),
16 and sequential (113 subsets) at the quick size (300 px; the sequential variant's 113 per-view
normalisers would take 1.9 GB at full size).

Quality per iteration (rows with ``ssim_per_iter``): simulated 180 x 180 px chart and camera at
SNR 30 dB (simulate + view_psfs), SSIM to the truth after each iteration for the simultaneous
(1), ordered-subset (4, 16) and sequential (113) variants, with the seconds per iteration.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))


def psf_bank(cfg):
    """The library's PSF bank (an import error is an error, never a stand-in model)."""
    from metasensor.optics.psf import view_psfs

    return np.asarray(view_psfs(cfg), np.float32), "view_psfs"


def _problem(lenslets: int, device):
    from metasensor.config import SystemConfig
    from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
    from metasensor.phasespace.views import view_order

    cfg = SystemConfig()
    bank, source = psf_bank(cfg)
    uv = view_order(cfg.view_mask(), "spiral")
    psf = np.stack([bank[u, v] for u, v in uv])
    d = cfg.scan_step_px
    s = lenslets * cfg.scan
    geom = make_geometry((s, s), d, psf.shape[-1] // 2)
    t0 = time.perf_counter()
    op = PhaseSpaceOperator(psf, geom, device=device)
    otf_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    from scipy.ndimage import gaussian_filter

    img = gaussian_filter(rng.random(geom.domain).astype(np.float32), 2.0) + 0.1
    data = op.forward(torch.from_numpy(img).to(op.device))
    mask = torch.zeros(geom.grid, dtype=torch.bool, device=op.device)
    sy, sx = geom.sample_slices()
    mask[sy, sx] = True
    data = data * mask
    return op, data, mask, otf_s, source, psf


def _sync(device):
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize()


def _fft_times(op, n_subsets: int, iterations: int) -> tuple[float, float]:
    """Seconds of (our FFT calls, a conventional per-view full-size FFT convolution's calls) for
    ``iterations`` iterations (one iteration timed, times ``iterations``: every iteration makes
    the same calls)."""
    dev = op.device
    ny, nx = op.geometry.domain
    my, mx = op.geometry.grid
    nh = nx // 2 + 1
    img = torch.rand((ny, nx), device=dev)
    spec = torch.fft.rfft2(img)
    ch = op.chunk
    half = torch.rand((ch, my, nh), device=dev, dtype=torch.complex64)
    small = torch.rand((ch, my, mx), device=dev)
    nv = op.n_views
    _sync(dev)
    t0 = time.perf_counter()
    for _ in range(1):
        for _ in range(n_subsets):
            torch.fft.rfft2(img)
            torch.fft.irfft2(spec, s=(ny, nx))
        for start in range(0, nv, ch):
            c = min(ch, nv - start)
            rows = torch.fft.ifft(half[:c], dim=-2)
            torch.fft.irfft(rows, n=nx, dim=-1)
            torch.fft.fft2(small[:c])
    _sync(dev)
    own = (time.perf_counter() - t0) * iterations
    t0 = time.perf_counter()
    for _ in range(1):
        for _ in range(n_subsets):
            torch.fft.rfft2(img)
            torch.fft.irfft2(spec, s=(ny, nx))
        for _ in range(nv):
            torch.fft.irfft2(spec, s=(ny, nx))
            torch.fft.rfft2(img)
    _sync(dev)
    conventional = (time.perf_counter() - t0) * iterations
    return own, conventional


def _speed_rows(lenslets: int, iterations: int, variants, device) -> list[dict]:
    from metasensor.solvers.richardson_lucy import RLOptions, richardson_lucy

    op, data, mask, otf_s, source, _ = _problem(lenslets, device)
    rows = []
    for subsets in variants:
        _sync(op.device)
        t0 = time.perf_counter()
        richardson_lucy(op, data, mask, RLOptions(iterations=iterations, subsets=subsets))
        _sync(op.device)
        wall = time.perf_counter() - t0
        own, conv = _fft_times(op, subsets, iterations)
        rows.append({"output_px": lenslets * 15, "views": op.n_views, "subsets": subsets,
                     "iterations": iterations, "domain": op.geometry.domain[0], "psf": source,
                     "device": str(op.device), "otf_setup_s": otf_s, "wall_s": wall,
                     "s_per_iter": wall / max(iterations, 1), "fft_own_s": own,
                     "ratio_own": wall / own, "fft_conventional_s": conv,
                     "ratio_conventional": wall / conv})
    return rows


def _hqs_row(lenslets: int, device) -> dict:
    """The default solver (solvers.hqs) on the same problem: wall time, the RL wall time of the
    same run (5 iterations, 16 subsets), and the FFTs it needs: its forward/adjoint calls (each
    half of an RL iteration's simultaneous FFTs), its folded-normal solves and applies (a complex
    FFT2 pair of the domain each), the margin bands' forward/adjoint pairs
    (:mod:`metasensor.phasespace.masked_normal`: an RL iteration's FFTs on each band's domain),
    and the
    folded normal's build (one complex FFT2 of the domain per view)."""
    from metasensor.phasespace.masked_normal import BandNormal
    from metasensor.phasespace.normal import FoldedNormal
    from metasensor.solvers import hqs
    from metasensor.solvers.richardson_lucy import RLOptions, richardson_lucy

    op, data, mask, _, source, psf = _problem(lenslets, device)
    counts = {"forward": 0, "adjoint": 0, "solve": 0, "apply": 0, "band_normal": 0}
    orig = {"forward": op.forward, "adjoint": op.adjoint, "solve": FoldedNormal.solve,
            "apply": FoldedNormal.apply, "band_normal": BandNormal.__call__}
    band_ops = []

    def counted(name, fn):
        def wrapper(*a, **k):
            counts[name] += 1
            if name == "band_normal" and not band_ops:
                band_ops.extend(b.op for b in a[0].bands)
            return fn(*a, **k)
        return wrapper

    op.forward, op.adjoint = counted("forward", op.forward), counted("adjoint", op.adjoint)
    for name, owner in (("solve", FoldedNormal), ("apply", FoldedNormal),
                        ("band_normal", BandNormal)):
        setattr(owner, "__call__" if name == "band_normal" else name, counted(name, orig[name]))
    try:
        _sync(op.device)
        t0 = time.perf_counter()
        hqs.hqs(op, data, mask, hqs.HQSOptions(noise=1e-3 * float(data.std())))
        _sync(op.device)
        wall = time.perf_counter() - t0
    finally:
        FoldedNormal.solve, FoldedNormal.apply = orig["solve"], orig["apply"]
        BandNormal.__call__ = orig["band_normal"]
        op.forward, op.adjoint = orig["forward"], orig["adjoint"]
    t0 = time.perf_counter()
    richardson_lucy(op, data, mask, RLOptions(iterations=5, subsets=16))
    _sync(op.device)
    rl_wall = time.perf_counter() - t0
    pair, _ = _fft_times(op, 1, 1)
    ny, nx = op.geometry.domain
    z = torch.rand((ny, nx), device=op.device, dtype=torch.complex64)
    _sync(op.device)
    t0 = time.perf_counter()
    for _ in range(4):
        torch.fft.ifft2(torch.fft.fft2(z))
    _sync(op.device)
    solve_fft = (time.perf_counter() - t0) / 4
    band_pair = sum(_fft_times(b, 1, 1)[0] for b in band_ops)
    fft = (0.5 * (counts["forward"] + counts["adjoint"]) * pair
           + (counts["solve"] + counts["apply"]) * solve_fft
           + counts["band_normal"] * band_pair + op.n_views * solve_fft / 2)
    return {"solver": "hqs", "output_px": lenslets * 15, "views": op.n_views,
            "domain": ny, "psf": source, "device": str(op.device), "wall_s": wall,
            "rl_5it_wall_s": rl_wall, "ratio_to_rl": wall / rl_wall, **counts,
            "fft_needed_s": fft, "ratio_fft": wall / fft}


def _quality_rows(iterations: int) -> list[dict]:
    import importlib.util

    from skimage.metrics import structural_similarity

    import metasensor as ms
    from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
    from metasensor.phasespace.views import subset_major, view_order
    from metasensor.simulation.capture import simulate
    from metasensor.simulation.scenes import natural_image, resolution_chart
    from metasensor.solvers.richardson_lucy import RLOptions, richardson_lucy

    spec = importlib.util.spec_from_file_location("bsp", HERE / "bench_scan_period.py")
    bsp = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bsp)
    cfg = ms.SystemConfig()
    bank = np.asarray(ms.view_psfs(cfg), np.float32)
    size = 12 * 15 + 12
    rows = []
    scenes = (("chart", resolution_chart(size)), ("camera", natural_image("camera", size)))
    for name, scene in scenes:
        cap = simulate(scene, cfg, snr_db=30.0, seed=0, comparison=False)
        truth = cap.truth * np.float32(bsp.truth_scale(cap, bank))
        dr = float(truth.max() - truth.min())
        s = cap.views.shape[-1]
        for subsets in (1, 4, 16, 113):
            uv = subset_major(view_order(cfg.view_mask(), "spiral"), subsets)
            g = make_geometry((s, s), cfg.scan_step_px, bank.shape[-1] // 2)
            op = PhaseSpaceOperator(np.stack([bank[u, v] for u, v in uv]), g)
            data = torch.zeros((len(uv), *g.grid), device=op.device)
            mask = torch.zeros(g.grid, dtype=torch.bool, device=op.device)
            sy, sx = g.sample_slices()
            data[:, sy, sx] = torch.from_numpy(np.stack([cap.views[u, v] for u, v in uv]))
            mask[sy, sx] = True
            curve = []
            t0 = time.perf_counter()
            est = None
            elapsed = 0.0
            for _ in range(iterations):
                t1 = time.perf_counter()
                est = richardson_lucy(op, data, mask, RLOptions(iterations=1, subsets=subsets),
                                      init=est).estimate
                elapsed += time.perf_counter() - t1
                img = g.crop(est).cpu().numpy()
                curve.append(round(float(structural_similarity(truth, img, data_range=dr)), 4))
            rows.append({"scene": name, "subsets": subsets, "iterations": iterations,
                         "s_per_iter": elapsed / iterations, "ssim_per_iter": curve,
                         "best_ssim": max(curve), "best_at": int(np.argmax(curve)) + 1,
                         "wall_s": time.perf_counter() - t0})
    return rows


def _edge_rows() -> list[dict]:
    """Edges: the padded estimate domain (linear convolution, unobserved margins estimated) vs
    the unpadded, circular one; PSNR/SSIM in the outer 15-px band of the field and inside it."""
    import importlib.util

    from skimage.metrics import structural_similarity

    import metasensor as ms
    from metasensor.recon.api import reconstruct
    from metasensor.simulation.capture import simulate
    from metasensor.simulation.scenes import natural_image

    spec = importlib.util.spec_from_file_location("bsp", HERE / "bench_scan_period.py")
    bsp = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bsp)
    cfg = ms.SystemConfig()
    bank = np.asarray(ms.view_psfs(cfg), np.float32)
    cap = simulate(natural_image("camera", 12 * 15 + 12), cfg, snr_db=30.0, seed=0,
                   comparison=False)
    truth = cap.truth * np.float32(bsp.truth_scale(cap, bank))
    dr = float(truth.max() - truth.min())
    band = np.ones(truth.shape, bool)
    band[15:-15, 15:-15] = False
    rows = []
    for solver, pad in (("rl", True), ("rl", False), ("hqs", True), ("hqs", False)):
        img = reconstruct(cap.views, cfg, psf=bank, pad=pad, solver=solver).image
        _, smap = structural_similarity(truth, img, data_range=dr, full=True)
        err = (img.astype(np.float64) - truth) ** 2
        rows.append({"edges": "padded" if pad else "circular", "solver": solver,
                     "psnr_band_db": float(10 * np.log10(dr**2 / err[band].mean())),
                     "psnr_inner_db": float(10 * np.log10(dr**2 / err[~band].mean())),
                     "ssim_band": float(smap[band].mean()),
                     "ssim_inner": float(smap[~band].mean())})
    return rows


def run(quick: bool = False) -> list[dict]:
    from metasensor.backend import resolve_device

    device = str(resolve_device(None))
    rows = _speed_rows(20, 2, (1, 16, 113), device)
    rows.append(_hqs_row(20, device))
    if not quick:
        rows += _speed_rows(134, 5, (16,), device)
        rows.append(_hqs_row(134, device))
        rows += _quality_rows(10)
        rows += _edge_rows()
    return rows


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    for row in run(quick="--quick" in sys.argv):
        print(row)
