"""Motion correction of realigned views (the paper's optical-flow motion correction, Methods).

Samples of a realigned view come from ``p²`` frames taken at different times; when the scene
moves, realignment puts them at the wrong place (a periodic grid artefact). For every frame k the
motion ``M_k`` of its samples relative to the reference time is estimated (:mod:`.flow`), each
sample is moved to its corrected position ``Q = P + M`` and the scattered samples are
interpolated back onto the dense grid (:mod:`.scatter`). Samples whose motion is below a
threshold stay exactly where they are, and pixels that no moved sample influences keep their
original value, so static regions come out bit-for-bit unchanged.

Object motion: one flow (centre view, or the sharpest) serves all views, and the interpolation
plan (triangulation) is built once. Turbulence: every view gets its own smooth flow from
non-rigid registration; a registration flow counts only where it makes the dense view more
consistent (:mod:`.consistency`), since between aliased sub-images a static scene yields flows
of about a view pixel; content the sub-images do not resolve (a star field) gives no evidence
(the moving region is then closed and filled as for object motion). Measurements behind these
choices: ``docs/decisions.md`` (2026-11-25, motion evidence).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence

import numpy as np
from scipy import ndimage

from metasensor.motion.consistency import RESOLVED_MIN, dense_confidence, resolved_fraction
from metasensor.motion.evidence import sample_evidence
from metasensor.motion.fallback import FallbackMap, FallbackOptions, blend, fallback_map
from metasensor.motion.flow import (
    FLOW_METHODS,
    motion_confidence,
    occlusions,
    phase_flows,
    registration_flows,
    suppress_static,
)
from metasensor.motion.plan import MotionPlan
from metasensor.sensor.scan import check_scan_order, period_of

__all__ = ["correct_motion", "correct_motion_views", "correct_motion_sequence",
           "estimate_motion", "plan_motion", "MotionPlan"]


def _resolve(scan_order, reference, shape) -> tuple[list[tuple[int, int]], int, int]:
    if scan_order is None or isinstance(scan_order, str):
        # None = row-major (docs/conventions.md); a preset name; period: the default configuration's
        from metasensor.config import SystemConfig

        order = check_scan_order(scan_order, SystemConfig().scan)
    else:
        order = check_scan_order(scan_order, period_of(scan_order))
    p = period_of(order)
    n = len(order)
    ref = n // 2 if reference is None else reference
    if not isinstance(ref, (int, np.integer)) or not 0 <= ref < n:
        raise ValueError(f"reference must be an index into scan_order (0..{n - 1}), got {ref!r}")
    if shape[0] < 12 * p or shape[1] < 12 * p:  # the flow needs sub-images of >= 12 x 12
        raise ValueError(f"view of shape {shape} is too small for scan period {p} "
                         f"(needs at least {12 * p} x {12 * p})")
    return order, p, int(ref)


def _check_options(scatter: str, threshold: float, smooth: float, method: str,
                   max_ratio: float | None = None) -> None:
    """One-line errors for impossible options, before any flow is computed."""
    if scatter not in ("linear", "cubic"):
        raise ValueError(f"scatter must be 'linear' or 'cubic', got {scatter!r}")
    if method not in FLOW_METHODS:
        raise ValueError(f"method must be one of {FLOW_METHODS}, got {method!r}")
    for name, value in (("threshold", threshold), ("smooth", smooth)):
        if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a non-negative number, got {value!r}")
    if max_ratio is not None and not (isinstance(max_ratio, int | float) and 0 < max_ratio <= 1):
        raise ValueError(f"max_ratio must lie in (0, 1] (1 disables the test), got {max_ratio!r}")


def _check_fallback(fallback) -> None:
    if not isinstance(fallback, bool | FallbackOptions):
        raise TypeError(f"fallback must be a bool or FallbackOptions, got "
                        f"{type(fallback).__name__}")


def _check_image(img, name: str) -> np.ndarray:
    img = np.asarray(img)
    if np.iscomplexobj(img) or not np.issubdtype(img.dtype, np.number):
        raise TypeError(f"{name} must hold real numbers, got dtype {img.dtype}")
    if img.ndim != 2:
        raise ValueError(f"{name} must be a 2-D (H, W) view, got shape {img.shape}")
    if not np.all(np.isfinite(img)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return img.astype(np.float32, copy=False)


def estimate_motion(view: np.ndarray, scan_order, reference: int | None = None,
                    method: str = "dis", threshold: float = 0.5, smooth: float = 1.0,
                    max_ratio: float = 0.5, grid: tuple[int, int] = (6, 6), device=None,
                    occlusion_tol: float | None = 1.0, evidence: bool = False) -> np.ndarray:
    """Motion of every view sample relative to the reference time: ``(2, H, W)`` (dy, dx) view
    pixels, exactly zero where the motion is below ``threshold`` (static) or does not explain
    the data better than no motion (residual ratio ≥ ``max_ratio``; 1 disables the test:
    optical flow: warping residual between the sub-images; registration: leave-one-out error
    of the dense view, :func:`.consistency.dense_confidence`, which also gives content the
    sub-images do not resolve no evidence, and a view with none is not registered at all).
    ``method``: "dis" (default),
    "farneback" or "registration" (smooth non-rigid, for turbulence; at most ``grid`` control
    points per sub-image, :func:`.flow.registration_grid`). Inside the moving region, samples that
    fail the forward–backward flow check (``occlusion_tol`` view px; None disables; optical
    flow only) are occluded at the reference time: their motion is NaN and they are left out of
    the interpolation. ``evidence`` (optical flow only): judge every sample against the
    reference frame (:func:`.evidence.sample_evidence`): the moving region grows to every
    coherent change, and samples whose moved prediction does not fit are left out (NaN)."""
    return _motion_and_gain(view, scan_order, reference, method, threshold, smooth, max_ratio,
                            grid, device, occlusion_tol, evidence)[0]


def _motion_and_gain(view, scan_order, reference, method, threshold, smooth, max_ratio, grid,
                     device, occlusion_tol, evidence
                     ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Dense motion ``(2, H, W)``; with ``evidence``, the brightness of every sample relative
    to the reference time ``(H, W)`` (else None); for optical flow, the samples the flow moved
    by at least ``threshold`` before the static suppression ``(T, h, w)`` (else None)."""
    view = _check_image(view, "view")
    order, p, ref = _resolve(scan_order, reference, view.shape)
    occ = resolved = None
    if method == "registration" and max_ratio < 1:
        resolved = resolved_fraction(view, p)
        if not (resolved >= RESOLVED_MIN).any():
            # nothing the sub-images resolve (a star field): no flow could count
            return np.zeros((2, *view.shape), np.float32), None, None
    moved = None
    if method == "registration":
        m = registration_flows(view, order, ref, grid=grid, device=device)
    else:
        m = phase_flows(view, order, ref, method=method)
        if occlusion_tol is not None:
            occ = occlusions(view, order, ref, m, method=method, tol=occlusion_tol)
    m = ndimage.gaussian_filter(m, (0, 0, smooth, smooth)) if smooth > 0 else m
    if method != "registration":
        moved = np.hypot(m[:, 0], m[:, 1]) >= max(threshold, 1e-6)
    conf = None
    if max_ratio < 1 and method == "registration":  # sub-image aliasing: test in the dense view
        conf = dense_confidence(view, order, _dense(m, order, view.shape), resolved=resolved)
    elif max_ratio < 1:
        conf = motion_confidence(view, order, ref, m)
    m = suppress_static(m, threshold=threshold, confidence=conf, max_ratio=max_ratio)
    if evidence and method != "registration":
        ev = sample_evidence(view, order, ref, m, occluded=occ)
        gain = np.broadcast_to(ev.gains[:, None, None, None], (len(order), 1, *m.shape[-2:]))
        gain = np.where(ev.kept[:, None], gain, 1.0)
        gain = _dense(np.repeat(gain, 2, axis=1), order, view.shape)[0]
        return _dense(ev.motion, order, view.shape), gain, moved
    if occ is not None:
        region = np.any(m != 0, axis=(0, 1))
        m[np.broadcast_to((occ & region[None])[:, None], m.shape)] = np.nan
    return _dense(m, order, view.shape), None, moved


