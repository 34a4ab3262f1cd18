"""Texture-preserving priors side by side: BM3D as the plug-and-play prior of the phase-space HQS.

Run: ``python benchmarks/bench_quality.py --prior [focus] [aberrated] [tune]`` (needs the
optional ``bm3d`` package, free for non-commercial use only: ``pip install 'metasensor[bm3d]'``;
without it the study says so and writes nothing). Rows go to ``results/quality_prior.json`` case
by case (a repeated run skips the cases it holds), the figure to ``results/quality_prior.png``.
Every capture as ``bench_quality``'s: the simulator, 5 x 5 scan, 30 dB per frame, seed 0, 256-px
fields (240 px of truth); figures against ``cap.truth``: SSIM, PSNR, resolved frequency (global,
worst of 3 x 3 regions).

Studies (the ``study`` column):

- ``prior-tune``: the data weight of BM3D-in-HQS (``bm3d_options(lam_scale=...)``) over 1.5 / 2 /
  3 on two dead-leaves scenes (``priors.dead_leaves``, seeds 10001 and 10002: not photographs,
  not the denoiser's training seeds), 0.25 λ off focus; the default is chosen here.
- ``prior-focus``: the six photographs at the operating point (0.25 λ off focus, aberration-free):
  the default reconstruction, the same with BM3D (``bm3d_options()``), the 2D sensor in focus and
  the 2D sensor denoised with BM3D (the noise level the best of 0.5 / 1 / 2 times the image's
  estimate by SSIM to the truth: like with like, favouring the 2D sensor).
- ``prior-aberrated``: rocket and grass (the photographs whose 1 λ / 3 λ rows fail the gain
  line) through wave DAO with the default prior and with BM3D in the final solve.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # _paths: where figures go

import bench_quality as bq  # noqa: E402
from _paths import output_path  # noqa: E402

PRIOR_JSON = HERE / "results" / "quality_prior.json"
PHOTOS = ("camera", "astronaut", "coffee", "chelsea", "rocket", "grass")
TUNE_SCENES = (10001, 10002)
TUNE_LAMS = (1.5, 2.0, 3.0)
SIZE = 256
OFFSET = 0.25


def _capture(scene: np.ndarray, offset: float, zernike=None):
    import metasensor as ms

    return ms.simulate(scene, ms.SystemConfig(), zernike=zernike, snr_db=30.0, seed=0,
                       focus_offset=offset)


def _meta_rows(cap, key: dict, settings, method: str = "isa") -> list[dict]:
    """One row per (label, solver options) of ``settings``: ``reconstruct`` timed and scored."""
    import metasensor as ms

    rows = []
    for label, opts in settings:
        t0 = time.perf_counter()
        rec = ms.reconstruct(cap.views, cap.config, method=method,
                             zernike=cap.zernike if method == "isa" else None,
                             solver_options=opts)
        rows.append({**key, "image": label, **bq.scores(rec.image, cap.truth),
                     "seconds": time.perf_counter() - t0})
    return rows


def restore_2d_bm3d(cap) -> tuple[np.ndarray, float]:
    """The 2D sensor's image denoised by BM3D, the noise level the best of 0.5 / 1 / 2 times
    ``skimage``'s estimate by SSIM to the truth. Denoised, not deconvolved: in focus and
    aberration-free its PSF is the diffraction spot over a pixel, and the package's deblurring
    path fails on NumPy 2.4 (``np.trapz``) and on 2D images (its pilot's shape)."""
    import bm3d
    from skimage.restoration import estimate_sigma

    from metasensor.metrics import ssim

    img = np.asarray(cap.sensor2d, dtype=np.float64)
    scale = float(img.max())
    z = img / scale
    sigma0 = float(estimate_sigma(z))
    rng = float(cap.truth.max() - cap.truth.min())
    best = None
    for f in (0.5, 1.0, 2.0):
        out = np.asarray(bm3d.bm3d(z, f * sigma0)) * scale
        s = ssim(truth=cap.truth, image=out, data_range=rng)
        if best is None or s > best[0]:
            best = (s, out, f)
    return best[1], best[2]


def tune_case(seed: int) -> list[dict]:
    from metasensor.priors import dead_leaves
    from metasensor.priors.external import bm3d_options

    cap = _capture(dead_leaves(size=SIZE, seed=seed), OFFSET)
    key = {"study": "prior-tune", "scene": f"dead-leaves {seed}", "focus_offset_waves": OFFSET,
           "aberration_rms_waves": 0.0}
    settings = [("ISA (default prior)", None)]
    settings += [(f"ISA (BM3D, lam_scale {lam:g})", bm3d_options(lam_scale=lam))
                 for lam in TUNE_LAMS]
    return _meta_rows(cap, key, settings)


def focus_case(name: str) -> list[dict]:
    from metasensor.priors.external import bm3d_options

    cap = _capture(bq._scene(name, SIZE), OFFSET)
    key = {"study": "prior-focus", "scene": name, "focus_offset_waves": OFFSET,
           "aberration_rms_waves": 0.0}
    rows = _meta_rows(cap, key, [("ISA (default prior)", None), ("ISA (BM3D)", bm3d_options())])
    rows.append({**key, "image": "2D sensor", **bq.scores(cap.sensor2d, cap.truth)})
    img, f = restore_2d_bm3d(cap)
    rows.append({**key, "image": "2D+BM3D", "sigma_factor": f, **bq.scores(img, cap.truth)})
    return rows


def aberrated_case(name: str, rms: float) -> list[dict]:
    import bench_ed_fig4 as fig4
    import metasensor as ms
    from metasensor.priors.external import bm3d_options

    z = bq.falling_zernike(rms)
    with fig4.coarse_widefield():
        cap = ms.simulate(bq._scene(name, SIZE), ms.SystemConfig(), zernike=z, snr_db=30.0,
                          seed=0, psf=fig4.sim_bank)
    key = {"study": "prior-aberrated", "scene": name, "focus_offset_waves": 0.0,
           "aberration_rms_waves": rms}
    rows = _meta_rows(cap, key, [("ISA (wave DAO, default prior)", None),
                                 ("ISA (wave DAO, BM3D)", bm3d_options())], method="wave")
    rows.append({**key, "image": "2D sensor", **bq.scores(cap.sensor2d, cap.truth)})
    return rows


def _load() -> list[dict]:
    return json.loads(PRIOR_JSON.read_text())["rows"] if PRIOR_JSON.exists() else []


def _save(rows: list[dict]) -> None:
    from metasensor.io.atomic import atomic_write_text

    atomic_write_text(PRIOR_JSON, json.dumps({"benchmark": "quality (BM3D prior)",
                                              "size_px": SIZE, "rows": rows}, indent=1,
                                             default=float))


def plot(rows: list[dict], path: Path) -> None:
    """SSIM and resolved frequency per photograph at the operating point: the default prior,
    BM3D, the 2D sensor and the 2D sensor denoised by BM3D."""
    from metasensor.io.figures import new_figure, save_figure

    kinds = ("ISA (default prior)", "ISA (BM3D)", "2D sensor", "2D+BM3D")
    fig, axes = new_figure(nrows=1, ncols=2, size=(12, 4))
    for ax, metric in zip(axes[0], ("ssim", "resolved"), strict=True):
        for k, kind in enumerate(kinds):
            sel = [next((r for r in rows if r["study"] == "prior-focus" and r["scene"] == n
                         and r["image"] == kind), None) for n in PHOTOS]
            xs = [i + 0.15 * (k - 1.5) for i, r in enumerate(sel) if r]
            ax.plot(xs, [r[metric] for r in sel if r], "osx+"[k], label=kind)
        ax.set_xticks(range(len(PHOTOS)), PHOTOS, rotation=30, fontsize=8)
        ax.set_ylabel("SSIM" if metric == "ssim" else "resolved [cycles/px]")
        ax.set_title("aberration-free, 0.25 λ off focus (2D sensor in focus), 30 dB", fontsize=9)
        ax.legend(fontsize=7)
    save_figure(fig, path, dpi=110)


def run(studies=("tune", "focus", "aberrated")) -> list[dict]:
    """Every case of ``studies`` not yet in the JSON, most telling first; rows saved per case."""
    from metasensor.priors.external import require_bm3d

    try:
        require_bm3d()
    except ImportError as err:
        print(f"{err}; nothing measured")
        return _load()
    rows = _load()
    done = {(r["study"], r["scene"], r["aberration_rms_waves"]) for r in rows}
    cases = []  # most telling first: the photographs, then 1 λ, the tuning, 3 λ
    if "focus" in studies:
        cases += [("prior-focus", n, 0.0, lambda n=n: focus_case(n)) for n in PHOTOS]
    aberrated = [("prior-aberrated", n, rms, lambda n=n, rms=rms: aberrated_case(n, rms))
                 for rms in (1.0, 3.0) for n in ("rocket", "grass")]
    if "aberrated" in studies:
        cases += aberrated[:2]
    if "tune" in studies:
        cases += [("prior-tune", f"dead-leaves {s}", 0.0, lambda s=s: tune_case(s))
                  for s in TUNE_SCENES]
    if "aberrated" in studies:
        cases += aberrated[2:]
    for study, scene, rms, fn in cases:
        if (study, scene, rms) in done:
            continue
        new = fn()
        rows += new
        _save(rows)
        for r in new:
            print(json.dumps(r, default=float), flush=True)
    plot(rows, output_path("quality_prior.png"))
    return rows
