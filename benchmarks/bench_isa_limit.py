"""What a scanning light-field capture can resolve: the information limit of ISA vs SNR.

Two studies with the library's PSF bank (5x5 scan, 113 views, aberration-free):

1. Spectrum of the measurement (:class:`metasensor.phasespace.normal.FoldedNormal`): per view
   frequency the d² eigenvalues of AᵀA (squared singular values). Rows per scan period: the
   fraction of directions below 1e-6 / 1e-4 / 1e-2 of the largest, and the null directions per
   frequency (a 1x1 scan has more aliases, 225, than views, 113).
2. SSIM vs SNR on data that follow the model exactly (circular domain, ``y = A·truth`` plus white
   Gaussian noise at the simulator's SNR definition Σc²/noise power): the best Tikhonov solution
   over a grid of λ and two regularisers (identity, first differences) — the best any linear
   reconstruction achieves, chosen with the truth — and Richardson–Lucy ISA (its own defaults;
   not ``reconstruct``'s default solver, HQS) on the same data. Scenes: the built-in chart and
   the natural image, 180 x 180 px.

Writes ``benchmarks/results/isa_limit.png``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))
sys.path.insert(0, str(HERE))  # _paths: where figures go

from _paths import output_path  # noqa: E402

SNRS = (20.0, 30.0, 40.0, 50.0, 60.0, None)
LAMS = (1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 3e-2, 0.1, 0.3)


def _spectrum_rows(quick: bool) -> list[dict]:
    import metasensor as ms
    from metasensor.phasespace.normal import FoldedNormal
    from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry

    rows = []
    for scan in (1, 3, 5) if quick else (1, 3, 5, 15):
        cfg = ms.SystemConfig(scan=scan)
        psf = np.asarray(ms.view_psfs(cfg), np.float32)[cfg.view_mask()]
        d = cfg.scan_step_px
        side = max(4, -(-psf.shape[-1] // d))
        g = make_geometry((side * 2, side * 2), d, psf.shape[-1] // 2, pad=False)
        nm = FoldedNormal(PhaseSpaceOperator(psf, g, device="cpu"))
        ev = nm.eigenvalues()
        ev = (ev / ev.max()).numpy()
        rows.append({"study": "spectrum", "scan": scan, "aliases": d * d, "views": len(psf),
                     "below_1e-6": float((ev < 1e-6).mean()),
                     "below_1e-4": float((ev < 1e-4).mean()),
                     "below_1e-2": float((ev < 1e-2).mean()),
                     "null_per_freq_max": int((ev < 1e-6).sum(-1).max()),
                     "median_eig": float(np.median(ev))})
    return rows


def _noisy(y, snr, seed):
    import torch

    if snr is None:
        return y
    gen = torch.Generator().manual_seed(seed)
    sigma = float(torch.sqrt((y**2).mean() / 10 ** (snr / 10)))
    return y + sigma * torch.randn(y.shape, generator=gen)


def _quality_rows(quick: bool) -> list[dict]:
    import torch
    from skimage.metrics import structural_similarity

    import metasensor as ms
    from metasensor.phasespace.normal import FoldedNormal
    from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
    from metasensor.simulation.scenes import natural_image, resolution_chart
    from metasensor.solvers.richardson_lucy import richardson_lucy
    from metasensor.solvers.tikhonov import tikhonov

    cfg = ms.SystemConfig()
    psf = np.asarray(ms.view_psfs(cfg), np.float32)[cfg.view_mask()]
    side = 40 if quick else 60
    g = make_geometry((side, side), cfg.scan_step_px, psf.shape[-1] // 2, pad=False)
    op = PhaseSpaceOperator(psf, g, device="cpu")
    nm = FoldedNormal(op)
    n = side * cfg.scan_step_px
    scenes = {"chart": resolution_chart(n), "camera": natural_image("camera", n)}
    full = torch.ones(g.grid, dtype=torch.bool)
    rows = []
    for name, scene in scenes.items():
        truth = torch.from_numpy(np.asarray(scene, np.float32))
        dr = float(truth.max() - truth.min())
        clean = op.forward(truth)
        for snr in SNRS[1::2] if quick else SNRS:
            y = _noisy(clean, snr, seed=0)
            best = (-1.0, None, None)
            for smooth in (False, True):
                for lam in LAMS:
                    x = tikhonov(nm, y, full, lam, smooth=smooth).numpy()
                    s = float(structural_similarity(truth.numpy(), x, data_range=dr))
                    if s > best[0]:
                        best = (s, lam, "differences" if smooth else "identity")
            rl = richardson_lucy(op, torch.clamp(y, min=0), full).estimate.numpy()
            rows.append({"study": "ssim_vs_snr", "scene": name, "snr_db": snr,
                         "tikhonov_best_ssim": best[0], "tikhonov_lam": best[1],
                         "tikhonov_reg": best[2],
                         "rl_ssim": float(structural_similarity(truth.numpy(), rl,
                                                                data_range=dr))})
    return rows


def run(quick: bool = False) -> list[dict]:
    rows = _spectrum_rows(quick) + _quality_rows(quick)
    _plot(rows, output_path("isa_limit_quick.png" if quick else "isa_limit.png"))
    return rows


def _plot(rows: list[dict], path: Path) -> None:
    from metasensor.io.figures import new_figure, save_figure

    fig, axes = new_figure(size=(5.5, 3.8))
    ax = axes[0, 0]
    q = [r for r in rows if r["study"] == "ssim_vs_snr"]
    for scene in dict.fromkeys(r["scene"] for r in q):
        sel = [r for r in q if r["scene"] == scene]
        xs = [r["snr_db"] if r["snr_db"] is not None else 70.0 for r in sel]
        ax.plot(xs, [r["tikhonov_best_ssim"] for r in sel], "o-", label=f"{scene}: best linear")
        ax.plot(xs, [r["rl_ssim"] for r in sel], "s--", label=f"{scene}: ISA (Richardson–Lucy)")
    ax.axhline(0.9, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("SNR of the views [dB] (70 = noise-free)")
    ax.set_ylabel("SSIM to truth")
    ax.set_title("Information limit of a 5x5 scan (aberration-free)")
    ax.legend(fontsize=7)
    save_figure(fig, path, dpi=120)


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    for row in run(quick="--quick" in sys.argv):
        print(row)
