"""Depth from the views: speed of the full pipeline and accuracy on scenes with known depth.

Speed (issue: 1,000 x 1,000 views, 113 views, 64 disparity candidates, 2 CPU cores): wall and
process CPU time (on a shared, oversubscribed machine CPU time / threads is the better measure)
of ``estimate_depth`` with and without the Gauss–Newton refinement, against the streaming bound
measured in the same run (adding every view into an accumulator once per candidate: the memory
traffic any plane sweep needs), and peak memory.
Accuracy (geometric light-field scenes, ``metasensor.depth.synthetic``, SNR 30 dB): BadPix(0.07)
and MSE in view px per view step on textured regions, meta-imaging (scan 5) vs a plain
light-field camera (scan 1) in image px per view step, and the aberration warp's gain.
Hard scenes of plain light-field cameras (``metasensor.depth.scenes``: 9 x 9 views at 40 dB and
5 x 5 views at 30 dB, scan 1, disparities up to ±3 view px per view step), default settings
(span measured from the views) and, for 9 x 9, the window aggregation alone
(``smoothing=None``), scored as the 4D light-field benchmark does (BadPix 0.07 / 0.03 / 0.01,
MSE x 100) over the view minus a 15-px border, with whether the span covers the truth and the
scores on the pixels the estimator marks valid; each also without the learned choice of
depth-edge pixels' layer (``refiner=None``, ``metasensor.depth.learned``), without any
re-decision of them (also ``edges=None``, ``metasensor.depth.edges``) and, for the default,
without the removal of speckles (``speckles=None``, ``metasensor.depth.speckle``) and without
the re-decision of background pixels by their visible views (``visibility=None``,
``metasensor.depth.visibility``), for 5 x 5 also with a wider cost aggregation window
(``radius=6``), and on
photographs in front of a photograph (``scenes.natural_scene``, a family neither was tuned or
trained on), at 128 px and, default settings only, at the 4D light-field benchmark's view size
(512 px; the same scene family, objects four times larger: the share of pixels near an
occlusion edge, where most of the squared error lies, four times smaller). The speed rows
time the default (semi-global matching) and the window aggregation alone in the same run.
``quick``: 200 x 200 views and smaller scenes (< 1 min).
"""

from __future__ import annotations

import time

import numpy as np
import torch
from scipy import ndimage

import metasensor as ms
from metasensor.depth import synthetic
from metasensor.depth.evaluate import evaluation_mask, score
from metasensor.io.memory import peak_resident_bytes, reset_peak_resident


def _timing_views(n_px: int, disparity: float = 0.4, seed: int = 0) -> np.ndarray:
    cfg = ms.SystemConfig()
    tex = ndimage.gaussian_filter(np.random.default_rng(seed).random((n_px, n_px)), 2.0)
    tex = (0.5 + 5 * (tex - tex.mean())).astype(np.float32)
    views = np.zeros((15, 15, n_px, n_px), dtype=np.float32)
    mask = cfg.view_mask()
    for u in range(15):
        for v in range(15):
            if mask[u, v]:
                views[u, v] = ndimage.shift(tex, (disparity * (u - 7), disparity * (v - 7)),
                                            order=1, mode="nearest")
    return views


def _streaming_bound(views: np.ndarray, mask: np.ndarray, candidates: int) -> float:
    """Seconds to add every used view into an accumulator, once per candidate (measured on 4
    candidates and scaled)."""
    stack = torch.from_numpy(views[mask])
    acc = torch.zeros(stack.shape[1:])
    reps = 4
    t0 = time.perf_counter()
    for _ in range(reps):
        for i in range(stack.shape[0]):
            acc.add_(stack[i])
    return (time.perf_counter() - t0) * candidates / reps


def _speed_rows(n_px: int, threads: int = 2) -> list[dict]:
    torch.set_num_threads(threads)
    cfg = ms.SystemConfig()
    views = _timing_views(n_px)
    mask = cfg.view_mask()
    rows = []
    bound = _streaming_bound(views, mask, 64)
    for it, smoothing, label in ((0, ms.depth.SemiGlobal(), ""), (2, ms.depth.SemiGlobal(), ""),
                                 (2, None, ", window only")):
        reset_peak_resident()  # each row's own peak, over the views it is handed
        t0, c0 = time.perf_counter(), time.process_time()
        res = ms.estimate_depth(views, cfg, candidates=64, refine_iterations=it,
                                smoothing=smoothing)
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
        err = np.abs(res.disparity[20:-20, 20:-20] - 0.4)
        rows.append({
            "case": f"speed {n_px}x{n_px}, {int(mask.sum())} views, 64 cand, GN {it}{label}",
            "seconds": dt, "cpu_seconds": cpu, "stream_bound_s": bound, "ratio": dt / bound,
            "threads": threads, "badpix": float(np.mean(err > 0.07)),
            "peak_rss_gb": peak_resident_bytes() / 1e9,
        })
    return rows


