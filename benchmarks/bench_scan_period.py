"""Scan-period study (the paper's Extended Data Fig. 2): ISA quality for scan 1, 3, 5 and 15.

For each scene (the built-in chart and a natural image) the simulator captures the same field at
SNR 30 dB with scan periods 1 (a plain light-field camera), 3, 5 and 15; ISA reconstructs each
with the library's PSFs (each solver's defaults); SSIM (skimage, data_range of the truth)
and PSNR against ``cap.truth``. Writes the table (rows) and a plot
``benchmarks/results/scan_period.png``. Expected: SSIM(1) < SSIM(3) < SSIM(5) and
SSIM(15) − SSIM(5) < 0.02.

``truth_scale``: Σ views_clean / Σ A(truth) on the centre view; the contract (simulate docs) is
V = H ⊛ truth, i.e. 1. Were it not, the table says so and compares against truth × that factor.

Three noise budgets (``budget``): ``per-frame`` — every frame at SNR 30 dB, so a 15x15 scan collects
9x the light of a 5x5 one; ``equal-light`` — the same total light for every period (the per-frame
SNR is 30 dB − 10·log10(p²/25): 44.0 / 34.4 / 30 / 20.5 dB for p = 1 / 3 / 5 / 15), which isolates
what the sampling density itself adds; ``noise-free`` — no photon or read noise (quantised only),
the sampling alone (Extended Data Fig. 2 names no noise level).

Two ISA solvers (``solver``): ``rl``, Richardson–Lucy (every period), and ``hqs``, the
sparse-gradient prior (``reconstruct``'s default where it applies: periods 3, 5, 15; a 1x1 scan
would need 225 x 225 systems per frequency).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))

PERIODS = (1, 3, 5, 15)


def truth_scale(cap, bank) -> float:
    """Σ views_clean / Σ S_d(H ⊛ truth) over the interior of the centre view."""
    import torch

    from metasensor.recon.forward import PhaseSpaceOperator, make_geometry

    cfg = cap.config
    c = cfg.center
    d = cfg.scan_step_px
    s = cap.views.shape[-2:]
    g = make_geometry(s, d, bank.shape[-1] // 2)
    op = PhaseSpaceOperator(bank[c, c][None], g, device="cpu")
    dom = np.zeros(g.domain, np.float32)
    oy, ox = g.offset
    dom[oy:oy + s[0] * d, ox:ox + s[1] * d] = cap.truth
    pred = op.forward(torch.from_numpy(dom))[0].numpy()[g.sample_slices()]
    m = max(bank.shape[-1] // 2 // d + 1, 1)
    inner = (slice(m, s[0] - m), slice(m, s[1] - m))
    return float(cap.views_clean[c, c][inner].sum() / max(pred[inner].sum(), 1e-30))


def run(quick: bool = False) -> list[dict]:
    from skimage.metrics import structural_similarity

    import metasensor as ms
    from metasensor.metrics import psnr
    from metasensor.recon.api import reconstruct
    from metasensor.simulation.capture import simulate
    from metasensor.simulation.scenes import natural_image, resolution_chart

    lenslets = 8 if quick else 16
    size = lenslets * 15 + 14  # holds `lenslets` lenslets at every period (margin (p-1)·d <= 14)
    scenes = {"chart": resolution_chart(size), "camera": natural_image("camera", size)}
    if quick:
        scenes.pop("camera")
    rows = []
    budgets = ("per-frame",) if quick else ("per-frame", "equal-light", "noise-free")
    for budget, name, p in [(b, n, p) for b in budgets for n in scenes for p in PERIODS]:
        scene = scenes[name]
        cfg = ms.SystemConfig(scan=p)
        bank = np.asarray(ms.view_psfs(cfg), np.float32)
        snr = {"per-frame": 30.0, "noise-free": None}.get(
            budget, 30.0 - 10.0 * np.log10(p * p / 25.0))
        cap = simulate(scene, cfg, snr_db=None if snr is None else float(snr), seed=0,
                       comparison=False)
        k = truth_scale(cap, bank)
        truth = cap.truth * np.float32(k)
        for solver in ("rl", "hqs") if p > 1 else ("rl",):
            t0 = time.perf_counter()
            rec = reconstruct(cap.views, cfg, psf=bank, solver=solver)
            sec = time.perf_counter() - t0
            dr = float(truth.max() - truth.min())
            shape = "x".join(map(str, cap.views.shape))
            rows.append({"budget": budget, "snr_db": None if snr is None else float(snr),
                         "scene": name, "scan": p,
                         "solver": solver, "views_shape": shape,
                         "ssim": float(structural_similarity(truth, rec.image, data_range=dr)),
                         "psnr_db": float(psnr(rec.image, truth, data_range=dr)),
                         "seconds": sec, "truth_scale": k,
                         **({"iterations": rec.iterations, "subsets": rec.subsets}
                            if solver == "rl" else {"hqs_steps": len(rec.history[0][0])})})
    _plot(rows, HERE / "results" / ("scan_period_quick.png" if quick else "scan_period.png"))
    return rows + _targets(rows)


def _targets(rows: list[dict]) -> list[dict]:
    """Issue 5's targets per budget, scene and solver series. The ``default`` series is what
    ``reconstruct`` runs without a solver: HQS, and Richardson–Lucy for the 1x1 scan."""
    out = []
    for budget, scene in dict.fromkeys((r["budget"], r["scene"]) for r in rows):
        for series in ("rl", "default"):
            ssim = {}
            for r in rows:
                if r["budget"] == budget and r["scene"] == scene and r["solver"] == (
                        "rl" if series == "rl" or r["scan"] == 1 else "hqs"):
                    ssim[r["scan"]] = r["ssim"]
            if all(p in ssim for p in (1, 3, 5)):
                out.append({"summary": "SSIM(1x1) < SSIM(3x3) < SSIM(5x5)", "budget": budget,
                            "scene": scene, "series": series,
                            "holds": bool(ssim[1] < ssim[3] < ssim[5])})
            if 5 in ssim and 15 in ssim:
                gain = ssim[15] - ssim[5]
                out.append({"summary": "SSIM(15x15) - SSIM(5x5) < 0.02", "budget": budget,
                            "scene": scene, "series": series, "value": gain,
                            "holds": bool(gain < 0.02)})
    return out


def _plot(rows: list[dict], path: Path) -> None:
    from metasensor.io.figures import new_figure, save_figure

    fig, axes = new_figure(size=(5, 3.6))
    ax = axes[0, 0]
    keys = dict.fromkeys((r["budget"], r["scene"], r.get("solver", "rl")) for r in rows)
    for budget, scene, solver in keys:
        sel = [r for r in rows if r["scene"] == scene and r["budget"] == budget
               and r.get("solver", "rl") == solver]
        ax.plot([r["scan"] for r in sel], [r["ssim"] for r in sel],
                {"per-frame": "o", "equal-light": "s"}.get(budget, "^")
                + ("-" if solver == "rl" else ":"),
                label=f"{scene}, {budget}, {solver}")
    ax.set_xscale("log")
    ax.set_xticks(PERIODS, [f"{p}x{p}" for p in PERIODS])
    ax.set_xlabel("scan period")
    ax.set_ylabel("SSIM to truth")
    ax.set_title("ISA vs scan period (30 dB per frame, equal light, noise-free)", fontsize=9)
    ax.legend(fontsize=6)
    save_figure(fig, path, dpi=120)


if __name__ == "__main__":
    for row in run(quick="--quick" in sys.argv):
        print(row)
