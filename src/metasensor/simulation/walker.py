"""A walking figure seen through a scan: articulated, non-rigid motion with occlusion.

What real movers do that a translating or smoothly warped texture does not: the figure is ten
rigid parts (torso, head, upper/lower arms and legs) whose joint angles swing with the gait
phase, so its motion field is piecewise and discontinuous; the parts occlude each other and the
background, and a static post in front of the path occludes the figure (occlusion and
disocclusion); every frame integrates the motion over its exposure (motion blur); the figure's
brightness drifts from frame to frame (shading); and it may move by more than a lenslet (``p``
view px) between scan frames.

The model works at the level of one realigned view (as :mod:`metasensor.motion.synthetic`): the
sample at view position ``(Y, X)`` was taken at frame ``t`` (its scan phase's place in
``scan_order``) and records the scene averaged over that frame's exposure,
``(1/S) Σ_s scene(t + e·(s + ½)/S − e/2, Y, X)`` (``S`` sub-steps, exposure ``e`` frames).
Each part carries its own texture in body coordinates (along and across the limb), so the
texture moves with the limb. Hand-written (no library renders articulated figures into a
scan's sample lattice).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

__all__ = ["WalkerOptions", "WalkerCapture", "walker_view"]

# (name, parent joint, length, radius, base angle [deg from +y, i.e. hanging down], swing
# amplitude [deg], swing phase [cycles]); lengths and radii in units of the figure height.
# Drawn in this order (back to front): far limbs, torso, head, near limbs.
_PARTS = (
    ("far upper arm", "shoulder", 0.17, 0.05, 0.0, 30.0, 0.0),
    ("far lower arm", "far upper arm", 0.16, 0.045, -15.0, 20.0, 0.1),
    ("far thigh", "hip", 0.24, 0.07, 0.0, 28.0, 0.5),
    ("far shin", "far thigh", 0.24, 0.055, 20.0, 25.0, 0.75),
    ("torso", "hip", 0.32, 0.11, 180.0, 3.0, 0.25),
    ("head", "neck", 0.1, 0.08, 180.0, 2.0, 0.25),
    ("near thigh", "hip", 0.24, 0.07, 0.0, 28.0, 0.0),
    ("near shin", "near thigh", 0.24, 0.055, 20.0, 25.0, 0.25),
    ("near upper arm", "shoulder", 0.17, 0.05, 0.0, 30.0, 0.5),
    ("near lower arm", "near upper arm", 0.16, 0.045, -15.0, 20.0, 0.6),
)


@dataclass(frozen=True)
class WalkerOptions:
    """Settings of the walking-figure scene (lengths in view px, times in frames).

    height : figure height. speed : walking speed along +x per frame (more than the scan period
    ``p`` is motion larger than a lenslet between frames). gait : gait cycles per frame.
    exposure : share of a frame the shutter is open (0 = no motion blur). substeps : time
    samples per exposure. brightness : relative brightness change of the figure per frame.
    post : draw a static post in front of the path (occludes the figure). seed : textures.
    """

    height: float = 150.0
    speed: float = 1.0
    gait: float = 0.03
    exposure: float = 0.8
    substeps: int = 4
    brightness: float = 0.01
    post: bool = True
    seed: int = 0

    def __post_init__(self):
        for name in ("height", "speed", "gait", "exposure", "brightness"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
        if self.height < 20:
            raise ValueError(f"height must be at least 20 view px, got {self.height!r}")
        if not 0 <= self.exposure <= 1:
            raise ValueError(f"exposure must lie in [0, 1], got {self.exposure!r}")
        if not (isinstance(self.substeps, int) and 1 <= self.substeps <= 64):
            raise ValueError(f"substeps must be an integer in [1, 64], got {self.substeps!r}")
        if abs(self.brightness) >= 0.04:
            raise ValueError(f"brightness must lie in (-0.04, 0.04) per frame, got "
                             f"{self.brightness!r}")


@dataclass(frozen=True)
class WalkerCapture:
    """One realigned view of the walking figure and its references (all ``(H, W)`` float32).

    view : the samples as the scan took them. static : a capture of the same scene with the
    figure frozen at the reference time (every sample from the reference frame). truth : the
    scene at the reference time without motion blur. moving : bool, pixels that the figure
    covers at some time of the scan (the moving region); its complement is static.
    """

    view: np.ndarray
    static: np.ndarray
    truth: np.ndarray
    moving: np.ndarray


def _texture(shape: tuple[int, int], seed: int, scale: float) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = ndimage.gaussian_filter(rng.standard_normal(shape), scale, mode="wrap")
    t = (t - t.mean()) / (t.std() + 1e-12)
    return t


def _pose(opt: WalkerOptions, tau: float, origin: tuple[float, float]) -> list[tuple]:
    """Segments ``(name, (y0, x0), (y1, x1), radius)`` of the figure at time ``tau``."""
    h = opt.height
    phase = 2 * math.pi * opt.gait * tau
    bob = 0.015 * h * math.cos(2 * phase)
    hip = (origin[0] - 0.48 * h + bob, origin[1] + opt.speed * tau)
    joints = {"hip": hip}
    segs = []
    for name, parent, length, radius, base, amp, ph in _PARTS:
        if parent == "shoulder":
            start = (joints["hip"][0] - 0.3 * h, joints["hip"][1])
        elif parent == "neck":
            start = (joints["hip"][0] - 0.34 * h, joints["hip"][1])
        else:
            start = joints.get(parent + " end", joints.get(parent))
        ang = math.radians(base + amp * math.sin(phase + 2 * math.pi * ph))
        if parent not in ("hip", "shoulder", "neck"):  # lower limbs hang from the upper ones
            ang += joints[parent + " angle"]
        end = (start[0] + length * h * math.cos(ang), start[1] + length * h * math.sin(ang))
        joints[name + " end"] = end
        joints[name + " angle"] = ang
        segs.append((name, start, end, radius * h))
    return segs


def _render(opt: WalkerOptions, tau: float, y: np.ndarray, x: np.ndarray, bg: np.ndarray,
            tex: np.ndarray, origin) -> np.ndarray:
    """Scene value at the view pixels (y, x) (integer arrays) at time ``tau`` (frames from the
    reference)."""
    out = bg[y, x].astype(np.float64)
    gain = 1.0 + opt.brightness * tau
    for k, (_, (y0, x0), (y1, x1), r) in enumerate(_pose(opt, tau, origin)):
        near = ((y >= min(y0, y1) - r - 1) & (y <= max(y0, y1) + r + 1)
                & (x >= min(x0, x1) - r - 1) & (x <= max(x0, x1) + r + 1))
        if not near.any():
            continue
        yn, xn = y[near].astype(np.float64), x[near].astype(np.float64)
        dy, dx = y1 - y0, x1 - x0
        length2 = max(dy * dy + dx * dx, 1e-9)
        s = np.clip(((yn - y0) * dy + (xn - x0) * dx) / length2, 0.0, 1.0)
        dist = np.hypot(yn - (y0 + s * dy), xn - (x0 + s * dx))
        alpha = np.clip(r + 0.5 - dist, 0.0, 1.0)
        # body coordinates: along the limb (px from its start) and across it (signed)
        along = s * math.sqrt(length2)
        across = ((yn - y0) * dx - (xn - x0) * dy) / math.sqrt(length2)
        ty = (along + 40.0 * k) % tex.shape[0]
        tx = (across + tex.shape[1] / 2) % tex.shape[1]
        val = 0.55 + 0.1 * ndimage.map_coordinates(tex, [ty, tx], order=1, mode="wrap")
        out[near] = out[near] * (1 - alpha) + gain * val * alpha
    return out


def walker_view(shape: tuple[int, int], scan_order, reference: int | None = None,
                options: WalkerOptions | None = None) -> WalkerCapture:
    """Simulate one realigned view of a figure walking in front of a static textured scene.

    Parameters
    ----------
    shape : view shape (H, W) [view px].
    scan_order : scan phases (row, col) in time order (period ``p = sqrt(len)``).
    reference : index into ``scan_order`` of the time the correction aligns to (default: the
        middle frame).
    options : :class:`WalkerOptions` (default settings if None).

    Returns
    -------
    WalkerCapture : the view, a static capture of the same scene, the truth at the reference
    time and the moving region.
    """
    from metasensor.motion.synthetic import natural_scene, phase_time_map
    from metasensor.sensor.scan import check_scan_order, period_of

    opt = WalkerOptions() if options is None else options
    if not isinstance(opt, WalkerOptions):
        raise TypeError(f"options must be WalkerOptions, got {type(opt).__name__}")
    order = check_scan_order(scan_order, period_of(scan_order))
    n = len(order)
    ref = n // 2 if reference is None else int(reference)
    if not 0 <= ref < n:
        raise ValueError(f"reference must be in [0, {n - 1}], got {reference!r}")
    h, w = int(shape[0]), int(shape[1])
    if h < opt.height + 10 or w < 2 * opt.height / 3:
        raise ValueError(f"shape {shape} is too small for a figure {opt.height} view px high")
    bg = natural_scene((h, w), 1, 1.0, seed=opt.seed).astype(np.float64)
    # cloth: coarse folds and fine weave (the fine part aliases in the scan's sub-images)
    tex = _texture((256, 96), opt.seed + 1, 4.0) + 0.4 * _texture((256, 96), opt.seed + 2, 1.2)
    origin = (0.5 * h + 0.5 * opt.height, 0.5 * w)
    yy, xx = np.mgrid[0:h, 0:w]
    tmap = phase_time_map((h, w), order)
    post = None
    if opt.post:  # a static post in front, 8 px wide, right of the reference position
        cx = 0.5 * w + 0.25 * opt.height
        post = np.clip(4.5 - np.abs(xx - cx), 0, 1)
        post_val = 0.25 + 0.05 * np.sin(yy / 3.0)  # a faint texture of its own

    def exposure(t: int, sel) -> np.ndarray:
        acc = np.zeros(int(sel.sum()))
        for s in range(opt.substeps):
            tau = (t - ref) + opt.exposure * ((s + 0.5) / opt.substeps - 0.5)
            acc += _render(opt, tau, yy[sel], xx[sel], bg, tex, origin)
        return acc / opt.substeps

    def compose(img):
        if post is not None:
            img = img * (1 - post) + post_val * post
        return img.astype(np.float32)

    view = np.zeros((h, w))
    for t in range(n):
        sel = tmap == t
        view[sel] = exposure(t, sel)
    full = np.ones((h, w), bool)
    static = exposure(ref, full).reshape(h, w)
    truth = _render(opt, 0.0, yy.ravel(), xx.ravel(), bg, tex, origin).reshape(h, w)
    # the moving region: where the figure is at some time of the scan
    moving = np.zeros((h, w), bool)
    for t in range(n):
        tau = t - ref
        diff = np.abs(_render(opt, tau, yy.ravel(), xx.ravel(), bg, tex, origin) - bg.ravel())
        moving |= diff.reshape(h, w) > 1e-6
    moving |= np.abs(view - static) > 1e-6  # and where the blurred exposures touch it
    if post is not None:
        moving &= post < 1.0  # the opaque post hides it
    return WalkerCapture(compose(view), compose(static), compose(truth), moving)
