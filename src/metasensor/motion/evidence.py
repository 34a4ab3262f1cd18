"""Per-sample evidence for motion correction: does a flow-moved sample fit the reference time?

Real movers (a walking person) move non-rigidly, occlude and uncover, blur within a frame and
change shading, so an optical flow between scan-phase sub-images is wrong on part of them, and a
wrongly placed sample is itself a scan artefact. Every sample of frame k is therefore judged
against the reference frame's sub-image ``S_ref`` (whose samples are exact at the reference
time): its prediction under the static hypothesis, ``S_ref`` at the phase offset, and under the
motion hypothesis, ``g_k · S_ref`` at the offset plus the flow (cubic interpolation; ``g_k`` the
frame's brightness relative to the reference, fitted on the moving samples). The prediction
error of static samples outside any motion (the sub-images' aliasing) sets the tolerance,
``τ_k = k_sigma × 1.4826 × MAD``; then

- a sample whose static prediction fails (``|r₀| > τ``) where many frames' samples do the same
  (a coherent change) within ``grow`` sub-image px of the flow's moving region belongs to the
  moving region, even where the flow saw no motion;
- inside the moving region a sample is kept, at its moved position and with its brightness
  scaled by ``1 / g_k``, only if its motion prediction fits (``|r₁| <= τ``, or
  ``|r₁| <= better · |r₀|``: the aliasing of a textured mover can exceed ``τ``) and it passed the
  forward-backward flow check; otherwise it is left out (NaN motion) and the interpolation
  fills its place from the samples that fit, the reference frame's among them (graceful
  fallback: the reference frame alone gives a coarser but artefact-free picture).

Hand-written (the gating is specific to the scan's sample lattice).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from metasensor.motion.flow import sub_images

__all__ = ["SampleEvidence", "sample_evidence"]


@dataclass(frozen=True)
class SampleEvidence:
    """Result of :func:`sample_evidence` (per frame on its sub-image grid ``(T, h, w)``).

    motion : (T, 2, h, w) view px, NaN for samples left out; zero outside the moving region.
    gains : (T,) brightness of each frame's moving samples relative to the reference.
    region : (h, w) bool, the moving region (sub-image grid).
    kept : (T, h, w) bool, samples of the moving region placed by their flow.
    """

    motion: np.ndarray
    gains: np.ndarray
    region: np.ndarray
    kept: np.ndarray


def _predict(ref: np.ndarray, oy: np.ndarray | float, ox: np.ndarray | float) -> np.ndarray:
    import cv2

    h, w = ref.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return cv2.remap(ref, (xx + ox).astype(np.float32), (yy + oy).astype(np.float32),
                     cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)


def sample_evidence(view: np.ndarray, order: list[tuple[int, int]], reference: int,
                    motion: np.ndarray, occluded: np.ndarray | None = None,
                    k_sigma: float = 3.0, min_fraction: float = 0.3,
                    grow: int = 0, better: float = 0.5) -> SampleEvidence:
    """Judge every sample's flow (see the module docstring).

    view : (H, W) realigned view; order : scan phases; reference : index into ``order``.
    motion : (T, 2, h, w) per-frame motion [view px] (:func:`.flow.phase_flows` after
        :func:`.flow.suppress_static`: zero outside the flow's moving region).
    occluded : (T, h, w) bool, samples failing the forward-backward check (or None).
    k_sigma : tolerance in robust standard deviations of the static prediction error.
    min_fraction : share of the frames whose static prediction must fail, locally, for a
        change to count as motion.
    better : a moved sample whose prediction error is at most this share of its static one
        fits too.
    grow : how far (sub-image px) the moving region grows from the flow's by such changes.
    """
    p = int(round(len(order) ** 0.5))
    subs = [s.astype(np.float32) for s in sub_images(np.asarray(view, np.float32), order)]
    ref = subs[reference]
    n = len(order)
    h, w = ref.shape
    r0, c0 = order[reference]
    flow_region = np.any(motion != 0, axis=(0, 1))
    res0 = np.zeros((n, h, w), np.float32)
    pred1 = np.zeros((n, h, w), np.float32)
    for t, (r, c) in enumerate(order):
        oy, ox = (r - r0) / p, (c - c0) / p
        res0[t] = subs[t] - _predict(ref, oy, ox)
        pred1[t] = _predict(ref, oy + motion[t, 0] / p, ox + motion[t, 1] / p)
    # tolerance per frame from the static samples (outside the flow's region, away from it)
    far = ~ndimage.binary_dilation(flow_region, iterations=2)
    tol = np.zeros(n, np.float32)
    for t in range(n):
        vals = res0[t][far] if far.sum() > 16 else res0[t].ravel()
        mad = np.median(np.abs(vals - np.median(vals)))
        tol[t] = k_sigma * 1.4826 * max(float(mad), 1e-6 * float(np.ptp(ref) + 1e-12))
    changed = np.abs(res0) > tol[:, None, None]
    changed[reference] = False
    frac = ndimage.gaussian_filter(changed.mean(axis=0, dtype=np.float64), 1.0) * n / (n - 1)
    # coherent changes near the flow's region (a static scene's aliasing, however strong at
    # its edges, has no flow region to grow from)
    near = ndimage.binary_dilation(flow_region, iterations=grow) if grow > 0 else flow_region
    region = flow_region | ((frac >= min_fraction) & near)
    if region.any():
        region = ndimage.binary_fill_holes(ndimage.binary_closing(region, iterations=2,
                                                                  border_value=1))
    # brightness of each frame's moving samples relative to the reference (robust ratio)
    gains = np.ones(n, np.float32)
    for t in range(n):
        a, b = subs[t][region], pred1[t][region]
        ok = (b > 1e-6 * max(float(np.abs(ref).max()), 1e-30)) & (np.abs(a - b) <= 2 * tol[t])
        if t != reference and ok.sum() > 32:
            gains[t] = float(np.clip(np.median(a[ok] / b[ok]), 0.5, 2.0))
    res1 = subs - gains[:, None, None] * pred1
    # fits: within the tolerance, or far better than the static hypothesis (the sub-images'
    # aliasing of a textured mover can exceed the static background's tolerance)
    fits = (np.abs(res1) <= tol[:, None, None]) | (np.abs(res1) <= better * np.abs(res0))
    kept = fits & region[None]
    if occluded is not None:
        kept &= ~occluded
    kept[reference] = region  # the reference frame is exact at the reference time
    out = np.where(region[None, None], motion, 0.0).astype(np.float32)
    drop = region[None] & ~kept
    out[np.broadcast_to(drop[:, None], out.shape)] = np.nan
    return SampleEvidence(motion=out, gains=gains, region=region, kept=kept)