def _accuracy_rows(size: int) -> list[dict]:
    cfg = ms.SystemConfig(scan=5)
    shape = (size, size)
    scenes = {
        "fronto-parallel planes": synthetic.scene_planes(shape, near=-1.5, far=1.0, seed=1),
        "slanted plane": synthetic.scene_slanted(shape, -2.0, 2.0, seed=2),
        "staircase": synthetic.scene_staircase(shape, 4, -2.0, 2.0, seed=3),
    }
    rows = []
    for name, (tex, layers) in scenes.items():
        sv = synthetic.render_views(tex, layers, cfg, snr_db=30, seed=0)
        t0 = time.perf_counter()
        res = ms.estimate_depth(sv.views, cfg)
        dt = time.perf_counter() - t0
        mask = evaluation_mask(sv.disparity, sv.views_clean[7, 7], edge_margin=3,
                               texture_fraction=0.1)
        s = score(res.disparity, sv.disparity, mask)
        s_all = score(res.disparity, sv.disparity)
        rows.append({"case": f"{name} (scan 5, view px)", "seconds": dt, "badpix": s["badpix"],
                     "mse": s["mse"], "coverage": s["coverage"], "badpix_all": s_all["badpix"],
                     "mse_all": s_all["mse"]})
    # meta-imaging vs plain light-field camera, common unit: image px per view step
    for name in ("slanted plane", "staircase"):
        tex, layers = scenes[name]
        out = {}
        for scan in (5, 1):
            c = cfg.replace(scan=scan)
            sv = synthetic.render_views(tex, layers, c, snr_db=30, seed=0)
            res = ms.estimate_depth(sv.views, c)
            est, tru = res.disparity * c.scan_step_px, sv.disparity * c.scan_step_px
            if scan == 5:
                est, tru = est[2::5, 2::5], tru[2::5, 2::5]
            out[scan] = (est, tru)
        tru = out[1][1]
        jump = 1.0 if name == "slanted plane" else 0.05
        mask = evaluation_mask(tru, edge_margin=1, border=1, jump=jump)
        for scan in (5, 1):
            s = score(out[scan][0], tru, mask, threshold=0.35)
            rows.append({"case": f"{name}, scan {scan} (image px/step)", "badpix": s["badpix"],
                         "mse": s["mse"], "rmse": s["rmse"], "coverage": s["coverage"]})
    # the aberration warp
    tex, layers = synthetic.scene_slanted(shape, -1.5, 1.5, seed=4)
    hv = size // cfg.scan_step_px
    maps = synthetic.aberration_shift_maps(cfg, (hv, hv), curvature=0.15, astig=0.1, coma=0.1)
    sv = synthetic.render_views(tex, layers, cfg, shift_maps=maps, snr_db=30, seed=0)
    m = evaluation_mask(sv.disparity, border=4)
    for label, cal in (("without", None), ("with", maps)):
        s = score(ms.estimate_depth(sv.views, cfg, calibration=cal).disparity, sv.disparity, m)
        rows.append({"case": f"field aberration, {label} calibrated warp", "badpix": s["badpix"],
                     "mse": s["mse"], "rmse": s["rmse"]})
    rows[-1]["rmse_reduction"] = 1 - rows[-1]["rmse"] / rows[-2]["rmse"]
    return rows


HARD_CASES = ((9, 40.0), (5, 30.0))  # views per side, SNR [dB]


def _hard_row(sv, n: int, smoothing, label: str, edges=ms.depth.EdgeSnap(),
              refiner=ms.depth.EdgeRefiner(), speckles=ms.depth.Speckles(),
              visibility=ms.depth.Visibility(), eps=None, radius=None) -> dict:
    t0 = time.perf_counter()
    res = ms.estimate_depth(sv.views, sv.config, smoothing=smoothing, edges=edges, refiner=refiner,
                            speckles=speckles, visibility=visibility, eps=eps,
                            **({} if radius is None else {"radius": radius}))
    dt = time.perf_counter() - t0
    m = np.zeros(sv.disparity.shape, bool)
    m[15:-15, 15:-15] = True
    row = {"case": label, "seconds": dt}
    for t in (0.07, 0.03, 0.01):
        row[f"badpix_{t}"] = score(res.disparity, sv.disparity, m, threshold=t)["badpix"]
    row["mse_x100"] = 100 * score(res.disparity, sv.disparity, m)["mse"]
    row["span"] = [float(res.candidates[0]), float(res.candidates[-1])]
    row["span_covers_truth"] = bool(res.candidates[0] <= sv.disparity.min()
                                    and res.candidates[-1] >= sv.disparity.max())
    row["valid_share"] = float(res.valid[m].mean())
    row["badpix_0.07_valid"] = score(res.disparity, sv.disparity, m & res.valid)["badpix"]
    row["mse_x100_valid"] = 100 * score(res.disparity, sv.disparity, m & res.valid)["mse"]
    return row


