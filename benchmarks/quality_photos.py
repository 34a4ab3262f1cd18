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
- ``photos-focus``: aberration-free, in focus and with the meta-imaging sensor 0.25 λ (Noll Z4)
  off the conjugate plane (``simulate(focus_offset=0.25)``, known to the reconstruction), the
  2D sensor in focus; default reconstruction (``bench_quality.case``).

Targets (issue: reconstruction quality), summarised by :func:`targets`: aberrated, SSIM >= 2D +
0.15, PSNR >= 2D + 5 dB, resolved frequency >= 2 x the 2D sensor's; off focus, SSIM and resolved
frequency at least those in focus.

Run: ``python benchmarks/bench_quality.py --photos [aberrated|focus]`` (one process,
single-threaded). Every finished case is written at once to ``results/quality_photos.json``
and skipped when the run is repeated; ``bench_quality.run`` merges the file's rows.
"""

from __future__ import annotations

import importlib.util
import json
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
PHOTOS_JSON = HERE / "results" / "quality_photos.json"
PHOTOS = ("camera", "astronaut", "coffee", "chelsea", "rocket", "grass")
SIZE = 256
ABERRATIONS = (1.0, 3.0)
OFFSETS = (0.0, 0.25)


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
             "seconds": seconds},
            {**key, "image": "2D sensor", **bq.scores(cap.sensor2d, cap.truth)}]
    for label, zz in (("true PSF", z), ("DAO PSF", est[:45])):
        img, lam = bq.restore_2d(cap, cfg, zernike=zz)
        rows.append({**key, "image": f"2D+prior ({label})", "lam": lam,
                     **bq.scores(img, cap.truth)})
    return rows


def focus_case(name: str, offset: float, size: int = SIZE) -> list[dict]:
    """One aberration-free photograph with the meta-imaging sensor ``offset`` λ off focus."""
    rows = _module("bench_quality").case(name, size, "photos-focus", offset=offset)
    return [r for r in rows if not r["image"].startswith("2D+prior")]


def _key(row: dict) -> tuple:
    return (row["study"], row["scene"], row["aberration_rms_waves"], row["focus_offset_waves"])


def load_rows() -> list[dict]:
    """The measured rows in :data:`PHOTOS_JSON` (no summaries), or []."""
    if not PHOTOS_JSON.is_file():
        return []
    return [r for r in json.loads(PHOTOS_JSON.read_text())["rows"] if "summary" not in r]


def _save(rows: list[dict]) -> None:
    from metasensor.io.atomic import atomic_write_text

    payload = {"benchmark": "quality (photos)", "size_px": SIZE, "rows": rows + targets(rows)}
    atomic_write_text(PHOTOS_JSON, json.dumps(payload, indent=2, default=float))


def run(studies=("aberrated", "focus")) -> list[dict]:
    """Every case of ``studies`` not yet in :data:`PHOTOS_JSON` (written after each case)."""
    import torch

    torch.set_num_threads(1)
    rows = load_rows()
    done = {_key(r) for r in rows}
    plan = []
    if "aberrated" in studies:
        plan += [("photos-aberrated", n, rms, 0.0) for rms in ABERRATIONS for n in PHOTOS]
    if "focus" in studies:
        plan += [("photos-focus", n, 0.0, off) for n in PHOTOS for off in OFFSETS]
    for study, name, rms, off in plan:
        if (study, name, rms, off) in done:
            continue
        new = (aberrated_case(name, rms) if study == "photos-aberrated"
               else focus_case(name, off))
        rows += new
        _save(rows)
        print(json.dumps(new[0], default=float), flush=True)
    return rows + targets(rows)


def _find(rows, study, scene, rms, off, prefix):
    return next((r for r in rows if _key(r) == (study, scene, rms, off)
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
                d_ssim = isa["ssim"] - r2["ssim"]
                d_psnr = isa["psnr_db"] - r2["psnr_db"]
                ratio = isa["resolved"] / max(r2["resolved"], 1e-9)
                out.append({"summary": "aberrated: SSIM >= ref + 0.15, PSNR >= ref + 5 dB, "
                            "resolved >= 2x ref", "scene": name, "aberration_rms_waves": rms,
                            "reference": ref, "ssim_gain": d_ssim, "psnr_gain_db": d_psnr,
                            "resolved_ratio": ratio,
                            "holds": bool(d_ssim >= 0.15 and d_psnr >= 5.0 and ratio >= 2.0)})
    for name in PHOTOS:
        on = _find(rows, "photos-focus", name, 0.0, 0.0, "ISA")
        off = _find(rows, "photos-focus", name, 0.0, 0.25, "ISA")
        if on is None or off is None:
            continue
        out.append({"summary": "0.25 λ off focus at least as good as in focus", "scene": name,
                    "ssim_in_focus": on["ssim"], "ssim_off": off["ssim"],
                    "resolved_in_focus": on["resolved"], "resolved_off": off["resolved"],
                    "holds": bool(off["ssim"] >= on["ssim"] and off["resolved"] >= on["resolved"])})
    return out