def _dense(m: np.ndarray, order, shape) -> np.ndarray:
    """Per-frame motion on the sub-image grids ``(T, 2, h, w)`` → dense field ``(2, H, W)``."""
    p = period_of(order)
    dense = np.zeros((2, *shape), np.float32)
    h, w = m.shape[-2:]
    for t, (r, c) in enumerate(order):
        tgt = dense[:, r::p, c::p]  # samples beyond the common sub-image size: nearest row/col
        iy = np.minimum(np.arange(tgt.shape[1]), h - 1)
        ix = np.minimum(np.arange(tgt.shape[2]), w - 1)
        tgt[...] = m[t][:, iy][:, :, ix]
    return dense


def correct_motion(view_image: np.ndarray, scan_order: Sequence | str | None,
                   reference: int | None = None,
                   *, method: str = "dis", scatter: str = "linear", threshold: float = 0.5,
                   smooth: float = 1.0, max_ratio: float = 0.5,
                   motion: np.ndarray | None = None, evidence: bool = False,
                   fallback: bool | FallbackOptions = True, return_fallback: bool = False):
    """Remove the scan artefacts of moving objects from one realigned view (docs/conventions.md).

    view_image: ``(H, W)``, sample (y, x) taken at frame ``scan_order.index((y % p, x % p))``;
    scan_order: list of (row, col) phases (period = sqrt of its length), or None (row-major) /
    "row-major" / "serpentine" with the default configuration's period (5); reference: index
    into scan_order of the time to align to (default: the middle one).
    method: optical flow "dis" (default) / "farneback", or "registration" (turbulence);
    scatter: "linear" (default: barycentric on the Delaunay triangulation) or "cubic"
    (Clough–Tocher = scipy griddata "cubic", as the paper); threshold: motions below this
    (view px) are flow noise and ignored, as are motions that do not lower the warping residual
    below ``max_ratio`` times that of "no motion"; motion: a precomputed ``(2, H, W)`` field
    (skips the flow); evidence: per-sample gating and brightness matching
    (:func:`estimate_motion`).
    fallback (optical flow only): where the view shows a scan artefact and the flow moved
    samples, but the corrected image still shows the artefact, blend towards the reference
    frame alone, band-limited (:mod:`.fallback`; True: default
    :class:`~.fallback.FallbackOptions`, or an options object; False: off). Warns once when
    most of the moving region fell back.
    return_fallback: also return the :class:`~.fallback.FallbackMap` (where and how much).

    Returns ``(H, W)`` float32 (with ``return_fallback``: ``(image, FallbackMap)``, whose
    weight is all zero when no fallback ran); static regions are returned unchanged.
    """
    view = _check_image(view_image, "view_image")
    _check_options(scatter, threshold, smooth, method, max_ratio)
    _check_fallback(fallback)
    order, p, ref = _resolve(scan_order, reference, view.shape)
    gain = moved = None
    if motion is None:
        motion, gain, moved = _motion_and_gain(view, order, ref, method, threshold, smooth,
                                               max_ratio, (6, 6), None, 1.0, evidence)
    elif np.shape(motion) != (2, *view.shape):
        raise ValueError(f"motion must have shape (2, {view.shape[0]}, {view.shape[1]}), "
                         f"got {np.shape(motion)}")
    plan = MotionPlan(motion, p, scatter=scatter)
    if gain is not None and not plan.empty:
        out = plan.apply(view / gain)
        out = np.where(plan.affected, out, view).astype(np.float32)
    else:
        out = plan.apply(view)
    fmap = FallbackMap(*(np.zeros(view.shape, np.float32),) * 2, 0.0)
    if fallback is not False and moved is not None:
        opts = fallback if isinstance(fallback, FallbackOptions) else None
        fmap = fallback_map(view, out, p, order[ref], moved, opts)
        out = blend(view, out, fmap, p, order[ref])
    return (out, fmap) if return_fallback else out


