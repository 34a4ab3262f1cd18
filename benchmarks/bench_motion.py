"""Motion correction speed: 5x5 scan, 1,000 x 1,000-pixel views, 113 views (issue 7).

Object mode as in the paper: one optical flow (centre view) serves all views; the interpolation
plan (Delaunay triangulation + barycentric weights) is built once and applied to every view.
Two scenes: a moving object over a static background, and a whole-frame translation (every
sample moves: the worst case for the interpolation). ``quick``: the same 1,000 x 1,000 views but
only 8 views corrected; the 113-view time is extrapolated from the per-view cost (the flow and
the plan do not depend on the number of views), and reported next to the measured figure.
``cpu_s`` (process CPU time) is given next to the wall time: on a shared machine the wall time
also counts other people's jobs.
"""

from __future__ import annotations

import time

import numpy as np

P = 5
ORDER = [(r, c) for r in range(P) for c in range(P)]
REF = len(ORDER) // 2
SIZE = 1000
N_VIEWS = 113


def _scene(kind: str):
    from metasensor.motion.synthetic import dynamic_view, natural_scene, rigid_motion

    shape = (SIZE, SIZE)
    if kind == "object":
        bg = natural_scene(shape, 2, 1.0, seed=1)
        obj = natural_scene(shape, 2, 1.0, seed=2)
        cy, cx, r = SIZE // 2, SIZE // 2, SIZE // 5

        def alpha(y, x):
            return np.clip(r + 0.5 - np.hypot(y - cy, x - cx), 0, 1)

        return dynamic_view(obj, 2, shape, ORDER, rigid_motion((2.0, 1.0), REF),
                            background=bg, alpha=alpha)
    sc = natural_scene(shape, 2, 1.0, seed=0)
    return dynamic_view(sc, 2, shape, ORDER, rigid_motion((1.0, 0.6), REF))


def _psnr(a, b):
    m = (slice(20, -20), slice(20, -20))
    return float(10 * np.log10(1.0 / np.mean((a[m] - b[m]) ** 2)))


def run(quick: bool = False) -> list[dict]:
    from metasensor.motion.correct import MotionPlan, estimate_motion

    n_views = 8 if quick else N_VIEWS
    rows = []
    for kind in ("object", "rigid"):
        view, truth = _scene(kind)
        gains = np.linspace(0.5, 1.0, n_views, dtype=np.float32)
        stack = gains[:, None, None] * view[None]
        c0 = time.process_time()
        t0 = time.perf_counter()
        motion = estimate_motion(view, ORDER, REF)
        t1 = time.perf_counter()
        plan = MotionPlan(motion, P)
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
        total = (t3 - t0)
        rows.append({
            "scene": kind, "views": n_views, "view_px": f"{SIZE}x{SIZE}",
            "moving_frac": float(plan.affected.mean()) if not plan.empty else 0.0,
            "flow_s": t1 - t0, "plan_s": t2 - t1, "apply_per_view_s": per_view,
            "total_s": total, "cpu_s": cpu,
            "total_113_views_s": (t2 - t0) + per_view * N_VIEWS,
            "measured_or_extrapolated": "measured" if n_views == N_VIEWS else "extrapolated",
            "apply_vs_memcopy": per_view / max(copy_s / n_views, 1e-9),
            "psnr_plain_db": _psnr(view, truth), "psnr_corrected_db": _psnr(out[-1], truth),
        })
    return rows


if __name__ == "__main__":  # pragma: no cover
    import sys

    for row in run(quick="--quick" in sys.argv):
        print(row)
