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

Two focus positions (``defocus_waves``): ``0`` — the scene on the MLA's conjugate plane, and
``0.25`` — the scene a little off it (Noll Z4 = 0.25 λ r.m.s., 0.36 mm on the image side: 1.7
depths of focus λ/NA²), simulated and reconstructed with that defocus. On the conjugate plane every
view samples the field at the same positions (every scan step d = 15/p px), so what lies beyond
1/(2d) aliases identically in all of them and only the views' PSF shapes tell the aliases apart;
off it, each view sees the scene shifted by its parallax (λ·∂W/∂ρ/NA: 4 px at the pupil's edge
here), a different sampling phase, and the views unmix the aliasing between them (measured: the 5x5
scan's SSIM rises from 0.92 to 0.96 (chart) and 0.76 to 0.78 (camera) at 30 dB, 0.97 to 0.99
and 0.87 to 0.94 noise-free, while 15x15 barely changes).

Two ISA solvers (``solver``): ``rl``, Richardson–Lucy (every period), and ``hqs``, the
sparse-gradient prior (``reconstruct``'s default where it applies: periods 3, 5, 15; a 1x1 scan
would need 225 x 225 systems per frequency).

A third series, ``hqs-pg``, is HQS with ``noise_estimate="auto"`` (``CANDIDATE``: a candidate
default, measured beside the default; ``docs/decisions.md``): the data weight's noise from the
capture's Poisson–Gaussian fit, with the scan factor ``(d / 3)^0.5`` and the misfit gate 0.95,
where the views follow that model; the default's second differences elsewhere (views without
measurable noise).

Subsets of the full run (the same sizes and rows, for a re-run on a busy machine):
``SCAN_PERIOD_BUDGETS=per-frame`` (comma-separated budgets), ``SCAN_PERIOD_FOCUS=0,0.25``
(defocus values among ``DEFOCUS``) and ``SCAN_PERIOD_SOLVERS=hqs-pg`` (series among
``SOLVERS``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))
sys.path.insert(0, str(HERE))  # _paths: where figures go

from _paths import output_path  # noqa: E402

PERIODS = (1, 3, 5, 15)
DEFOCUS = (0.0, 0.25)  # Noll Z4 [waves r.m.s.]: on the MLA's conjugate plane, and off it
SOLVERS = ("rl", "hqs", "hqs-pg")
#: settings of the ``hqs-pg`` series
CANDIDATE = {"noise_estimate": "auto"}


def truth_scale(cap, bank) -> float:
    """Σ views_clean / Σ S_d(H ⊛ truth) over the interior of the centre view."""
    import torch

    from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry

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


def _solvers() -> tuple:
    """``SOLVERS`` narrowed by ``SCAN_PERIOD_SOLVERS``."""
    import os

    env = os.environ.get("SCAN_PERIOD_SOLVERS")
    if not env:
        return SOLVERS
    want = tuple(v.strip() for v in env.split(","))
    bad = [v for v in want if v not in SOLVERS]
    if bad:
        raise ValueError(f"SCAN_PERIOD_SOLVERS: unknown series {bad}; valid: {SOLVERS}")
    return want


def _subset(budgets: tuple, focus: tuple) -> tuple[tuple, tuple]:
    """``budgets`` and ``focus`` narrowed by ``SCAN_PERIOD_BUDGETS`` / ``SCAN_PERIOD_FOCUS``."""
    import os

    env_b, env_f = os.environ.get("SCAN_PERIOD_BUDGETS"), os.environ.get("SCAN_PERIOD_FOCUS")
    if env_b:
        want = [b.strip() for b in env_b.split(",")]
        bad = [b for b in want if b not in budgets]
        if bad:
            raise ValueError(f"SCAN_PERIOD_BUDGETS: unknown budget(s) {bad}; valid: {budgets}")
        budgets = tuple(want)
    if env_f:
        want_f = [float(v) for v in env_f.split(",")]
        bad_f = [v for v in want_f if v not in focus]
        if bad_f:
            raise ValueError(f"SCAN_PERIOD_FOCUS: unknown defocus {bad_f}; valid: {focus}")
        focus = tuple(want_f)
    return budgets, focus


