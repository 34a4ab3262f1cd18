"""ISA (phase-space Richardson–Lucy) speed: wall time vs the time of the FFTs it needs.

Full mode (the issue): 2,010 x 2,010-pixel output (134 x 134 lenslets, nnum 15, 5x5 scan, d = 3),
113 views, 5 iterations, one block. Two FFT references, timed in the same run at the same sizes
on the same device:
- ``fft_own_s``: exactly the FFT calls our iteration makes (per subset one full rfft2 + irfft2; per
  view the small transforms of the folded spectra: an inverse FFT along y of (My, Nx/2+1), an
  inverse real FFT along x of (My, Nx), and a small FFT2 (My, Mx));
- ``fft_conventional_s``: what a per-view full-size FFT convolution needs (the authors' way, on
  views up-sampled to the image grid): per view one inverse and one forward full-size real FFT per
  iteration (+ the per-subset pair).
Ratios ``wall / fft``. Variants: simultaneous (1 subset) and the default ordered subsets;
the sequential per-view variant (113 subsets) is measured at the quick size (its 113 per-view
normalisers would take 1.9 GB at full size).
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
    """The library's PSF bank, or (before the optics stage lands) the tests' stand-in model."""
    try:
        from metasensor.optics.psf import view_psfs

        return np.asarray(view_psfs(cfg), np.float32), "view_psfs"
    except ImportError:
        sys.path.insert(0, str(HERE.parent / "tests" / "recon"))
        from recon_standin import standin_psfs

        return standin_psfs(nnum=cfg.nnum), "standin"


def _problem(lenslets: int, device):
    from metasensor.config import SystemConfig
    from metasensor.recon.forward import PhaseSpaceOperator, make_geometry
    from metasensor.recon.isa import view_order

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
    return op, data, mask, otf_s, source


def _sync(device):
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize()


def _fft_times(op, n_subsets: int, iterations: int) -> tuple[float, float]:
    """Seconds of (our FFT calls, a conventional per-view full-size FFT convolution's calls)."""
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
    for _ in range(iterations):
        for _ in range(n_subsets):
            torch.fft.rfft2(img)
            torch.fft.irfft2(spec, s=(ny, nx))
        for start in range(0, nv, ch):
            c = min(ch, nv - start)
            rows = torch.fft.ifft(half[:c], dim=-2)
            torch.fft.irfft(rows, n=nx, dim=-1)
            torch.fft.fft2(small[:c])
    _sync(dev)
    own = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(iterations):
        for _ in range(n_subsets):
            torch.fft.rfft2(img)
            torch.fft.irfft2(spec, s=(ny, nx))
        for _ in range(nv):
            torch.fft.irfft2(spec, s=(ny, nx))
            torch.fft.rfft2(img)
    _sync(dev)
    conventional = time.perf_counter() - t0
    return own, conventional


def _speed_rows(lenslets: int, iterations: int, variants, device) -> list[dict]:
    from metasensor.recon.isa import richardson_lucy

    op, data, mask, otf_s, source = _problem(lenslets, device)
    rows = []
    for subsets in variants:
        _sync(op.device)
        t0 = time.perf_counter()
        richardson_lucy(op, data, mask, iterations=iterations, subsets=subsets)
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


def run(quick: bool = False) -> list[dict]:
    from metasensor.backend import resolve_device

    device = str(resolve_device(None))
    rows = _speed_rows(20, 2, (1, 8, 113), device)
    if not quick:
        rows += _speed_rows(134, 5, (1, 8), device)
    return rows


if __name__ == "__main__":
    for row in run(quick="--quick" in sys.argv):
        print(row)