def plan_motion(view: np.ndarray, scan_order: Sequence | str | None,
                reference: int | None = None, *, method: str = "dis",
                scatter: str = "linear", threshold: float = 0.5, smooth: float = 1.0,
                max_ratio: float = 0.5, fallback: bool | FallbackOptions = True) -> MotionPlan:
    """The correction of :func:`correct_motion` as a reusable plan: the flow of ``view``
    (optical flow, ``method`` "dis" or "farneback") and, with ``fallback``, the fallback map
    judged on that view, for :meth:`MotionPlan.apply` to any views sampled as ``view`` (all
    views of a stack: one flow serves them all). Options as :func:`correct_motion`."""
    view = _check_image(view, "view")
    _check_options(scatter, threshold, smooth, method, max_ratio)
    _check_fallback(fallback)
    if method == "registration":
        raise ValueError("plan_motion needs an optical flow method ('dis' or 'farneback')")
    order, p, ref = _resolve(scan_order, reference, view.shape)
    motion, _, moved = _motion_and_gain(view, order, ref, method, threshold, smooth, max_ratio,
                                        (6, 6), None, 1.0, False)
    plan = MotionPlan(motion, p, scatter=scatter)
    if fallback is not False:
        opts = fallback if isinstance(fallback, FallbackOptions) else None
        fmap = fallback_map(view, plan.apply(view), p, order[ref], moved, opts)
        plan.with_fallback(fmap, order[ref])
    return plan


