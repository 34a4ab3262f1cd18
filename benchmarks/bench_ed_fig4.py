"""Extended Data Fig. 4: image quality vs aberration strength for five imaging modes.

For every scene, aberration level (r.m.s. waves over Noll modes 4–45, random, seeded) and draw:
simulate a capture (5×5 scan, SNR 30 dB) and compare with the truth
- the conventional 2D sensor (``cap.sensor2d``),
- hardware AO with a 15×15 tip-tilt mirror measuring the wavefront perfectly (``cap.hardware_ao``),
- the meta-imaging sensor with geometric DAO (ideal PSFs translated by the measured shifts),
- the meta-imaging sensor with wave-optics DAO (PSFs regenerated from the estimated pupil),
- ISA with the true aberration (the oracle).
Rows: PSNR, SSIM and (DAO) the residual wavefront r.m.s. and σ = residual / peak-to-valley.
Writes ``benchmarks/results/ed_fig4.png`` and the rows (run_all.py writes the JSON).
Targets (the DAO requirement): wave ≥ geometric + 3 dB at 3 λ; wave within 1.5 dB of the
oracle at 1 λ; wave above the 2D sensor at every level.

PSF windows (the cost driver). ``view_psfs``' default window keeps 99.5 % of the light of all
225 views and is sized by the ray reach at the pupil rim (K = 341-413 at 1 λ, ~900 at 3 λ, whose
3×-subsampled simulation bank would not fit in memory). Here every bank is sized from the ray
reach over the 113 used views (:func:`metasensor.dao.estimate.psf_window`): the reconstructions
(oracle, geometric, wave) use that window, the simulation (3×-subsampled, a different grid) a
window ``SIM_EXTRA`` pixels wider on each side, so the data hold light the models drop, up to
``SIM_MAX`` = 401 px (memory): at 3 λ (reach ≈ 160-190 px) the simulation window is then the
ray reach + 10-20 px, and the data lack the far diffraction tails of the most tilted views.
Full mode: two scenes of 150 × 150 pixels (10 × 10 lenslets; 240 × 240 at 3 λ, ``BIG_BLOCK``),
three draws per level, wave and geometric DAO with at most 3 updates (8 at 3 λ).
``ED_FIG4_LEVELS=0.5,1`` runs a subset of the levels; ``ED_FIG4_CASES=FILE`` keeps the finished
cases in FILE instead of ``results/ed_fig4_cases.jsonl`` (a re-run that measures afresh, leaving
the committed cases alone).
ISA here is the paper's Richardson–Lucy (``solver="rl"``, 5 iterations, 16 subsets) for every
mode, as in the figure; the library's default solver (the sparse-gradient prior) is not used.
"""

from __future__ import annotations

import os
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))
sys.path.insert(0, str(HERE))  # _paths: where figures go

from _paths import output_path  # noqa: E402

LEVELS = (0.5, 1.0, 3.0)
SIM_EXTRA = 20  # pixels per side the simulation's PSF window exceeds the reconstructions'
BIG_BLOCK = 240  # scene size (px) at 3 λ
SIM_MAX = 401  # largest simulation window: its 3×-subsampled bank peaks at ~6 GB of memory


def _pv(z) -> float:
    from metasensor.optics.zernike import wavefront

    t = np.linspace(-1, 1, 129)
    x, y = np.meshgrid(t, t)
    w = wavefront(z, x, y)[(x**2 + y**2) <= 1]
    return float(w.max() - w.min())


def sim_bank(cfg, zernike=None, depth=0.0, phase=None, device=None):
    """The simulator's fine bank (``view_psfs(subsample=3) · 9``, as its default) on a window
    ``SIM_EXTRA`` px per side wider than the reconstructions' :func:`psf_window`."""
    import metasensor as ms
    from metasensor.dao.banks import psf_window

    size = min(psf_window(cfg, zernike) + 2 * SIM_EXTRA, SIM_MAX)
    kw = {} if phase is None else {"phase": phase, "cache": False}
    bank = ms.view_psfs(cfg, zernike, float(depth), subsample=3, size=size, device=device, **kw)
    return np.asarray(bank, dtype=np.float32) * np.float32(9.0)


WIDEFIELD_CAP = 2001  # fine samples (pixel/3): larger 2D-sensor PSFs are computed per pixel


