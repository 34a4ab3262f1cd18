"""Reconstruction quality against the 2D sensor, read with the honest resolution metrics.

Every capture: the simulator (inverse-crime free), 5 x 5 scan, SNR 30 dB per frame, seed 0;
reconstruction by the contract call ``ms.reconstruct(views, cfg, method=...)`` with default
settings. Every figure is against ``cap.truth`` (data range of the truth), for the
meta-imaging (ISA) image and for the same capture's 2D sensor (same lens, photon budget, noise):

- SSIM / PSNR (``metasensor.metrics``);
- resolved frequency [cycles/px] (``metrics.spectral``: highest frequency below which the
  error-to-truth power ratio stays < 0.5), globally and the worst of the 3 x 3 field regions;
- on the bar chart (``load_scene("bars")``, three-bar groups at the centre, edge midpoints and
  corners): the finest resolved bar period per location (``metrics.bars``).

Studies (the ``study`` column):

- ``aberration-free``: the demo chart, the bar chart and six scikit-image photographs (camera,
  astronaut, coffee, chelsea, rocket, grass; 256 px fields, 240 px of truth). Next to the 2D
  sensor, the 2D sensor restored with the same kind of prior as ISA's default (``2d+prior``:
  hyper-Laplacian deconvolution by its own widefield PSF, Krishnan & Fergus, lam chosen from
  100 / 400 / 2e3 / 1e4 / 5e4 by the truth, i.e. the best it can do): like with like.
- ``focus``: a deliberate focus offset of the meta-imaging sensor (``simulate(focus_offset=)``:
  Noll Z4 = 0, 0.25, 0.5, 1 λ r.m.s. on the views only), known to the reconstruction (its
  PSF bank has the same defocus: ``zernike=cap.zernike``), against the 2D sensor in focus; bar
  chart and camera.
- ``aberrated``: the demo chart and the camera under random 1 and 3 λ r.m.s. aberrations (Noll
  4-45, amplitudes falling as 1/n with the radial order n, seed 0) through the default pipeline
  with wave DAO (``method="wave"``); slow, so run once
  (``python benchmarks/bench_quality.py --aberrated``, writes
  ``results/quality_aberrated.json``) and merged into the table when present. Its
  ``2D+prior`` row deconvolves with the true aberrated PSF (an oracle the 2D sensor lacks).

- ``photos-aberrated`` / ``photos-focus``: the six photographs under 1 and 3 λ through wave DAO
  and 0.25 λ off focus (``benchmarks/quality_photos.py``; ``--photos``, written to
  ``results/quality_photos.json`` case by case and merged into the table when present).
- ``prior-tune`` / ``prior-focus`` / ``prior-aberrated``: BM3D as the plug-and-play prior
  (an optional extra, free for non-commercial use only) against the default prior, and the 2D
  sensor restored with BM3D (``benchmarks/quality_prior.py``; ``--prior``, written to
  ``results/quality_prior.json``).
- ``--limit``: the linear-MMSE (Wiener) limit of the meta-imaging sensor and the 2D sensor on the
  six photographs from the operators' spectra (``benchmarks/quality_limit.py``,
  ``results/quality_limit.json``).
- ``demo``: ``metasensor demo`` at its defaults (the bar chart through the single plastic lens,
  field-dependent aberrations of up to 2 λ r.m.s., both light-field cameras at the operating
  focus offset, 384 px): per image SSIM, PSNR, resolved frequency, the fringe ratio at the
  block borders and the finest bar group per location; ``python benchmarks/bench_quality.py
  --demo`` writes ``results/quality_demo.json`` (merged into the table when present).

Figures: ``results/quality.png`` (SSIM and resolved frequency per scene, and against the focus
offset).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "src"))
sys.path.insert(0, str(HERE))  # _paths: where figures go

from _paths import output_path  # noqa: E402

NATURAL = ("camera", "astronaut", "coffee", "chelsea", "rocket", "grass")
SCENES_FULL = ("chart", "bars") + NATURAL
SCENES_QUICK = ("bars", "camera")
SIZE_FULL, SIZE_QUICK = 256, 166
OFFSETS = (0.0, 0.25, 0.5, 1.0)
FOCUS_SCENES = ("bars", "camera")
ABERRATED_SCENES = ("chart", "camera")
ABERRATIONS = (1.0, 3.0)
HL_LAMBDAS = (100.0, 400.0, 2e3, 1e4, 5e4)  # KF data weights; 400 was best on the camera
ABERRATED_JSON = HERE / "results" / "quality_aberrated.json"
DEMO_JSON = HERE / "results" / "quality_demo.json"


def falling_zernike(rms: float, seed: int = 0, jmax: int = 45) -> np.ndarray:
    """Random Noll vector (modes 4..jmax) with amplitudes ∝ 1/n (radial order), r.m.s. ``rms``."""
    from metasensor.optics.zernike import noll_to_nm

    rng = np.random.default_rng(seed)
    z = np.zeros(jmax)
    for j in range(4, jmax + 1):
        z[j - 1] = rng.standard_normal() / noll_to_nm(j)[0]
    return z * (rms / np.linalg.norm(z))


def scores(image, truth, bars=None) -> dict:
    """SSIM, PSNR, resolved frequency (global, worst region) and bar periods of one image."""
    from metasensor.metrics import psnr, regional_fidelity, ssim
    from metasensor.metrics.bars import bar_resolution

    rng = float(truth.max() - truth.min())
    reg = regional_fidelity(image, truth)
    out = {"ssim": ssim(truth=truth, image=image, data_range=rng),
           "psnr_db": psnr(truth=truth, image=image, data_range=rng),
           "resolved": reg["global"].resolved,
           "resolved_worst_region": min(v.resolved for k, v in reg.items() if k != "global")}
    if bars is not None:
        res = bar_resolution(image, bars)
        for loc in ("centre", "top", "left", "top-left", "bottom-right"):
            out[f"bar_px_{loc}"] = res[loc]["period_px"]
    return out


def restore_2d(cap, cfg, zernike=None) -> tuple[np.ndarray, float]:
    """The 2D sensor's image deconvolved by its widefield PSF with the hyper-Laplacian prior
    (the best of :data:`HL_LAMBDAS` by SSIM to the truth) and that lam."""
    from metasensor.metrics import ssim
    from metasensor.optics.widefield import widefield_psf
    from metasensor.solvers.krishnan_fergus import KFOptions, hyper_laplacian_deconv

    psf = widefield_psf(cfg, zernike=zernike)
    rng = float(cap.truth.max() - cap.truth.min())
    best = None
    for lam in HL_LAMBDAS:
        img = hyper_laplacian_deconv(cap.sensor2d, psf, KFOptions(lam=lam))
        s = ssim(truth=cap.truth, image=img, data_range=rng)
        if best is None or s > best[0]:
            best = (s, img, lam)
    return best[1], best[2]


def _layout(name: str, size: int, cap):
    """The bar chart's layout on ``cap.truth``'s grid (it starts at scene pixel cap.offset)."""
    if name != "bars":
        return None
    from metasensor.simulation.bars import bar_groups

    h, w = cap.truth.shape
    groups = bar_groups(size, origin=float(cap.offset))
    inside = [g for g in groups if g.y0 >= 0 and g.x0 >= 0 and g.y0 + g.extent <= h
              and g.x0 + g.extent <= w]
    if len(inside) < len(groups):
        raise ValueError(f"bar groups outside the truth: {len(groups) - len(inside)}")
    return groups


def _scene(name: str, size: int):
    from metasensor.simulation.scenes import load_scene

    return load_scene(name, size)


def case(name: str, size: int, study: str, zernike=None, offset: float = 0.0,
         method: str = "isa") -> list[dict]:
    """Simulate, reconstruct and score one scene; rows for ISA, the 2D sensor (in focus: the
    simulator's ``focus_offset`` moves the meta-imaging sensor only) and, in focus, the 2D sensor
    restored with the hyper-Laplacian prior."""
    import metasensor as ms

    cfg = ms.SystemConfig()
    cap = ms.simulate(_scene(name, size), cfg, zernike=zernike, snr_db=30.0, seed=0,
                      focus_offset=offset)
    z = cap.zernike  # the system's known aberration (the focus offset) for ISA
    bars = _layout(name, size, cap)
    key = {"study": study, "scene": name, "truth_px": cap.truth.shape[0],
           "focus_offset_waves": offset, "aberration_rms_waves":
           0.0 if zernike is None else round(float(np.linalg.norm(zernike)), 3)}
    t0 = time.perf_counter()
    rec = ms.reconstruct(cap.views, cfg, method=method,
                         zernike=z if method == "isa" else None)
    rows = [{**key, "image": f"ISA ({method})", **scores(rec.image, cap.truth, bars),
             "seconds": time.perf_counter() - t0}]
    rows.append({**key, "image": "2D sensor", **scores(cap.sensor2d, cap.truth, bars)})
    if offset == 0.0:
        img, lam = restore_2d(cap, cfg, zernike=zernike)
        rows.append({**key, "image": f"2D+prior (lam {lam:g})",
                     **scores(img, cap.truth, bars)})
    return rows


def plan(quick: bool = False) -> list[tuple[str, str, float]]:
    """The cases (scene, study, focus offset), most telling first (so that a run cut short by a
    busy machine still holds the operating-point comparison)."""
    if quick:
        return [(n, "aberration-free", 0.0) for n in SCENES_QUICK] + [("bars", "focus", 0.25)]
    first = [("bars", "aberration-free", 0.0), ("camera", "aberration-free", 0.0),
             ("bars", "focus", 0.25), ("camera", "focus", 0.25)]
    rest = [(n, "aberration-free", 0.0) for n in SCENES_FULL if n not in ("bars", "camera")]
    later = [(n, "focus", off) for off in OFFSETS[2:] for n in FOCUS_SCENES]
    return first + rest + later


def run(quick: bool = False, sink=None) -> list[dict]:
    """All cases of :func:`plan`; ``sink(rows)`` after each (progressive runs)."""
    import torch

    torch.set_num_threads(1)
    size = SIZE_QUICK if quick else SIZE_FULL
    rows: list[dict] = []
    for name, study, off in plan(quick):
        new = case(name, size, study, offset=off)
        rows += new
        if study == "aberration-free" and name in FOCUS_SCENES:  # the focus study's offset 0
            rows += [{**r, "study": "focus"} for r in new]
        if sink is not None:
            sink(rows)
    if not quick:  # the slow studies' measured rows, as their own runs wrote them
        for path in (ABERRATED_JSON, HERE / "results" / "quality_photos.json", DEMO_JSON):
            rows += measured_rows(path)
    _plot(rows, output_path("quality_quick.png" if quick else "quality.png"))
    return rows


def measured_rows(path: Path) -> list[dict]:
    """The measured rows of a results file (its summary rows left out: they are recomputed
    over the merged table), or [] where the file is missing."""
    if not path.is_file():
        return []
    return [r for r in json.loads(path.read_text())["rows"] if "summary" not in r]


def run_aberrated(quick: bool = False) -> list[dict]:
    """The slow aberrated study (module docstring), single-threaded."""
    import torch

    torch.set_num_threads(1)
    rows = []
    for rms in ABERRATIONS[:1] if quick else ABERRATIONS:
        for name in SCENES_QUICK[1:] if quick else ABERRATED_SCENES:
            rows += case(name, SIZE_QUICK if quick else SIZE_FULL, "aberrated",
                         zernike=falling_zernike(rms), method="wave")
            print(rows[-3:], flush=True)
    return rows


def run_demo_rows(out: Path) -> list[dict]:
    """The demo at its defaults (module docstring), one row per image, single-threaded."""
    import torch

    from metasensor.report.demo import DemoSettings, run_demo

    torch.set_num_threads(1)
    settings = DemoSettings()
    summary = run_demo(out, settings, progress=False)
    rows = []
    for r in summary["table"]:
        row = {"scene": settings.scene, "study": "demo", "image": r["sensor"],
               "focus_offset_waves": settings.focus_offset, "seconds": summary["seconds"],
               "ssim": r.get("ssim"), "psnr_db": r.get("psnr_db"),
               "resolved": r.get("resolved_cpp"), "fringe_ratio": r.get("fringe_ratio")}
        for b in summary["bar_groups"]:
            if r["sensor"] in b:
                row[f"bar_px_{b['location']}"] = b[r["sensor"]]
        rows.append(row)
    return rows


def _plot(rows: list[dict], path: Path) -> None:
    from metasensor.io.figures import new_figure, save_figure

    fig, axes = new_figure(ncols=2, size=(10, 4.4))
    ax = axes[0, 0]
    free = [r for r in rows if r["study"] == "aberration-free"]
    names = list(dict.fromkeys(r["scene"] for r in free))
    for k, (label, mark) in enumerate((("ISA", "o"), ("2D sensor", "x"), ("2D+prior", "+"))):
        sel = [next((r for r in free if r["scene"] == n and r["image"].startswith(label)), None)
               for n in names]
        xs = [i + 0.2 * (k - 1) for i, r in enumerate(sel) if r]
        ax.plot(xs, [r["ssim"] for r in sel if r], mark, label=f"{label}: SSIM")
        ax.plot(xs, [r["resolved"] / 0.5 for r in sel if r], mark, alpha=0.5, ms=9,
                label=f"{label}: resolved / Nyquist")
    ax.set_xticks(range(len(names)), names, rotation=30, fontsize=7)
    ax.set_title("aberration-free, 30 dB, 5 x 5 scan", fontsize=9)
    # below the axes: inside, it hid the low resolved-frequency points
    ax.legend(fontsize=6, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.2))
    ax = axes[0, 1]
    focus = [r for r in rows if r["study"] == "focus" and r["image"].startswith("ISA")]
    for name in dict.fromkeys(r["scene"] for r in focus):
        sel = sorted((r for r in focus if r["scene"] == name),
                     key=lambda r: r["focus_offset_waves"])
        line, = ax.plot([r["focus_offset_waves"] for r in sel], [r["ssim"] for r in sel], "o-",
                        label=f"{name}: ISA SSIM")
        ref = next(r for r in rows if r["study"] == "focus" and r["scene"] == name
                   and r["image"] == "2D sensor")
        ax.axhline(ref["ssim"], color=line.get_color(), ls=":", lw=0.8)
    ax.set_xlabel("focus offset, Noll Z4 [waves r.m.s.]")
    ax.set_ylabel("SSIM (dotted: 2D sensor in focus)")
    ax.legend(fontsize=6)
    save_figure(fig, path, dpi=120)


if __name__ == "__main__":
    from _usage import exit_on_help

    exit_on_help(__doc__)
    if "--photos" in sys.argv:  # the natural photographs' studies (benchmarks/quality_photos.py)
        sys.path.insert(0, str(HERE))
        import quality_photos

        studies = ("aberrated", "focus", "solver")
        which = [a for a in studies if a in sys.argv] or list(studies)
        for row in quality_photos.run(tuple(which)):
            print(row)
    elif "--prior" in sys.argv:  # BM3D as the prior, side by side (benchmarks/quality_prior.py)
        sys.path.insert(0, str(HERE))
        import quality_prior

        studies = ("tune", "focus", "aberrated")
        quality_prior.run(tuple(a for a in studies if a in sys.argv) or studies)
    elif "--limit" in sys.argv:  # the linear-MMSE limit (benchmarks/quality_limit.py)
        sys.path.insert(0, str(HERE))
        import quality_limit

        quality_limit.run()
    elif "--aberrated" in sys.argv:
        quick = "--quick" in sys.argv
        result = run_aberrated(quick=quick)
        if not quick:
            from metasensor.io.atomic import atomic_write_text

            atomic_write_text(ABERRATED_JSON, json.dumps({"rows": result}, indent=2,
                                                        default=float))
    elif "--demo" in sys.argv:  # --demo [FOLDER]: the demo's report goes to FOLDER if given
        import tempfile

        from metasensor.io.atomic import atomic_write_text

        at = sys.argv.index("--demo") + 1
        keep = sys.argv[at] if at < len(sys.argv) and not sys.argv[at].startswith("-") else None
        with tempfile.TemporaryDirectory() as tmp:
            result = run_demo_rows(Path(keep or tmp))
        atomic_write_text(DEMO_JSON, json.dumps({"benchmark": "quality", "study": "demo",
                                                 "rows": result}, indent=2, default=float))
        for row in result:
            print(row)
    elif "--progressive" in sys.argv:  # results/quality.json rewritten after every case
        from metasensor.io.atomic import atomic_write_text

        def _sink(rows):
            done = len({(r["scene"], r["study"], r["focus_offset_waves"]) for r in rows
                        if not (r["study"] == "focus" and r["focus_offset_waves"] == 0.0)})
            atomic_write_text(HERE / "results" / "quality.json", json.dumps(
                {"benchmark": "quality", "quick": False, "partial": done < len(plan()),
                 "cases_planned": len(plan()), "cases_done": done, "rows": rows}, indent=2,
                default=float))
            print(rows[-1], flush=True)

        run(sink=_sink)
    else:
        for row in run(quick="--quick" in sys.argv):
            print(row)