def run(quick: bool = False) -> list[dict]:
    from skimage.metrics import structural_similarity

    import metasensor as ms
    from metasensor.metrics import psnr
    from metasensor.recon.api import reconstruct
    from metasensor.simulation.capture import simulate
    from metasensor.simulation.scenes import natural_image, resolution_chart
    from metasensor.solvers.hqs import HQSOptions

    lenslets = 8 if quick else 16
    size = lenslets * 15 + 14  # holds `lenslets` lenslets at every period (margin (p-1)·d <= 14)
    scenes = {"chart": resolution_chart(size), "camera": natural_image("camera", size)}
    if quick:
        scenes.pop("camera")
    rows = []
    budgets = ("per-frame",) if quick else ("per-frame", "equal-light", "noise-free")
    focus = DEFOCUS[:1] if quick else DEFOCUS
    budgets, focus = _subset(budgets, focus)
    for df, budget, name, p in [(f, b, n, p) for f in focus for b in budgets for n in scenes
                                for p in PERIODS]:
        scene = scenes[name]
        cfg = ms.SystemConfig(scan=p)
        z = np.zeros(4, np.float32)
        z[3] = df
        bank = np.asarray(ms.view_psfs(cfg, zernike=z if df else None), np.float32)
        snr = {"per-frame": 30.0, "noise-free": None}.get(
            budget, 30.0 - 10.0 * np.log10(p * p / 25.0))
        cap = simulate(scene, cfg, zernike=z if df else None,
                       snr_db=None if snr is None else float(snr), seed=0, comparison=False)
        k = truth_scale(cap, bank)
        truth = cap.truth * np.float32(k)
        for solver in [s for s in _solvers() if p > 1 or s == "rl"]:
            t0 = time.perf_counter()
            rec = reconstruct(cap.views, cfg, psf=bank, solver=solver.removesuffix("-pg"),
                              solver_options=HQSOptions(**CANDIDATE) if solver == "hqs-pg"
                              else None)
            sec = time.perf_counter() - t0
            dr = float(truth.max() - truth.min())
            shape = "x".join(map(str, cap.views.shape))
            rows.append({"defocus_waves": df, "budget": budget,
                         "snr_db": None if snr is None else float(snr), "scene": name, "scan": p,
                         "solver": solver, "views_shape": shape,
                         "ssim": float(structural_similarity(truth, rec.image, data_range=dr)),
                         "psnr_db": float(psnr(truth=truth, image=rec.image, data_range=dr)),
                         "seconds": sec, "truth_scale": k,
                         **({"iterations": rec.iterations, "subsets": rec.subsets}
                            if solver == "rl" else {"hqs_steps": len(rec.history[0][0])})})
    _plot(rows, output_path("scan_period_quick.png" if quick else "scan_period.png"))
    return rows + _targets(rows)


def _targets(rows: list[dict]) -> list[dict]:
    """The scan-period targets per focus, budget, scene and solver series. The ``default`` series is
    what ``reconstruct`` runs without a solver: HQS, and Richardson–Lucy for the 1x1 scan."""
    out = []
    for df, budget, scene in dict.fromkeys(
            (r["defocus_waves"], r["budget"], r["scene"]) for r in rows):
        key = {"defocus_waves": df, "budget": budget, "scene": scene}
        for series in ("rl", "default"):
            ssim = {}
            for r in rows:
                if (r["defocus_waves"], r["budget"], r["scene"]) == (df, budget, scene) and \
                        r["solver"] == ("rl" if series == "rl" or r["scan"] == 1 else "hqs"):
                    ssim[r["scan"]] = r["ssim"]
            if all(p in ssim for p in (1, 3, 5)):
                out.append({"summary": "SSIM(1x1) < SSIM(3x3) < SSIM(5x5)", **key,
                            "series": series, "holds": bool(ssim[1] < ssim[3] < ssim[5])})
            if 5 in ssim and 15 in ssim:
                gain = ssim[15] - ssim[5]
                out.append({"summary": "SSIM(15x15) - SSIM(5x5) < 0.02", **key,
                            "series": series, "value": gain, "holds": bool(gain < 0.02)})
    return out


def _plot(rows: list[dict], path: Path) -> None:
    """SSIM against scan period, one panel per focus position."""
    from metasensor.io.figures import new_figure, save_figure

    rows = [r for r in rows if "summary" not in r]
    focus = list(dict.fromkeys(r["defocus_waves"] for r in rows))
    # colour: scene and budget; marker: budget; line: the solver series
    pairs = list(dict.fromkeys((r["scene"], r["budget"]) for r in rows))
    fig, axes = new_figure(1, len(focus), size=(5.5 * len(focus), 4.2))
    for ax, df in zip(axes[0], focus, strict=True):
        mine = [r for r in rows if r["defocus_waves"] == df]
        for budget, scene, solver in dict.fromkeys(
                (r["budget"], r["scene"], r["solver"]) for r in mine):
            sel = sorted((r for r in mine if (r["budget"], r["scene"], r["solver"])
                          == (budget, scene, solver)), key=lambda r: r["scan"])
            ax.plot([r["scan"] for r in sel], [r["ssim"] for r in sel],
                    {"per-frame": "o", "equal-light": "s"}.get(budget, "^")
                    + {"rl": "-", "hqs": ":"}.get(solver, "--"),
                    color=f"C{pairs.index((scene, budget)) % 10}",
                    label=f"{scene}, {budget}, {solver}")
        ax.set_xscale("log")
        ax.set_xticks(PERIODS, [f"{p}x{p}" for p in PERIODS])
        ax.set_xlabel("scan period")
        ax.set_ylabel("SSIM to truth")
        where = "on the MLA's conjugate plane" if df == 0 else f"defocus Z4 = {df:g} λ"
        ax.set_title(f"ISA vs scan period, {where}", fontsize=9)
        ax.legend(fontsize=5, ncol=2)
    save_figure(fig, path, dpi=120)


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    for row in run(quick="--quick" in sys.argv):
        print(row)