def coarse_fine_widefield(original):
    """Wrap the simulator's ``fine_widefield`` (2D-sensor and hardware-AO PSFs at pixel/3):
    windows wider than ``WIDEFIELD_CAP`` fine samples (the 2D sensor at 3 λ: 4,309 samples,
    whose 19,845² complex128 field exhausts 24 GB) are computed at the pixel pitch on the same
    extent and spread uniformly over each pixel's 3 × 3 fine samples (the PSF integrated per
    pixel; a ~1,400-px blur loses nothing at that scale)."""

    def fine_widefield(cfg, zernike=None, depth=0.0, phase=None, device=None):
        from metasensor.optics.widefield import widefield_psf
        from metasensor.simulation import kernels as kern

        k = kern._widefield_size(cfg, zernike, depth, phase, cfg.pixel_pitch / 3)
        if k <= WIDEFIELD_CAP:
            return original(cfg, zernike, depth, phase=phase, device=device)
        kp = (k // 3) | 1
        kw = {"device": device, "size": kp}
        if phase is not None:
            kw["phase"] = phase
        pix = np.asarray(widefield_psf(cfg, zernike, float(depth), cfg.pixel_pitch, **kw))
        return (np.kron(pix, np.ones((3, 3))) / 9.0).astype(np.float32)

    return fine_widefield


@contextmanager
def coarse_widefield():
    """The simulator's ``fine_widefield`` wrapped by :func:`coarse_fine_widefield` while the
    block runs (restored after it, also on an error)."""
    from metasensor.simulation import kernels as kern

    original = kern.fine_widefield
    kern.fine_widefield = coarse_fine_widefield(original)
    try:
        yield
    finally:
        kern.fine_widefield = original


def one_case(scene_name: str, rms: float, draw: int, size: int, max_iter: int,
             snr_db: float = 30.0, methods=("geometric", "wave")) -> list[dict]:
    """One capture (``snr_db``, aberration ``rms`` draw ``draw``, ``size`` px) and its rows: 2D
    sensor, hardware AO, the oracle ISA and DAO by each of ``methods``."""
    import metasensor as ms
    from metasensor.dao.banks import block_psfs, psf_window
    from metasensor.dao.estimate import run_dao
    from metasensor.dao.wavefront import zernike_rms
    from metasensor.metrics import psnr, ssim
    from metasensor.optics.zernike import random_zernike
    from metasensor.simulation.scenes import load_scene

    cfg = ms.SystemConfig()
    z = random_zernike(rms, seed=draw)
    scene = load_scene(scene_name, size)
    cap = ms.simulate(scene, cfg, zernike=z, snr_db=snr_db, seed=draw, psf=sim_bank)
    k_sim = min(psf_window(cfg, z) + 2 * SIM_EXTRA, SIM_MAX)
    truth = cap.truth
    rng_ = float(truth.max() - truth.min())
    rows = []

    def add(mode, image, extra=None, seconds=None):
        row = {"scene": scene_name, "rms": rms, "draw": draw, "size": size, "snr_db": snr_db,
               "mode": mode,
               "psnr": psnr(truth=truth, image=image, data_range=rng_),
               "ssim": ssim(truth=truth, image=image, data_range=rng_)}
        if seconds is not None:
            row["seconds"] = seconds
        row.update(extra or {})
        rows.append(row)

    add("2d_sensor", cap.sensor2d, {"sim_psf_size": k_sim})
    add("hardware_ao", cap.hardware_ao)
    t0 = time.perf_counter()
    k_true = psf_window(cfg, z)
    oracle = ms.reconstruct(cap.views, cfg, method="isa", psf=ms.view_psfs(cfg, z, size=k_true),
                            solver="rl")
    add("oracle_isa", oracle.image, {"psf_size": k_true}, seconds=time.perf_counter() - t0)
    for method in methods:
        t0 = time.perf_counter()
        res = run_dao(cap.views, cfg, method=method, max_iter=max_iter)
        bank = block_psfs(cfg, res)
        rec = ms.reconstruct(cap.views, cfg, method="isa", psf=bank, solver="rl")
        resid = zernike_rms(res.zernike - z)
        pv = _pv(z)
        add(f"{method}_dao", rec.image, {"residual_rms": resid,
                                         "sigma": resid / pv if pv > 0 else None,
                                         "dao_updates": len(res.history),
                                         "history": [round(h, 4) for h in res.history],
                                         "psf_size": int(bank.shape[-1])},
            seconds=time.perf_counter() - t0)
    return rows


def figure(rows: list[dict], path: Path) -> None:
    from metasensor.io.figures import new_figure, save_figure

    modes = list(dict.fromkeys(r["mode"] for r in rows))
    fig, axes = new_figure(1, 2, size=(10, 4))
    axes = axes[0]
    for ax, key in zip(axes, ("psnr", "ssim"), strict=True):
        for m in modes:
            lv = sorted({r["rms"] for r in rows if r["mode"] == m})
            mean = [np.mean([r[key] for r in rows if r["mode"] == m and r["rms"] == v])
                    for v in lv]
            ax.plot(lv, mean, "o-", label=m)
        ax.set_xlabel("aberration r.m.s. (λ)")
        ax.set_ylabel(key.upper())
        ax.set_xscale("log")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle("Extended Data Fig. 4: DAO vs aberration level (SNR 30 dB)")
    save_figure(fig, path, dpi=120)


def summary(rows: list[dict]) -> list[dict]:
    """Mean per (rms, mode) plus the three target checks."""
    out = []
    levels = sorted({r["rms"] for r in rows})
    modes = list(dict.fromkeys(r["mode"] for r in rows))
    mean = {}
    for v in levels:
        for m in modes:
            sel = [r for r in rows if r["rms"] == v and r["mode"] == m]
            mean[v, m] = float(np.mean([r["psnr"] for r in sel]))
            out.append({"summary": "mean", "rms": v, "mode": m, "psnr": mean[v, m],
                        "ssim": float(np.mean([r["ssim"] for r in sel])), "n": len(sel)})
    if 3.0 in levels:
        gap = mean[3.0, "wave_dao"] - mean[3.0, "geometric_dao"]
        out.append({"summary": "target wave >= geometric + 3 dB at 3 λ", "value": gap,
                    "holds": bool(gap >= 3.0)})
    if 1.0 in levels:
        gap = mean[1.0, "oracle_isa"] - mean[1.0, "wave_dao"]
        out.append({"summary": "target wave within 1.5 dB of oracle at 1 λ", "value": gap,
                    "holds": bool(gap <= 1.5)})
    for v, limit in ((1.0, 0.1), (3.0, 0.3)):  # the DAO requirement: residual wavefront r.m.s.
        res = [r["residual_rms"] for r in rows if r["rms"] == v and r["mode"] == "wave_dao"]
        if res:
            ok = sum(x <= limit for x in res)
            out.append({"summary": f"target wave residual <= {limit} λ at {v:g} λ",
                        "value": float(max(res)), "draws_within": f"{ok} of {len(res)}",
                        "holds": bool(ok == len(res))})
    above = [mean[v, "wave_dao"] - mean[v, "2d_sensor"] for v in levels]
    out.append({"summary": "target wave above 2D sensor at every level", "value": min(above),
                "holds": bool(min(above) > 0)})
    return out


def run(quick: bool = False) -> list[dict]:
    if quick:
        scenes, levels, draws, size = ("camera",), (0.5,), (0,), 120
    else:
        scenes, levels, draws, size = ("camera", "astronaut"), LEVELS, (0, 1, 2), 150
    # 3 λ: rays reach 110-190 px, more than a 150-px block (measured: wave DAO diverged there,
    # residual 3.5 λ), hence 240 px. Measured (2 scenes × 3 draws, 8 updates at most; DAO's
    # default estimator, the block's ISA below 0.5 λ updates): wave DAO 0.083-0.147 λ residual
    # (6 of 6 ≤ 0.3), PSNR 0.00-0.04 dB under the oracle, 4.3-5.5 dB over geometric DAO,
    # 81-155 s per draw; 1 λ: 0.029-0.057 λ in 3 updates. With the paper's estimator only
    # (estimator="views"): 0.12-0.31 λ (5 of 6), 133-410 s, and 0.027-0.056 λ. Before the
    # precision-weighted fit: 0.33-0.93 λ and 0.041-0.120 λ; before the known-region weights,
    # 3 λ draw 0: 1.92 λ
    env = os.environ.get("ED_FIG4_LEVELS")  # e.g. "0.5,1": a subset of the levels
    if env:
        levels = tuple(float(v) for v in env.split(","))
    rows: list[dict] = []
    from tqdm.auto import tqdm

    # scenes innermost: both reuse the (cached) simulation bank of one aberration draw
    cases = [(s, v, d) for v in sorted(levels, reverse=True) for d in draws for s in scenes]
    # every finished case is appended to a JSON-lines file and skipped when the run is repeated
    # (a run of ~45 min on 2 cores); delete the file to start afresh
    import json

    done_file = output_path("ed_fig4_quick_cases.jsonl" if quick else
                            "ed_fig4_cases.jsonl")
    if os.environ.get("ED_FIG4_CASES"):
        done_file = Path(os.environ["ED_FIG4_CASES"])
    done: dict = {}
    if done_file.exists():
        for line in done_file.read_text().splitlines():
            r = json.loads(line)
            done.setdefault((r["scene"], r["rms"], r["draw"], r["size"]), []).append(r)
    with coarse_widefield():
        for s, v, d in tqdm(cases, desc="ED Fig. 4"):
            px = BIG_BLOCK if (v >= 3 and not quick) else size
            if (s, v, d, px) in done:
                rows += done[s, v, d, px]
                continue
            new = one_case(s, v, d, px, (8 if v >= 3 else 3) if not quick else 2)
            done_file.parent.mkdir(parents=True, exist_ok=True)
            with done_file.open("a") as f:
                f.writelines(json.dumps(r) + "\n" for r in new)
            rows += new
    figure(rows, output_path("ed_fig4_quick.png" if quick else "ed_fig4.png"))
    return rows + summary(rows)


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    import json

    quick = "--quick" in sys.argv
    result = run(quick)
    for r in result:
        print(json.dumps(r))
