"""Motion correction speed: 5x5 scan, 1,000 x 1,000-pixel views, 113 views; and the walking
figure (articulated motion, occlusion, blur, brightness drift).

Object mode as in the paper: one optical flow (centre view) serves all views; the interpolation
plan (Delaunay triangulation + barycentric weights) and the fallback map (where the corrected
view still shows the scan artefact, :mod:`metasensor.motion.fallback`) are built once and
applied to every view. Each speed scene runs with the fallback and without it (the pipeline
before the fallback), alternating, twice each in one process; the faster run of each is
reported, with the ratios of wall and CPU time.
Two scenes: a moving object over a static background, and a whole-frame translation (every
sample moves: the worst case for the interpolation). ``quick``: 400 x 400 views, 8 views; the
1,000 x 1,000, 113-view time is extrapolated (flow and plan scale with the pixel count,
(1000/400)², and do not depend on the number of views; the per-view cost scales with both) and
labelled "extrapolated" (linear in the pixel count; the triangulation is n log n, so this
slightly underestimates); the full mode measures it.
``cpu_s`` (process CPU time) is given next to the wall time: on a shared machine the wall time
also counts other people's jobs.

Walker rows (:func:`metasensor.simulation.walker.walker_view`, one view, reference = middle
frame): ``lattice_ratio`` (energy at the scan-lattice frequencies over the local spectrum, about
1 without an artefact) on the moving region, of the plain realignment, the corrected view and a
static capture of the same scene; the static region (> 6 px from the moving region) before and
after: correlation and detail (r.m.s. Laplacian) ratio; the share of the moving region that fell
back to the reference frame alone; r.m.s. error against the truth (the scene at the reference
time, unblurred) on the moving region, of each output and of the reference frame alone
(``reference_alone``: the fallback everywhere). Quick: 300 px scenes only.
"""

from __future__ import annotations

import time

import numpy as np

P = 5
ORDER = [(r, c) for r in range(P) for c in range(P)]
REF = len(ORDER) // 2
SIZE = 1000
N_VIEWS = 113


def _scene(kind: str, size: int):
    from metasensor.motion.synthetic import dynamic_view, natural_scene, rigid_motion

    shape = (size, size)
    if kind == "object":
        bg = natural_scene(shape, 2, 1.0, seed=1)
        obj = natural_scene(shape, 2, 1.0, seed=2)
        cy, cx, r = size // 2, size // 2, size // 5

        def alpha(y, x):
            return np.clip(r + 0.5 - np.hypot(y - cy, x - cx), 0, 1)

        return dynamic_view(obj, 2, shape, ORDER, rigid_motion((2.0, 1.0), REF),
                            background=bg, alpha=alpha)
    sc = natural_scene(shape, 2, 1.0, seed=0)
    return dynamic_view(sc, 2, shape, ORDER, rigid_motion((1.0, 0.6), REF))


def _psnr(a, b):
    m = (slice(20, -20), slice(20, -20))
    return float(10 * np.log10(1.0 / np.mean((a[m] - b[m]) ** 2)))


