"""Natural photographs for ``bench_quality``: aberrated (wave DAO) and 0.25 λ off focus.

Six scikit-image photographs (camera, astronaut, coffee, chelsea, rocket, grass), 256-px fields
(240 px of truth), 5 x 5 scan, SNR 30 dB per frame, seed 0. Two studies (``study`` column):

- ``photos-aberrated``: a random aberration of 1 and 3 λ r.m.s. (Noll 4-45, amplitudes falling as
  1/n with the radial order n, seed 0: ``bench_quality.falling_zernike``) over the whole field,
  reconstructed by the default pipeline with wave DAO (``ms.reconstruct(views, cfg,
  method="wave")``: the default ``DaoOptions`` and the default HQS solver, one block). The
  capture is simulated with the ED Fig. 4 benchmark's windows (``bench_ed_fig4.sim_bank`` and
  ``coarse_widefield``: at 3 λ the simulator's default 3x-subsampled bank does not fit in
  memory). Against the same capture's 2D sensor, and the 2D sensor restored with the
  hyper-Laplacian prior (``bench_quality.restore_2d``, lam best of three by the truth) by two
  PSFs: the true aberrated one (``2D+prior (true PSF)``, an oracle the 2D sensor lacks) and the
  widefield PSF of the wavefront the meta-imaging sensor's DAO estimated (``2D+prior (DAO
  PSF)``: the same knowledge). ``residual_rms``: DAO's wavefront error (waves, Noll 4-45).
- ``photos-solver``: the HQS data weight ``lam_scale`` 0.1 / 0.3 (default) / 1 on the chart and
  the photographs, aberration-free, in focus, 166-px fields (a smaller size: a study of the
  setting, not of the acceptance).
- ``photos-focus``: aberration-free, in focus and with the meta-imaging sensor 0.25 λ (Noll Z4)
  off the conjugate plane (``simulate(focus_offset=0.25)``, known to the reconstruction), the
  2D sensor in focus; default reconstruction (``bench_quality.case``).

Targets (issue: reconstruction quality), summarised by :func:`targets`: aberrated, SSIM >= 2D +
0.15, PSNR >= 2D + 5 dB, resolved frequency >= 2 x the 2D sensor's; off focus, SSIM and resolved
frequency at least those in focus.

Run: ``python benchmarks/bench_quality.py --photos [aberrated|focus|solver]`` (one process,
single-threaded). Every finished case is written at once to ``results/quality_photos.json``
and skipped when the run is repeated; ``bench_quality.run`` merges the file's rows.
"""

from __future__ import annotations

import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # _paths: where figures go

from _paths import output_path  # noqa: E402

PHOTOS_JSON = HERE / "results" / "quality_photos.json"
PHOTOS = ("camera", "astronaut", "coffee", "chelsea", "rocket", "grass")
SIZE = 256
ABERRATIONS = (1.0, 3.0)
OFFSETS = (0.0, 0.25)
LAM_SCALES = (0.1, 0.3, 1.0)  # HQS data weight study (default 0.3), 166 px, in focus
SOLVER_SIZE = 166
SOLVER_SCENES = ("chart",) + PHOTOS