def sharpest_view(views: np.ndarray) -> tuple[int, int]:
    """(u, v) of the view with the largest mean squared Laplacian (sharpness)."""
    n = views.shape[0]
    score = np.array([[np.mean(ndimage.laplace(np.asarray(views[u, v], np.float32)) ** 2)
                       for v in range(n)] for u in range(n)])
    return tuple(int(i) for i in np.unravel_index(np.argmax(score), score.shape))


def correct_motion_views(views: np.ndarray, scan_order: Sequence, reference: int | None = None,
                         flow_view: tuple[int, int] | str | None = None, *,
                         mode: str = "object", method: str = "dis", scatter: str = "linear",
                         threshold: float = 0.5, smooth: float = 1.0, chunk: int = 8,
                         workers: int = 2, progress: bool = True,
                         fallback: bool | FallbackOptions = True) -> np.ndarray:
    """Motion-correct a view stack ``(nnum, nnum, H, W)`` (returns a new float32 stack).

    mode "object": one flow, from ``flow_view`` ((u, v); None = centre view; "sharpest"),
    serves every view (the paper), one interpolation plan for all views, applied in chunks of
    ``chunk`` views; with ``fallback`` (:func:`correct_motion`), the fallback map of the
    flow view serves every view too (each view blends towards its own reference frame).
    mode "turbulence": every view gets its own smooth flow from non-rigid
    registration, ``workers`` views at a time in threads. Views that are entirely zero
    (outside the coded aperture) are left as they are.
    """
    from tqdm.auto import tqdm

    views = np.asarray(views)
    if views.ndim != 4 or views.shape[0] != views.shape[1]:
        raise ValueError(f"views must have shape (nnum, nnum, H, W), got {views.shape}")
    if np.iscomplexobj(views) or not np.issubdtype(views.dtype, np.number):
        raise TypeError(f"views must hold real numbers, got dtype {views.dtype}")
    if not np.all(np.isfinite(views)):
        raise ValueError("views contain NaN or infinite values")
    n, _, h, w = views.shape
    _check_options(scatter, threshold, smooth, method)
    _check_fallback(fallback)
    if not (isinstance(chunk, int | np.integer) and chunk >= 1):
        raise ValueError(f"chunk must be a positive integer, got {chunk!r}")
    if isinstance(flow_view, str) and flow_view != "sharpest":
        raise ValueError(f"flow_view must be None, 'sharpest' or (u, v), got {flow_view!r}")
    if isinstance(flow_view, tuple | list) and not (
            len(flow_view) == 2 and all(0 <= int(a) < n for a in flow_view)):
        raise ValueError(f"flow_view {flow_view!r} is not a view of the {n} x {n} stack")
    order, p, ref = _resolve(scan_order, reference, (h, w))
    out = views.astype(np.float32, copy=True)
    flat = out.reshape(n * n, h, w)
    live = [i for i in range(n * n) if np.any(flat[i])]
    if mode == "object":
        if flow_view is None:
            flow_view = (n // 2, n // 2)
        elif flow_view == "sharpest":
            flow_view = sharpest_view(views)
        u, v = flow_view
        plan = plan_motion(views[u, v], order, ref, method=method, scatter=scatter,
                           threshold=threshold, smooth=smooth, fallback=fallback)
        if plan.identity:
            return out
        chunks = [live[i:i + chunk] for i in range(0, len(live), chunk)]
        for idx in tqdm(chunks, desc="motion: views", unit="chunk", disable=not progress):
            flat[idx] = plan.apply(flat[idx])
    elif mode == "turbulence":
        from concurrent.futures import ThreadPoolExecutor

        from metasensor.backend import one_thread_here

        def one(i):
            with one_thread_here():  # this worker thread's own count; others keep theirs
                m = estimate_motion(flat[i], order, ref, method="registration",
                                    threshold=threshold, smooth=smooth)
                flat[i] = MotionPlan(m, p, scatter=scatter).apply(flat[i])

        # views in parallel threads (torch, OpenCV and the sparse products release the GIL)
        with ThreadPoolExecutor(max(1, workers)) as pool:
            for _ in tqdm(pool.map(one, live), total=len(live), desc="motion: views",
                          unit="view", disable=not progress):
                pass
    else:
        raise ValueError(f"mode must be 'object' or 'turbulence', got {mode!r}")
    return out


def correct_motion_sequence(frames: np.ndarray, cfg, scan_order=None, moving: str = "mla",
                            times: Sequence[int] | None = None, **kwargs
                            ) -> Iterator[tuple[int, np.ndarray]]:
    """Sliding window over a capture sequence: for every frame time t (whose window of ``T = p²``
    frames ``t − T//2 … t + T//2`` lies inside the sequence, or the given ``times``), realign
    that window and motion-correct it to time t. Frame i of the sequence has scan phase
    ``scan_order[i % T]``. Yields ``(t, views)``; kwargs go to :func:`correct_motion_views`.
    """
    from metasensor.sensor.realign import realign

    frames = np.asarray(frames)
    order = check_scan_order(scan_order, cfg.scan)
    n = len(order)
    if frames.ndim != 3 or frames.shape[0] < n:
        raise ValueError(f"frames must be (T, H, W) with T >= {n}, got shape {frames.shape}")
    half = n // 2
    valid = range(half, frames.shape[0] - (n - 1 - half))
    for t in (valid if times is None else times):
        if t not in valid:
            raise ValueError(f"time {t} has no full scan window in {frames.shape[0]} frames")
        idx = list(range(t - half, t - half + n))
        window_order = [order[i % n] for i in idx]
        views = realign(frames[idx], cfg, scan_order=window_order, moving=moving)
        yield t, correct_motion_views(views, window_order, reference=half, **kwargs)