def _figure(view, out, truth, path, size):
    """Plain realignment / corrected / truth, a 200 x 200 crop across the object's edge."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from metasensor.io.atomic import atomic_path

    h = size // 10
    c = (slice(size // 2 - 3 * h, size // 2 - h), slice(size // 2 - h, size // 2 + h))
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.3))
    for ax, img, title in zip(axes, (view, out, truth),
                              ("plain realignment", "motion-corrected", "truth"), strict=True):
        ax.imshow(img[c], cmap="gray", vmin=0, vmax=1)
        ax.set_title(title if img is truth else f"{title}: {_psnr(img, truth):.1f} dB")
        ax.axis("off")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def _speed_row(kind: str, size: int, n_views: int, fallback: bool) -> dict:
    from metasensor.motion.correct import plan_motion

    scale = (SIZE / size) ** 2
    view, truth = _scene(kind, size)
    gains = np.linspace(0.5, 1.0, n_views, dtype=np.float32)
    stack = gains[:, None, None] * view[None]
    c0 = time.process_time()
    t0 = time.perf_counter()
    plan = plan_motion(view, ORDER, REF, fallback=fallback)
    t2 = time.perf_counter()
    out = np.empty_like(stack)
    for i in range(0, n_views, 8):
        out[i:i + 8] = plan.apply(stack[i:i + 8])
    t3 = time.perf_counter()
    cpu = time.process_time() - c0
    copy_t0 = time.perf_counter()
    _ = stack.copy()
    copy_s = time.perf_counter() - copy_t0
    per_view = (t3 - t2) / n_views
    total = t3 - t0
    fmap = plan.fallback[0] if plan.fallback is not None else None
    return {
        "scene": kind, "fallback": fallback, "views": n_views, "view_px": f"{size}x{size}",
        "moving_frac": float(plan.affected.mean()) if not plan.empty else 0.0,
        "fallback_frac": fmap.fraction if fmap is not None else 0.0,
        "plan_s": t2 - t0, "apply_per_view_s": per_view,
        "total_s": total, "cpu_s": cpu,
        "total_113x1000px_s": scale * ((t2 - t0) + per_view * N_VIEWS),
        # CPU time, extrapolated like the wall time (identical to cpu_s in full mode)
        "cpu_113x1000px_s": scale * cpu * ((t2 - t0) + per_view * N_VIEWS) / max(total, 1e-9),
        "measured_or_extrapolated": "measured" if size == SIZE else "extrapolated",
        "apply_vs_memcopy": per_view / max(copy_s / n_views, 1e-9),
        "psnr_plain_db": _psnr(view, truth), "psnr_corrected_db": _psnr(out[-1] / gains[-1],
                                                                        truth),
        "_images": (view, out[-1] / gains[-1], truth),
    }


WALKERS = ((300, 200.0, 0), (300, 200.0, 1), (300, 200.0, 2), (300, 200.0, 3),
           (400, 300.0, 1), (400, 250.0, 3))


def _walker_row(size: int, height: float, seed: int) -> dict:
    import warnings

    from scipy import ndimage

    from metasensor.motion.correct import correct_motion
    from metasensor.motion.fallback import reference_upsample
    from metasensor.motion.synthetic import lattice_ratio
    from metasensor.simulation.walker import WalkerOptions, walker_view

    cap = walker_view((size, size), ORDER, REF, WalkerOptions(height=height, seed=seed))
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out, fmap = correct_motion(cap.view, ORDER, REF, return_fallback=True)
    seconds = time.perf_counter() - t0
    plain = correct_motion(cap.view, ORDER, REF, fallback=False)
    mv = cap.moving
    still = ~ndimage.binary_dilation(mv, iterations=6)

    def detail(img):
        return float(np.sqrt(np.mean(ndimage.laplace(img.astype(np.float64))[still] ** 2)))

    alone = reference_upsample(cap.view, P, ORDER[REF])
    images = (("view", cap.view), ("no_fallback", plain), ("corrected", out),
              ("static", cap.static), ("reference_alone", alone))
    lat = {k: lattice_ratio(img, P, mv) for k, img in images}
    rmse = {f"rmse_{k}": float(np.sqrt(np.mean((img[mv] - cap.truth[mv]) ** 2)))
            for k, img in images}
    return {
        "scene": f"walker {size}px h{height:g} seed {seed}", "fallback": True, "views": 1,
        "view_px": f"{size}x{size}", "moving_frac": float(mv.mean()),
        "fallback_frac": fmap.fraction, "total_s": seconds,
        "lattice_view": lat["view"], "lattice_no_fallback": lat["no_fallback"],
        "lattice_corrected": lat["corrected"], "lattice_static": lat["static"],
        "lattice_vs_static": lat["corrected"] / lat["static"],
        "static_corr": float(np.corrcoef(out[still], cap.view[still])[0, 1]),
        "static_detail_ratio": detail(out) / detail(cap.view),
        **rmse,
    }


def run(quick: bool = False) -> list[dict]:
    from pathlib import Path

    n_views = 8 if quick else N_VIEWS
    size = 400 if quick else SIZE
    rows = []
    for kind in ("object", "rigid"):
        # without and with the fallback, alternating, twice each: the faster run of each
        # (a shared machine's load comes and goes)
        runs = [_speed_row(kind, size, n_views, fb) for fb in (False, True, False, True)]
        pair = [min(runs[i::2], key=lambda r: r["total_s"]) for i in (0, 1)]
        pair[1]["time_vs_no_fallback"] = pair[1]["total_s"] / max(pair[0]["total_s"], 1e-9)
        pair[1]["cpu_vs_no_fallback"] = pair[1]["cpu_s"] / max(pair[0]["cpu_s"], 1e-9)
        if kind == "object":
            view, out, truth = pair[1]["_images"]
            _figure(view, out, truth, Path(__file__).resolve().parent / "results"
                    / ("motion_quick.png" if quick else "motion.png"), size)
        for row in pair:
            row.pop("_images")
        rows += pair
    for size_w, height, seed in WALKERS:
        if not (quick and size_w > 300):
            rows.append(_walker_row(size_w, height, seed))
    return rows


if __name__ == "__main__":  # pragma: no cover
    from _usage import exit_on_help

    exit_on_help(__doc__)
    import sys

    for row in run(quick="--quick" in sys.argv):
        print(row)
