"""Synthetic dynamic scenes at the view level, and the scan-artefact measure.

A realigned view sample at ``(Y, X)`` was taken at time ``t = index of (Y % p, X % p) in
scan_order`` (interface.md). A dynamic scene is a fixed texture ``I0`` seen through a time- and
position-dependent displacement: the sample sees ``I0((Y, X) + m_t(Y, X))``. The truth at the
reference time is ``I0((Y, X) + m_ref(Y, X))`` on the dense grid. ``I0`` is sampled by cubic
spline interpolation of a finer scene (``upsample`` times finer), so the test data are not made
with the interpolators used by the correction (no inverse crime).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import ndimage

from metasensor.sensor.scan import check_scan_order, period_of

__all__ = ["natural_scene", "phase_time_map", "dynamic_view", "scan_artifact",
           "rigid_motion", "smooth_random_motion"]


def natural_scene(shape: tuple[int, int], upsample: int = 2, blur: float = 1.0,
                  seed: int = 0) -> np.ndarray:
    """A band-limited natural texture on a grid ``upsample`` times finer than ``shape`` (view px).

    Tiles of scikit-image's photographs (chosen by ``seed``), Gaussian-blurred by ``blur`` view
    pixels so that the views are band-limited as real views are (view sub-aperture diffraction).
    Returns float32 in [0, 1] of shape ``shape * upsample``.
    """
    from skimage import color, data, transform

    imgs = [data.astronaut(), data.coffee(), data.chelsea(), data.rocket()]
    img = color.rgb2gray(imgs[seed % len(imgs)]).astype(np.float64)
    hf, wf = shape[0] * upsample, shape[1] * upsample
    scale = max(hf / img.shape[0], wf / img.shape[1])
    if scale > 1:
        img = transform.rescale(img, scale, order=3, anti_aliasing=False)
    rng = np.random.default_rng(seed)
    y0 = int(rng.integers(0, img.shape[0] - hf + 1))
    x0 = int(rng.integers(0, img.shape[1] - wf + 1))
    img = img[y0:y0 + hf, x0:x0 + wf]
    return ndimage.gaussian_filter(img, blur * upsample).astype(np.float32)


def phase_time_map(shape: tuple[int, int], scan_order) -> np.ndarray:
    """``(H, W)`` int array: the frame index (position in scan_order) of every view sample."""
    order = check_scan_order(scan_order, period_of(scan_order))
    p = period_of(order)
    lut = np.zeros((p, p), np.int64)
    for t, (r, c) in enumerate(order):
        lut[r, c] = t
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    return lut[yy % p, xx % p]


def _sample_scene(scene: np.ndarray, upsample: int, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Cubic-spline value of the fine scene at view coordinates (y, x); mirror outside."""
    fy = (y + 0.5) * upsample - 0.5
    fx = (x + 0.5) * upsample - 0.5
    return ndimage.map_coordinates(scene, [fy, fx], order=3, mode="mirror", prefilter=True)


def dynamic_view(scene: np.ndarray, upsample: int, shape: tuple[int, int], scan_order,
                 motion: Callable, reference: int | None = None, background: np.ndarray | None
                 = None, alpha: Callable | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Simulate one realigned view of a dynamic scene and its truth at the reference time.

    motion(t, Y, X) -> (dy, dx) arrays: displacement (view px) of the scene seen by samples at
    (Y, X) taken at frame t. Optional layered scene: ``alpha(Yd, Xd)`` ∈ [0, 1] is the opacity of
    the moving layer ``scene`` at its own (displaced) coordinates over the static ``background``
    (fine grid, same size). Returns ``(view, truth)``, both float32 ``shape``.
    """
    order = check_scan_order(scan_order, period_of(scan_order))
    n = len(order)
    ref = n // 2 if reference is None else int(reference)
    tmap = phase_time_map(shape, order)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)

    def at(tgrid):
        out = np.zeros(shape, np.float64)
        for t in np.unique(tgrid):
            sel = tgrid == t
            dy, dx = motion(int(t), yy[sel], xx[sel])
            ys, xs = yy[sel] + dy, xx[sel] + dx
            val = _sample_scene(scene, upsample, ys, xs)
            if background is not None:
                a = np.clip(alpha(ys, xs), 0, 1)
                val = a * val + (1 - a) * _sample_scene(background, upsample, yy[sel], xx[sel])
            out[sel] = val
        return out.astype(np.float32)

    return at(tmap), at(np.full(shape, ref))


def rigid_motion(velocity: tuple[float, float], reference: int) -> Callable:
    """Rigid translation at ``velocity`` (dy, dx) view px per frame; zero at the reference frame."""
    def motion(t, y, x):
        return (np.full_like(y, velocity[0] * (t - reference)),
                np.full_like(x, velocity[1] * (t - reference)))
    return motion


def smooth_random_motion(shape: tuple[int, int], frames: int, amplitude: float, scale: float,
                         seed: int = 0) -> tuple[Callable, np.ndarray]:
    """Per-frame random smooth displacement fields (phase-screen-like turbulence distortion).

    Gaussian-filtered white noise with correlation length ``scale`` view px, r.m.s. amplitude
    ``amplitude`` view px, independent per frame. Returns ``(motion, fields (T, 2, H, W))``.
    """
    rng = np.random.default_rng(seed)
    fields = ndimage.gaussian_filter(rng.standard_normal((frames, 2, *shape)),
                                     (0, 0, scale, scale), mode="wrap")
    fields *= amplitude / fields.std(axis=(-2, -1), keepdims=True)
    fields = fields.astype(np.float32)

    def motion(t, y, x):
        coords = [y, x]
        return (ndimage.map_coordinates(fields[t, 0], coords, order=1, mode="nearest"),
                ndimage.map_coordinates(fields[t, 1], coords, order=1, mode="nearest"))
    return motion, fields


def scan_artifact(image: np.ndarray, period: int, region: tuple[slice, slice] | None = None,
                  radius: int = 1, ring: tuple[int, int] = (3, 6)) -> float:
    """Periodic scan artefact: excess spectral energy at the scan lattice frequencies.

    In the (Hann-windowed, mean-removed) power spectrum of ``image[region]``, at every lattice
    frequency (k/p, l/p) cycles/sample except DC, the energy in the bins within ``radius`` is
    compared with the image's own spectral level around it (mean energy per bin in the ring of
    radii ``ring`` bins, times the number of peak bins). Returns
    ``Σ max(E_peak − E_local, 0) / Σ E_local`` (≈ 0 without an artefact). Hand-written.
    """
    img = np.asarray(image, np.float64)
    if region is not None:
        img = img[region]
    h, w = img.shape
    win = np.outer(np.hanning(h), np.hanning(w))
    spec = np.abs(np.fft.fft2((img - img.mean()) * win)) ** 2
    ky = np.fft.fftfreq(h) * h
    kx = np.fft.fftfreq(w) * w
    excess = 0.0
    local_sum = 0.0
    for k in range(period):
        for m in range(period):
            if k == 0 and m == 0:
                continue
            fy, fx = k * h / period, m * w / period
            dy = (ky[:, None] - fy + h / 2) % h - h / 2
            dx = (kx[None, :] - fx + w / 2) % w - w / 2
            dist = np.hypot(dy, dx)
            peak = dist <= radius
            around = (dist >= ring[0]) & (dist <= ring[1])
            e_peak = spec[peak].sum()
            e_local = spec[around].mean() * peak.sum()
            excess += max(e_peak - e_local, 0.0)
            local_sum += e_local
    return float(excess / max(local_sum, 1e-300))
