"""Per-frame motion of a realigned view: optical flow between its scan-phase sub-images.

A realigned view with scan period p holds p² sub-images ``S_k = view[r::p, c::p]`` (frame k has
phase ``(r, c) = scan_order[k]``), sampled at view positions ``P = p·(i, j) + (r, c)``. The
flow ``g`` from ``S_k`` to the reference sub-image ``S_ref`` (``S_k(i, j) ≈ S_ref((i, j) + g)``,
sub-image pixels) of a static scene equals the sampling-phase offset
``((r − r_ref)/p, (c − c_ref)/p)``, so the scene motion of sample P, in view pixels, is
``M = p·g − (r − r_ref, c − c_ref)`` and its motion-corrected position at the reference time
is ``Q = P + M`` (the paper's (x + Δx, y + Δy)).

Flow engines: OpenCV DIS (default; ``tests/motion`` compares it with Farneback on aliased
sub-images) or Farneback, each initialised from the already estimated neighbouring frame
(closer in time to the reference), which keeps large motions (many pixels per frame) in range;
or, for turbulence, the smooth non-rigid registration of :mod:`metasensor.align.nonrigid`.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["sub_images", "phase_flows", "registration_flows", "registration_grid",
           "suppress_static",
           "motion_confidence", "occlusions", "FLOW_METHODS"]

FLOW_METHODS = ("dis", "farneback", "registration")  # optical flows, and non-rigid registration
MIN_CONTROL_SPACING = 7.5  # sub-image px between registration control points, at least


def sub_images(view: np.ndarray, order: list[tuple[int, int]]) -> list[np.ndarray]:
    """The scan-phase sub-images ``view[r::p, c::p]`` in scan order (all cropped to one size)."""
    p = int(round(len(order) ** 0.5))
    h, w = view.shape[0] // p, view.shape[1] // p
    return [np.ascontiguousarray(view[r::p, c::p][:h, :w]) for r, c in order]


def _to_u8(img: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return np.clip((img - lo) * (255.0 / max(hi - lo, 1e-12)) + 0.5, 0, 255).astype(np.uint8)


def _engine(method: str):
    import cv2

    if method == "dis":
        # finer than the MEDIUM preset: 8-px patches every 2 px down to the finest scale; this
        # halved the error on a moving object 24 sub-image px wide (measured, tests/motion)
        dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        dis.setPatchSize(8)
        dis.setPatchStride(2)
        dis.setFinestScale(0)
        dis.setVariationalRefinementIterations(10)

        def calc(a, b, init):
            return dis.calc(a, b, init.copy())
        return calc
    if method == "farneback":
        def calc(a, b, init):
            return cv2.calcOpticalFlowFarneback(a, b, init.copy(), 0.5, 4, 9, 5, 5, 1.1,
                                                cv2.OPTFLOW_USE_INITIAL_FLOW)
        return calc
    raise ValueError(f"flow method must be one of {FLOW_METHODS}, got {method!r}")


def _order_by_distance(n: int, ref: int) -> list[int]:
    return sorted((t for t in range(n) if t != ref), key=lambda t: (abs(t - ref), t))


def phase_flows(view: np.ndarray, order: list[tuple[int, int]], reference: int,
                method: str = "dis") -> np.ndarray:
    """Motion ``M`` (view px) of every sample of every frame: ``(T, 2, h, w)`` = (dy, dx) at the
    sample positions of frame k (its sub-image grid). ``M[reference] = 0``.
    """
    p = int(round(len(order) ** 0.5))
    subs = sub_images(np.asarray(view, np.float32), order)
    lo, hi = np.percentile(view, [0.5, 99.5])
    u8 = [_to_u8(s, lo, hi) for s in subs]
    h, w = subs[0].shape
    motion = np.zeros((len(order), 2, h, w), np.float32)
    r0, c0 = order[reference]
    calc = _engine(method)
    for t in _order_by_distance(len(order), reference):
        r, c = order[t]
        nb = t - 1 if t > reference else t + 1
        init = np.stack([(motion[nb, 1] + (c - c0)) / p, (motion[nb, 0] + (r - r0)) / p], -1)
        f = calc(u8[t], u8[reference], np.ascontiguousarray(init, np.float32))
        motion[t, 0] = p * f[..., 1] - (r - r0)
        motion[t, 1] = p * f[..., 0] - (c - c0)
    return motion


def occlusions(view: np.ndarray, order: list[tuple[int, int]], reference: int,
               motion: np.ndarray, method: str = "dis", tol: float = 1.5) -> np.ndarray:
    """Forward–backward consistency of the flow: ``(T, h, w)`` True where a sample of frame k
    has no consistent counterpart at the reference time (occluded or uncovered by a moving
    object). The backward flow b (reference → frame k) taken at the forward target
    ``x + g(x)`` must cancel the forward flow g: ``p·|g(x) + b(x + g(x))| <= tol`` view px."""
    import cv2

    p = int(round(len(order) ** 0.5))
    subs = sub_images(np.asarray(view, np.float32), order)
    lo, hi = np.percentile(view, [0.5, 99.5])
    u8 = [_to_u8(s, lo, hi) for s in subs]
    h, w = subs[0].shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r0, c0 = order[reference]
    calc = _engine(method)
    occ = np.zeros((len(order), h, w), bool)
    for t in range(len(order)):
        if t == reference:
            continue
        r, c = order[t]
        gy = (motion[t, 0] + (r - r0)) / p
        gx = (motion[t, 1] + (c - c0)) / p
        init = -np.stack([gx, gy], -1)
        b = calc(u8[reference], u8[t], np.ascontiguousarray(init, np.float32))
        by = cv2.remap(b[..., 1], xx + gx, yy + gy, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE)
        bx = cv2.remap(b[..., 0], xx + gx, yy + gy, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_REPLICATE)
        occ[t] = p * np.hypot(gy + by, gx + bx) > tol
    return occ


def registration_grid(shape: tuple[int, int], grid: tuple[int, int] = (6, 6),
                      spacing: float = MIN_CONTROL_SPACING) -> tuple[int, int]:
    """Control points per sub-image side: at most ``grid``, and no denser than one per
    ``spacing`` sub-image px, so that the grid's parameters stay well below the sub-image's
    samples (2 x 2 at 13 px, 4 x 4 at 27 px, 6 x 6 at 40 px)."""
    return tuple(max(1, min(int(g), 1 + int((n - 1) // spacing)))
                 for g, n in zip(grid, shape, strict=True))


def registration_flows(view: np.ndarray, order: list[tuple[int, int]], reference: int,
                       grid: tuple[int, int] = (6, 6), iterations: int = 60, device=None
                       ) -> np.ndarray:
    """Smooth per-frame motion for turbulence: non-rigid registration (control grid ``grid``,
    thinned by :func:`registration_grid` on small sub-images,
    :func:`metasensor.align.nonrigid.register_nonrigid_batch`) of the reference sub-image
    onto every other sub-image. Same output as :func:`phase_flows`."""
    from metasensor.align.nonrigid import register_nonrigid_batch
    from metasensor.backend import one_thread_here

    p = int(round(len(order) ** 0.5))
    subs = sub_images(np.asarray(view, np.float32), order)
    grid = registration_grid(subs[0].shape, grid)
    others = [t for t in range(len(order)) if t != reference]
    r0, c0 = order[reference]
    init = np.zeros((len(others), 2, *grid), np.float32)
    for i, t in enumerate(others):  # start from the static phase offset
        init[i, 0] = (order[t][0] - r0) / p
        init[i, 1] = (order[t][1] - c0) / p
    # S_ref(y + g) ≈ S_k(y): g lives on the grid of S_k, as phase_flows' flow does
    with one_thread_here(device):  # small sub-image problems: thread start-up outweighs them
        g = register_nonrigid_batch(np.repeat(subs[reference][None], len(others), 0),
                                    np.stack([subs[t] for t in others]), grid=grid,
                                    iterations=iterations, lr=0.05, levels=2, init=init,
                                    device=device)
    motion = np.zeros((len(order), 2, *subs[0].shape), np.float32)
    for i, t in enumerate(others):
        motion[t, 0] = p * g[i, 0] - (order[t][0] - r0)
        motion[t, 1] = p * g[i, 1] - (order[t][1] - c0)
    return motion


def motion_confidence(view: np.ndarray, order: list[tuple[int, int]], reference: int,
                      motion: np.ndarray, window: float = 2.0) -> np.ndarray:
    """Warping-residual test of the flow: ``(T, h, w)`` ratio of the local residual energy of
    the motion hypothesis to that of the static hypothesis (< 1: the flow explains frame k
    better than "nothing moved"). Both predict the samples of frame k from the reference
    sub-image (cubic interpolation), so the aliasing error of that prediction is common to both
    and cancels in the comparison. ``window``: Gaussian window (sub-image px)."""
    import cv2

    p = int(round(len(order) ** 0.5))
    subs = sub_images(np.asarray(view, np.float32), order)
    ref = subs[reference]
    h, w = ref.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r0, c0 = order[reference]
    ratio = np.zeros((len(order), h, w), np.float32)
    for t, (r, c) in enumerate(order):
        if t == reference:
            continue
        oy, ox = (r - r0) / p, (c - c0) / p
        res = []
        for my, mx in ((0.0, 0.0), (motion[t, 0] / p, motion[t, 1] / p)):
            pred = cv2.remap(ref, xx + ox + mx, yy + oy + my, cv2.INTER_CUBIC,
                             borderMode=cv2.BORDER_REPLICATE)
            res.append(ndimage.gaussian_filter((subs[t] - pred) ** 2, window))
        ratio[t] = res[1] / np.maximum(res[0], 1e-12)
    return ratio


def suppress_static(motion: np.ndarray, threshold: float = 0.5,
                    confidence: np.ndarray | None = None, max_ratio: float = 0.5,
                    min_fraction: float = 0.3, window: float = 2.0) -> np.ndarray:
    """Flow noise on static texture is not motion. A sample position is *moving* in frame k when
    its motion is at least ``threshold`` view px and, if ``confidence`` (:func:`motion_confidence`)
    is given, the motion cuts the warping residual of "no motion" below ``max_ratio``. Motion is
    coherent in time, so the moving region is where at least ``min_fraction`` of the frames
    (locally averaged over a Gaussian ``window``, sub-image px) say so, closed and hole-filled;
    inside it every frame keeps its flow, outside all motion is set to exactly zero.
    Returns a new float32 array ``(T, 2, h, w)``."""
    evidence = np.hypot(motion[:, 0], motion[:, 1]) >= threshold
    if confidence is not None:
        evidence &= confidence < max_ratio
    frac = ndimage.gaussian_filter(evidence.mean(axis=0, dtype=np.float64), window)
    region = frac * len(motion) / max(len(motion) - 1, 1) >= min_fraction
    if region.any():
        region = ndimage.binary_closing(region, iterations=2, border_value=1)
        region = ndimage.binary_fill_holes(region)
        region = ndimage.binary_dilation(region, iterations=1)
    return (motion * region[None, None]).astype(np.float32)