def _module(name: str):
    spec = importlib.util.spec_from_file_location(name, HERE / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def aberrated_case(name: str, rms: float, size: int = SIZE) -> list[dict]:
    """One photograph under a ``rms`` λ falling-spectrum aberration: rows for the wave-DAO
    reconstruction, the 2D sensor and the 2D sensor restored by the true and the DAO PSF."""
    import metasensor as ms
    from metasensor.dao.wavefront import zernike_rms

    bq, fig4 = _module("bench_quality"), _module("bench_ed_fig4")
    cfg = ms.SystemConfig()
    z = bq.falling_zernike(rms)
    with fig4.coarse_widefield():
        cap = ms.simulate(bq._scene(name, size), cfg, zernike=z, snr_db=30.0, seed=0,
                          psf=fig4.sim_bank)
    key = {"study": "photos-aberrated", "scene": name, "truth_px": cap.truth.shape[0],
           "focus_offset_waves": 0.0, "aberration_rms_waves": rms}
    t0 = time.perf_counter()
    rec = ms.reconstruct(cap.views, cfg, method="wave")
    seconds = time.perf_counter() - t0
    est = np.asarray(rec.zernike[0, 0], dtype=np.float64)
    rows = [{**key, "image": "ISA (wave DAO)", **bq.scores(rec.image, cap.truth),
             "residual_rms": zernike_rms(est[:45] - z), "dao_updates": len(rec.dao_history[0][0]),
             "seconds": seconds, "zernike_estimate": [round(float(v), 5) for v in est[:45]]},
            {**key, "image": "2D sensor", **bq.scores(cap.sensor2d, cap.truth)}]
    return rows + restored_rows(cap, key, (("true PSF", z), ("DAO PSF", est[:45])))


def restored_rows(cap, key: dict, psfs) -> list[dict]:
    """The 2D sensor restored with the prior by each (label, Noll vector) of ``psfs``: the true
    aberration and the DAO estimate."""
    bq = _module("bench_quality")
    rows = []
    for label, zz in psfs:
        img, lam = bq.restore_2d(cap, cap.config, zernike=zz)
        rows.append({**key, "image": f"2D+prior ({label})", "lam": lam,
                     "lam_grid": list(bq.HL_LAMBDAS), **bq.scores(img, cap.truth)})
    return rows


def refresh_restored(rows: list[dict]) -> list[dict]:
    """Every case's 2D+prior rows measured again where they predate the current lam grid
    (``bench_quality.HL_LAMBDAS``): the capture is simulated again (same seed), ISA is not."""
    import metasensor as ms

    bq, fig4 = _module("bench_quality"), _module("bench_ed_fig4")
    grid = list(bq.HL_LAMBDAS)
    stale = {_key(r) for r in rows if r["image"].startswith("2D+prior")
             and r.get("lam_grid") != grid}
    for k in sorted(stale, key=lambda k: (k[0] != "photos-focus", k[2], PHOTOS.index(k[1]))):
        study, name, rms, off, _ = k
        same = [r for r in rows if _key(r) == k]
        key = {c: same[0][c] for c in ("study", "scene", "truth_px", "focus_offset_waves",
                                       "aberration_rms_waves")}
        cfg = ms.SystemConfig()
        if study == "photos-aberrated":
            z = bq.falling_zernike(rms)
            with fig4.coarse_widefield():
                cap = ms.simulate(bq._scene(name, SIZE), cfg, zernike=z, snr_db=30.0, seed=0,
                                  psf=fig4.sim_bank)
            isa = next(r for r in same if r["image"].startswith("ISA"))
            psfs = [("true PSF", z)]  # the DAO estimate: only where the ISA row kept it
            if "zernike_estimate" in isa:
                psfs.append(("DAO PSF", np.asarray(isa["zernike_estimate"])))
            new = restored_rows(cap, key, psfs)
        else:
            cap = ms.simulate(bq._scene(name, SIZE), cfg, snr_db=30.0, seed=0)
            img, lam = bq.restore_2d(cap, cfg)
            new = [{**key, "image": f"2D+prior (lam {lam:g})", "lam": lam, "lam_grid": grid,
                    **bq.scores(img, cap.truth)}]
        rows = [r for r in rows if not (_key(r) == k and r["image"].startswith("2D+prior"))]
        rows += new
        _save(rows)
        print(json.dumps(new[0], default=float), flush=True)
    return rows


def focus_case(name: str, offset: float, size: int = SIZE) -> list[dict]:
    """One aberration-free photograph with the meta-imaging sensor ``offset`` λ off focus (in
    focus also the 2D sensor restored with the prior)."""
    return _module("bench_quality").case(name, size, "photos-focus", offset=offset)


def solver_case(name: str, lam_scale: float, size: int = SOLVER_SIZE) -> list[dict]:
    """One aberration-free scene in focus reconstructed with HQS ``lam_scale`` (the data weight
    λ·σ²; the default is ``HQSOptions().lam_scale``), other settings default."""
    import metasensor as ms
    from metasensor.solvers.hqs import HQSOptions

    bq = _module("bench_quality")
    cfg = ms.SystemConfig()
    cap = ms.simulate(bq._scene(name, size), cfg, snr_db=30.0, seed=0)
    t0 = time.perf_counter()
    rec = ms.reconstruct(cap.views, cfg, solver_options=HQSOptions(lam_scale=lam_scale))
    return [{"study": "photos-solver", "scene": name, "truth_px": cap.truth.shape[0],
             "aberration_rms_waves": 0.0, "focus_offset_waves": 0.0, "lam_scale": lam_scale,
             "image": f"ISA (lam_scale {lam_scale:g})", **bq.scores(rec.image, cap.truth),
             "seconds": time.perf_counter() - t0}]


def _key(row: dict) -> tuple:
    return (row["study"], row["scene"], row["aberration_rms_waves"], row["focus_offset_waves"],
            row.get("lam_scale"))


def load_rows() -> list[dict]:
    """The measured rows in :data:`PHOTOS_JSON` (no summaries), or []."""
    if not PHOTOS_JSON.is_file():
        return []
    return [r for r in json.loads(PHOTOS_JSON.read_text())["rows"] if "summary" not in r]


def _save(rows: list[dict]) -> None:
    from metasensor.io.atomic import atomic_write_text

    payload = {"benchmark": "quality (photos)", "size_px": SIZE, "rows": rows + targets(rows)}
    atomic_write_text(PHOTOS_JSON, json.dumps(payload, indent=2, default=float))


def run(studies=("aberrated", "focus", "solver")) -> list[dict]:
    """Every case of ``studies`` not yet in :data:`PHOTOS_JSON` (written after each case)."""
    import torch

    torch.set_num_threads(1)
    rows = refresh_restored(load_rows())
    done = {_key(r) for r in rows}
    plan = []
    if "aberrated" in studies:
        plan += [("photos-aberrated", n, rms, 0.0) for rms in ABERRATIONS for n in PHOTOS]
    if "focus" in studies:
        plan += [("photos-focus", n, 0.0, off) for off in OFFSETS[::-1] for n in PHOTOS]
    if "solver" in studies:
        plan += [("photos-solver", n, 0.0, 0.0, lam) for n in SOLVER_SCENES
                 for lam in LAM_SCALES]
    for study, name, rms, off, *lam in plan:
        if (study, name, rms, off, *(lam or [None])) in done:
            continue
        if study == "photos-solver":
            new = solver_case(name, lam[0])
        else:
            new = (aberrated_case(name, rms) if study == "photos-aberrated"
                   else focus_case(name, off))
        rows += new
        _save(rows)
        print(json.dumps(new[0], default=float), flush=True)
    plot(rows, output_path("quality_photos.png"))
    return rows + targets(rows)


def plot(rows: list[dict], path: Path) -> None:
    """SSIM and resolved frequency per photograph: aberrated (ISA, 2D, 2D+prior) and focus."""
    from metasensor.io.figures import new_figure, save_figure

    fig, axes = new_figure(nrows=2, ncols=3, size=(14, 7))
    for col, rms in enumerate(ABERRATIONS):
        for row, metric in enumerate(("ssim", "resolved")):
            ax = axes[row, col]
            for k, kind in enumerate(("ISA", "2D sensor", "2D+prior (true PSF)")):
                sel = [_find(rows, "photos-aberrated", n, rms, 0.0, kind) for n in PHOTOS]
                xs = [i + 0.2 * (k - 1) for i, r in enumerate(sel) if r]
                ax.plot(xs, [r[metric] for r in sel if r], "o", label=kind)
            ax.set_xticks(range(len(PHOTOS)), PHOTOS, rotation=30, fontsize=7)
            ax.set_ylabel(metric if metric == "ssim" else "resolved [cycles/px]")
            ax.set_title(f"{rms:g} λ r.m.s., wave DAO, 30 dB", fontsize=9)
            ax.legend(fontsize=6)
    for row, metric in enumerate(("ssim", "resolved")):
        ax = axes[row, 2]
        for off in OFFSETS:
            sel = [_find(rows, "photos-focus", n, 0.0, off, "ISA") for n in PHOTOS]
            ax.plot([i for i, r in enumerate(sel) if r], [r[metric] for r in sel if r], "s",
                    label=f"ISA, {off:g} λ off focus")
        sel = [_find(rows, "photos-focus", n, 0.0, 0.0, "2D sensor") for n in PHOTOS]
        ax.plot([i for i, r in enumerate(sel) if r], [r[metric] for r in sel if r], "x",
                label="2D sensor, in focus")
        ax.set_xticks(range(len(PHOTOS)), PHOTOS, rotation=30, fontsize=7)
        ax.set_title("aberration-free, 30 dB", fontsize=9)
        ax.legend(fontsize=6)
    save_figure(fig, path, dpi=110)


def _find(rows, study, scene, rms, off, prefix):
    return next((r for r in rows if _key(r)[:4] == (study, scene, rms, off)
                 and r["image"].startswith(prefix)), None)


def targets(rows: list[dict]) -> list[dict]:
    """The issue's acceptance lines, per photograph and case."""
    out = []
    for rms in ABERRATIONS:
        for name in PHOTOS:
            isa = _find(rows, "photos-aberrated", name, rms, 0.0, "ISA")
            if isa is None:
                continue
            for ref in ("2D sensor", "2D+prior (true PSF)", "2D+prior (DAO PSF)"):
                r2 = _find(rows, "photos-aberrated", name, rms, 0.0, ref)
                if r2 is None:
                    continue
                d_ssim = isa["ssim"] - r2["ssim"]
                d_psnr = isa["psnr_db"] - r2["psnr_db"]
                # the 2D image resolving nothing (0 cycles/px): any resolved frequency is more
                ratio = isa["resolved"] / r2["resolved"] if r2["resolved"] > 0 else None
                out.append({"summary": "aberrated: SSIM >= ref + 0.15, PSNR >= ref + 5 dB, "
                            "resolved >= 2x ref", "scene": name, "aberration_rms_waves": rms,
                            "reference": ref, "ssim_gain": d_ssim, "psnr_gain_db": d_psnr,
                            "resolved_ratio": ratio,
                            "reference_resolved": r2["resolved"],
                            "holds": bool(d_ssim >= 0.15 and d_psnr >= 5.0 and (
                                ratio is None or ratio >= 2.0))})
    for name in PHOTOS:
        on = _find(rows, "photos-focus", name, 0.0, 0.0, "ISA")
        off = _find(rows, "photos-focus", name, 0.0, 0.25, "ISA")
        if on is None or off is None:
            continue
        out.append({"summary": "0.25 λ off focus at least as good as in focus", "scene": name,
                    "ssim_in_focus": on["ssim"], "ssim_off": off["ssim"],
                    "resolved_in_focus": on["resolved"], "resolved_off": off["resolved"],
                    "holds": bool(off["ssim"] >= on["ssim"] and off["resolved"] >= on["resolved"])})
    base = {r["scene"]: r for r in rows if r["study"] == "photos-solver"
            and r["lam_scale"] == LAM_SCALES[1]}
    for lam in LAM_SCALES[::2]:
        mine = {r["scene"]: r for r in rows if r["study"] == "photos-solver"
                and r["lam_scale"] == lam}
        common = [n for n in SOLVER_SCENES if n in mine and n in base]
        if len(common) < len(SOLVER_SCENES):
            continue
        gain = {n: mine[n]["ssim"] - base[n]["ssim"] for n in common}
        res = {n: mine[n]["resolved"] - base[n]["resolved"] for n in common}
        out.append({"summary": f"lam_scale {lam:g} against the default {LAM_SCALES[1]:g}",
                    "ssim_gain": gain, "resolved_gain": res,
                    "improves_photos_keeps_chart": bool(
                        all(gain[n] > 0 for n in PHOTOS) and gain["chart"] >= -0.005)})
    return out