def _hard_rows(size: int) -> list[dict]:
    """Default settings on every hard scene (9 x 9 views at 40 dB, 5 x 5 at 30 dB), without
    the learned refiner, without any edge re-decision, and the window aggregation alone
    (``smoothing=None``, the coverage re-decision kept as before) on the 9 x 9 ones: what
    semi-global matching buys."""
    from metasensor.depth.scenes import SCENES, benchmark_scene

    rows = []
    for n, snr in HARD_CASES:
        for kind in SCENES:
            sv = benchmark_scene(kind, nnum=n, size=size, max_disparity=3.0, snr_db=snr, seed=1)
            name = f"hard {n}x{n} scan 1 ±3 {snr:g} dB: {kind} ({size} px)"
            rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(), name))
            rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(), name + ", no speckle removal",
                                  speckles=None))
            rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(),
                                  name + ", no visibility re-decision", visibility=None))
            rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(), name + ", no learned refiner",
                                  refiner=None))
            rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(), name + ", no edge re-decision",
                                  edges=None, refiner=None))
            if n == 9:
                rows.append(_hard_row(sv, n, None, name + ", window only", refiner=None))
            else:
                rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(), name + ", radius 6",
                                      radius=6))
    return rows


def _hard_seed_rows(size: int, count: int = 3) -> list[dict]:
    """The hard scenes again with ``count`` other seeds (shapes, disparities, textures and
    noise drawn anew), default settings only: one seed's row can sit on either side of a line
    by chance (a few edge pixels carry its MSE). The seeds are ones the edge refiner was not
    trained on (``refiner_training.held_out_seeds``)."""
    from metasensor.depth.refiner_training import held_out_seeds
    from metasensor.depth.scenes import SCENES, benchmark_scene

    seeds = held_out_seeds(count)
    rows = []
    for n, snr in HARD_CASES:
        for kind in SCENES:
            for seed in seeds:
                sv = benchmark_scene(kind, nnum=n, size=size, max_disparity=3.0, snr_db=snr,
                                     seed=seed)
                name = f"hard {n}x{n} scan 1 ±3 {snr:g} dB: {kind} ({size} px), seed {seed}"
                rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(), name))
    return rows


def _natural_rows(size: int, seeds=(1, 2, 3, 4), variants: bool = True) -> list[dict]:
    """Photographs in front of a photograph (``scenes.natural_scene``, a family the edge
    re-decision was not tuned on and the learned refiner not trained on), default settings,
    and with ``variants`` also without the visibility re-decision, without the learned refiner,
    without any edge re-decision, and with the edge-aware cost aggregation of scanned views
    (eps 0.01)."""
    from metasensor.depth.scenes import natural_scene

    rows = []
    for n, snr in HARD_CASES:
        for seed in seeds:
            sv = natural_scene(nnum=n, size=size, max_disparity=3.0, snr_db=snr, seed=seed)
            name = f"natural {n}x{n} scan 1 ±3 {snr:g} dB: seed {seed} ({size} px)"
            rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(), name))
            if not variants:
                continue
            rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(),
                                  name + ", no visibility re-decision", visibility=None))
            rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(), name + ", no learned refiner",
                                  refiner=None))
            rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(), name + ", no edge re-decision",
                                  edges=None, refiner=None))
            rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(),
                                  name + ", edge-aware cost aggregation (eps 0.01)",
                                  eps=0.01))
            if n == 5:
                rows.append(_hard_row(sv, n, ms.depth.SemiGlobal(), name + ", radius 6",
                                      radius=6))
    return rows


def run(quick: bool = False) -> list[dict]:
    threads = torch.get_num_threads()
    try:
        rows = _speed_rows(200 if quick else 1000, threads=2)
        torch.set_num_threads(2)
        rows += _accuracy_rows(240 if quick else 480)
        rows += _hard_rows(96 if quick else 192)
        if not quick:
            rows += _hard_seed_rows(192)
        rows += _natural_rows(64 if quick else 128, seeds=(1,) if quick else (1, 2, 3, 4))
        if not quick:  # the 4D light-field benchmark's view size
            rows += _natural_rows(512, variants=False)
    finally:
        torch.set_num_threads(threads)
    return rows


if __name__ == "__main__":  # pragma: no cover
    from _usage import exit_on_help

    exit_on_help(__doc__)
    import sys

    for row in run(quick="--quick" in sys.argv):
        print(row)
