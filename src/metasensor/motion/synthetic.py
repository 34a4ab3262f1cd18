"""Synthetic dynamic scenes at the view level, and the scan-artefact measure.

A realigned view sample at ``(Y, X)`` was taken at time ``t = index of (Y % p, X % p) in
scan_order`` (docs/conventions.md). A dynamic scene is a fixed texture ``I0`` seen through a time-
and position-dependent displacement: the sample sees ``I0((Y, X) + m_t(Y, X))``. The truth at the
reference time is ``I0((Y, X) + m_ref(Y, X))`` on the dense grid. ``I0`` is sampled by cubic
spline interpolation of a finer scene (``upsample`` times finer), so the test data are not made
with the interpolators used by the correction (no inverse crime).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import ndimage

from metasensor.sensor.scan import check_scan_order, period_of

__all__ = ["natural_scene", "phase_time_map", "dynamic_view", "scan_artifact", "lattice_ratio",
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
                  truth: np.ndarray | None = None, radius: float = 0.02,
                  ring: tuple[float, float] = (0.03, 0.05)) -> float:
    """Periodic scan artefact: spectral energy at the scan lattice frequencies (k/p, l/p)
    cycles/sample (DC excluded), relative to the image's own energy around them.

    Spectra are of the Hann-windowed, mean-removed ``image[region]``. Without ``truth``: the
    excess of the energy within ``radius`` (cycles/sample) of each lattice frequency over the
    image's own level there (its mean energy per bin in the ring ``ring``), summed and divided by
    that level: ``Σ max(E_disk − E_ring_level, 0) / Σ E_ring_level`` (≈ 0 without an artefact).
    With ``truth``: the energy of ``image − truth`` within ``radius`` of the lattice
    frequencies divided by the energy of ``truth`` in the same disks (sensitive also to the
    broadband replicas that smooth motion produces). Hand-written.
    """
    img = np.asarray(image, np.float64)
    ref = None if truth is None else np.asarray(truth, np.float64)
    if region is not None:
        img = img[region]
        ref = None if ref is None else ref[region]
    h, w = img.shape
    win = np.outer(np.hanning(h), np.hanning(w))

    def power(a):
        return np.abs(np.fft.fft2((a - a.mean()) * win)) ** 2

    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    disk = np.zeros((h, w), bool)
    num = den = 0.0
    spec = power(img)
    for k in range(period):
        for m in range(period):
            if k == 0 and m == 0:
                continue
            dy = (fy - k / period + 0.5) % 1.0 - 0.5
            dx = (fx - m / period + 0.5) % 1.0 - 0.5
            dist = np.hypot(dy, dx)
            peak = dist <= radius
            if ref is None:
                level = spec[(dist >= ring[0]) & (dist <= ring[1])].mean() * peak.sum()
                num += max(spec[peak].sum() - level, 0.0)
                den += level
            else:
                disk |= peak
    if ref is not None:
        num, den = power(img - ref)[disk].sum(), power(ref)[disk].sum()
    return float(num / max(den, 1e-300))


def lattice_ratio(image: np.ndarray, period: int, mask: np.ndarray | None = None,
                  radius: float = 0.02, ring: tuple[float, float] = (0.03, 0.05)) -> float:
    """Scan-lattice energy of ``image`` relative to its local spectrum: the spectral energy
    within ``radius`` (cycles/sample) of the scan lattice frequencies (k/p, l/p) (DC excluded)
    over the image's own level there (mean energy per bin in the ``ring`` around each,
    times the disk's bins). About 1 for an image without a scan artefact; larger with one.

    Spectra of the mean-removed bounding box of ``mask`` (boolean ``(H, W)``, the region to
    judge; None: the whole image), windowed by the mask feathered over ``period / 2`` px
    (Gaussian) and a Hann window. Hand-written, as :func:`scan_artifact`.
    """
    img = np.asarray(image, np.float64)
    win = np.ones(img.shape)
    if mask is not None:
        mask = np.asarray(mask, bool)
        ys, xs = np.nonzero(mask)
        if ys.size == 0:
            raise ValueError("mask is empty")
        box = (slice(ys.min(), ys.max() + 1), slice(xs.min(), xs.max() + 1))
        # the region itself, feathered over a lenslet: other content in its box does not count
        win = ndimage.gaussian_filter(mask.astype(np.float64), period / 2)[box]
        img = img[box]
    h, w = img.shape
    if min(h, w) < 4 * period:
        raise ValueError(f"region {h} x {w} is too small for scan period {period}")
    win = win * np.outer(np.hanning(h), np.hanning(w))
    mean = float((img * win).sum() / max(win.sum(), 1e-300))
    spec = np.abs(np.fft.fft2((img - mean) * win)) ** 2
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    num = den = 0.0
    for k in range(period):
        for m in range(period):
            if k == 0 and m == 0:
                continue
            dist = np.hypot((fy - k / period + 0.5) % 1.0 - 0.5,
                            (fx - m / period + 0.5) % 1.0 - 0.5)
            peak = dist <= radius
            num += spec[peak].sum()
            den += spec[(dist >= ring[0]) & (dist <= ring[1])].mean() * peak.sum()
    return float(num / max(den, 1e-300))
