"""Sanity checks of raw frames against the configured lenslet grid, and the calibration's
goodness of fit (hand-written on numpy FFTs: no library measures a lenslet lattice).

- :func:`lattice_period`: the lenslet period of a stack of frames from the sum of their power
  spectra (shift-invariant, so the frames of an MLA scan add up as well as those of an image
  scan), with the lattice peak's strength over the spectrum's median in the search ring.
- :func:`lattice_residual`: how well one lattice (pitch, rotation, point) describes the whole
  field: the frame is cut into tiles of a few lenslets, each tile's lattice point is measured
  from the phases of the two lattice components there, and the r.m.s. distance [px] of those
  points from the model's nearest lattice point is returned (tiles without lenslet contrast,
  e.g. between sparse beads, are skipped).
"""

from __future__ import annotations

import math

import numpy as np
from scipy import fft as sfft
from scipy import ndimage

from metasensor.config import MAX_NNUM

__all__ = ["lattice_period", "lattice_residual", "PERIOD_TOLERANCE", "MIN_PEAK_STRENGTH",
           "FAR_PEAK_STRENGTH", "MAX_RESIDUAL_PX", "check_scan_offsets", "period_mismatch"]

PERIOD_TOLERANCE = 0.02  # realign refuses frames whose period differs more from nnum
MIN_PEAK_STRENGTH = 12.0  # a lattice peak less prominent than this is not trusted
FAR_PEAK_STRENGTH = 3 * MIN_PEAK_STRENGTH  # ... nor one far from nnum less prominent than this
MAX_RESIDUAL_PX = 0.3  # calibrate refuses a lattice that misses the field's tiles by more
_CROP = 512
_MIN_PERIOD = 3.0  # the smallest lenslet period searched [px]
_PAD = 4


def _power(frame: np.ndarray, side: int) -> np.ndarray:
    img = np.asarray(frame, dtype=np.float64)
    h, w = img.shape
    y0, x0 = max(0, (h - _CROP) // 2), max(0, (w - _CROP) // 2)
    img = img[y0:y0 + _CROP, x0:x0 + _CROP]
    win = np.outer(np.hanning(img.shape[0]), np.hanning(img.shape[1]))
    spec = sfft.rfft2((img - img.mean()) * win, s=(side, side), workers=1)
    return spec.real**2 + spec.imag**2


def _peak(power: np.ndarray, sel: np.ndarray, side: int) -> tuple[np.ndarray, float]:
    """Sub-bin position (cycles/px) of the largest value of ``power`` in ``sel`` (parabola
    through the neighbours along each axis) and that value."""
    k = int(np.argmax(np.where(sel, power, -1.0)))
    iy, ix = np.unravel_index(k, power.shape)
    pos = []
    for axis, i in ((0, iy), (1, ix)):
        n = power.shape[axis]
        idx = [(iy, ix)] * 3
        if axis == 0:
            idx = [((iy - 1) % n, ix), (iy, ix), ((iy + 1) % n, ix)]
        elif 0 < ix < n - 1:
            idx = [(iy, ix - 1), (iy, ix), (iy, ix + 1)]
        a, b, c = (math.log(max(power[j], 1e-300)) for j in idx)
        den = a - 2 * b + c
        pos.append(i + (0.5 * (a - c) / den if den < 0 else 0.0))
    fy = pos[0] if pos[0] <= side / 2 else pos[0] - side
    return np.array([fy / side, pos[1] / side]), float(power[iy, ix])


def lattice_period(frames, nnum: int, max_frames: int = 9) -> tuple[float, float] | None:
    """The lenslet period of a stack of frames, measured over every period a lenslet can have.

    Parameters
    ----------
    frames : array_like
        ``(T, H, W)`` frames or a list of ``(H, W)`` frames; the first ``max_frames`` are used.
    nnum : int
        The configured pixels per lenslet: only the frames' minimum size depends on it; the
        period is searched from 3 px to :data:`metasensor.config.MAX_NNUM` (at most a quarter
        of the frame's side), so that frames of another lenslet size are measured, not missed.
    max_frames : int
        How many frames' power spectra are summed.

    Returns
    -------
    tuple of float or None
        ``(period [px], peak strength)`` from both axes' fundamentals. A lattice of period p
        also shows peaks at p/2, p/3... and cross terms: the strongest peak within
        ``0.8 .. 1.25 × nnum`` (prominence >= :data:`MIN_PEAK_STRENGTH`), taken down to the
        largest period p·k whose peak is as prominent, is the answer when it lies within
        :data:`PERIOD_TOLERANCE` of ``nnum``; else the lowest-frequency peak of prominence >=
        :data:`FAR_PEAK_STRENGTH` (and half the strongest) over the whole range, failing
        that the period near ``nnum``. None when the frames are too small (< 4 lenslets of
        ``nnum`` per side), differ in shape, hold NaN or infinite values, or hold no trusted
        lattice peak.
    """
    frames = [np.asarray(f) for f in list(frames)[:max_frames]]
    if not frames or min(frames[0].shape) < 4 * nnum or any(
            f.shape != frames[0].shape or (f.dtype.kind == "f" and not np.isfinite(f).all())
            for f in frames):
        return None  # (non-finite frames are refused by realign itself)
    side = min(_PAD * min(_CROP, max(frames[0].shape)), 2048)
    power = sum(_power(f, side) for f in frames)
    fy = np.fft.fftfreq(side)[:, None]
    fx = np.fft.rfftfreq(side)[None, :]
    rad = np.hypot(fy, fx)
    longest = min(MAX_NNUM, min(_CROP, min(frames[0].shape)) / 4)
    ring = (rad >= 1 / longest) & (rad <= 1 / _MIN_PERIOD)
    # prominence over the local background (the scene's own spectrum falls steeply with
    # frequency and would otherwise win at low frequencies): ~4 main lobes of the window
    lobe = 4 * side / min(_CROP, min(frames[0].shape))
    background = ndimage.uniform_filter(power, size=int(4 * lobe) | 1, mode="wrap")
    prominence = power / (background + 1e-300 + 1e-12 * float(power.max()))
    tan = math.tan(math.radians(30))
    wedges = (fx > 0) & (np.abs(fy) < fx * tan), np.abs(fx) < np.abs(fy) * tan
    near = None
    found = []
    for wedge in wedges:  # the configured period first: its peak, taken down to its fundamental
        g, strength = _peak(prominence, (rad >= 1 / (1.25 * nnum)) & (rad <= 1 / (0.8 * nnum))
                            & wedge, side)
        if strength < MIN_PEAK_STRENGTH:
            break
        found.append(_fundamental(prominence, g, strength, 1 / longest, side))
    if len(found) == 2:
        (g1, p1), (g2, p2) = found
        near = 2.0 / (np.hypot(*g1) + np.hypot(*g2)), float(min(p1, p2))
        if abs(near[0] - nnum) <= PERIOD_TOLERANCE * nnum:
            return near
    # another period (or a harmonic or cross term of one near nnum): the lowest strong peak
    found = []
    for wedge in wedges:
        strength = float(prominence[ring & wedge].max())
        if strength < FAR_PEAK_STRENGTH:
            return near
        strong = prominence >= max(FAR_PEAK_STRENGTH, strength / 2)
        found.append(_lowest_peak(prominence, ring & wedge & strong, rad, lobe, side))
    (g1, p1), (g2, p2) = found
    return 2.0 / (np.hypot(*g1) + np.hypot(*g2)), float(min(p1, p2))


def period_mismatch(frames, nnum: int) -> float | None:
    """The frames' measured lenslet period [px] (:func:`lattice_period`, at most 9 frames) where
    it contradicts ``nnum``, else None (it agrees, or no lattice is measured).

    It contradicts ``nnum`` beyond :data:`PERIOD_TOLERANCE`, or beyond the period resolution of
    the frames' size (about ``nnum / (2 · side)`` relative) where that is coarser."""
    frames = [frames[t] for t in range(min(len(frames), 9))]
    got = lattice_period(frames, nnum)
    if got is None:
        return None
    tolerance = max(PERIOD_TOLERANCE, nnum / (2 * min(np.shape(frames[0])[-2:])))
    return got[0] if abs(got[0] - nnum) > tolerance * nnum else None


def _fundamental(prominence: np.ndarray, g: np.ndarray, strength: float, lowest: float,
                 side: int) -> tuple[np.ndarray, float]:
    """(frequency, prominence) of the fundamental of the lattice peak at ``g`` (cycles/px):
    ``g / k`` for the largest ``k`` (frequencies down to ``lowest``) whose peak within two bins
    is at least :data:`FAR_PEAK_STRENGTH` and three quarters of ``strength`` (a lattice's
    fundamental is as prominent as its harmonics; a scene's own periodic structure is weaker)."""
    best = (g, strength)
    for k in range(2, int(np.hypot(*g) / lowest) + 1):
        iy, ix = (int(round(v)) for v in g / k * side)
        sel = np.zeros(prominence.shape, bool)
        sel[np.arange(iy - 2, iy + 3) % side, max(ix - 2, 0):ix + 3] = True
        got = _peak(prominence, sel, side)
        if got[1] >= max(FAR_PEAK_STRENGTH, 0.75 * strength):
            best = got
    return best


def _lowest_peak(prominence: np.ndarray, strong: np.ndarray, rad: np.ndarray, lobe: float,
                 side: int) -> tuple[np.ndarray, float]:
    """The lattice peak of lowest frequency among the ``strong`` bins: the fundamental (in a
    wedge of +-30 degrees about an axis the lattice's nearest peak is its axis's first; its
    harmonics and the cross terms lie farther out), found within half a window lobe of the
    lowest strong bin."""
    k = int(np.argmin(np.where(strong, rad, np.inf)))
    iy, ix = np.unravel_index(k, rad.shape)
    half = max(2, int(lobe / 2))
    sel = np.zeros(rad.shape, bool)
    sel[np.arange(iy - half, iy + half + 1) % side, max(ix - half, 0):ix + half + 1] = True
    return _peak(prominence, sel & (rad > 0), side)


def _tile_phase(tile: np.ndarray, g: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Unwindowed DFT of ``tile`` at the two lattice frequencies ``g`` (coordinates relative to
    ``centre``): whole lenslets inside the tile add their components with the lattice's phase."""
    y = np.arange(tile.shape[0]) - centre[0]
    x = np.arange(tile.shape[1]) - centre[1]
    return np.array([np.exp(-2j * np.pi * gk[0] * y) @ tile @ np.exp(-2j * np.pi * gk[1] * x)
                     for gk in g])


def lattice_residual(image: np.ndarray, g: np.ndarray, point: np.ndarray,
                     tile_lenslets: int = 6) -> tuple[float, int]:
    """(r.m.s. distance [px] of the tiles' measured lattice points from the model lattice
    ``g`` (2 x 2 reciprocal vectors, cycles/px) through ``point`` (row, col), tiles used).
    ``image``: the (summed) frame the lattice was fitted to. Tiles are ``tile_lenslets`` model
    cells per side, cut along the model's cell borders (so that each holds whole lenslets when
    the model is right); tiles whose lattice amplitude is below a fifth of the strongest tile's
    are skipped; ``(nan, n)`` when fewer than 3 remain."""
    g = np.asarray(g, float)
    point = np.asarray(point, float)
    a = np.linalg.inv(g)  # columns: the lattice vectors
    pitch = 1.0 / float(np.hypot(*g[0]))
    h, w = image.shape
    span = tile_lenslets * pitch
    found = []
    first = point - (np.floor(point / pitch) + 0.5) * pitch  # a cell border near 0
    for y0 in np.arange(first[0], h - span + 1, span):
        for x0 in np.arange(first[1], w - span + 1, span):
            r0, c0 = int(round(y0)), int(round(x0))
            r1, c1 = int(round(y0 + span)), int(round(x0 + span))
            if r0 < 0 or c0 < 0:
                continue
            tile = np.asarray(image[r0:r1, c0:c1], dtype=np.float64)
            total = float(tile.sum())
            if total <= 0:
                continue
            centre = np.array([r0 + r1 - 1, c0 + c1 - 1], float) / 2
            vals = _tile_phase(tile, g, centre - np.array([r0, c0], float))
            frac = -np.angle(vals) / (2 * np.pi)
            want = g @ (point - centre)
            local = centre + a @ (frac + np.round(want - frac))
            found.append((float(np.abs(vals).mean() / total), local - point))
    if not found:
        return float("nan"), 0
    amp = np.array([f[0] for f in found])
    keep = amp >= 0.2 * amp.max()
    if keep.sum() < 3:
        return float("nan"), int(keep.sum())
    dev = np.array([f[1] for f, k in zip(found, keep, strict=True) if k])
    return float(np.sqrt(np.mean(np.sum(dev**2, axis=1)))), int(keep.sum())


def check_scan_offsets(measured, order, matrix, nnum: int, scan: int, start_phase: int = 0,
                       first: int = 0, relative: bool = False) -> None:
    """Refuse frames whose measured grid offsets contradict their scan phases.

    A frame whose measured offset lies more than half a scan step (``nnum // scan / 2``
    rectified px, along either lattice axis) from its phase's nominal offset sits nearer
    another phase: the frames were not taken in ``order`` (or the stage did not step as
    configured), and realigning them would put each such frame's samples in another phase's
    place.

    Parameters
    ----------
    measured : array_like
        ``(F, 2)`` measured offsets [sensor px] of frames ``first .. first + F - 1`` from the
        calibration's phase (0, 0); frame ``f`` has phase ``order[(f + start_phase) % T]``.
    order : sequence of (int, int)
        The scan order the frames are realigned in.
    matrix : array_like
        The calibration's rectified → sensor matrix (``Calibration.matrix``).
    nnum, scan : int
        Pixels per lenslet and scan period.
    start_phase, first : int
        Index in ``order`` of frame 0, and the number of the first measured frame.
    relative : bool
        The offsets are known only relative to the first measured frame's (taken at its
        nominal offset in ``order``): another order is judged with its own first phase there.

    Raises
    ------
    ValueError
        One line naming the frames and how far they sit; when the frames cover a whole period
        and another preset order places every one within half a step, it names that order.
    """
    from metasensor.sensor.scan import PRESETS, scan_order

    measured = np.asarray(measured, float)
    step = nnum // scan
    slots = [(first + f + start_phase) % len(order) for f in range(len(measured))]
    rect = np.linalg.solve(np.asarray(matrix, float), measured.T).T

    def deviation(phases):  # rectified px from the nominal offset, nearest lattice translate
        dev = rect - step * np.array([phases[k] for k in slots], float)
        dev = dev - dev[0] if relative else dev
        return dev - nnum * np.round(dev / nnum)

    dev = deviation(list(order))
    bad = np.flatnonzero(np.abs(dev).max(axis=1) > step / 2)
    if bad.size == 0:
        return
    names = [k for k in PRESETS if scan_order(scan, k) == list(order)]
    used = f"{names[0]} order" if names else "the given scan order"
    fits = [k for k in PRESETS if not names or k != names[0]] if len(measured) == len(order) \
        else []
    fits = [k for k in fits if np.abs(deviation(scan_order(scan, k))).max() <= step / 2]
    far = float(np.abs(dev[bad] @ np.asarray(matrix, float).T).max())
    frames = _runs([first + int(f) for f in bad])
    where = "sit {:.1f} px from their nominal phases" if len(bad) > 1 else \
        "sits {:.1f} px from its nominal phase"
    hint = (f" (they fit {fits[0]}); pass --scan-order {fits[0]}" if fits else
            "; pass the order they were taken in (--scan-order), or check the stage's steps")
    raise ValueError(f"{frames} {where.format(far)} (more than half the {step}-px scan step): "
                     f"the frames are not in {used}{hint}")


def _runs(numbers: list[int]) -> str:
    """``frames 5–9, 15–19`` (``frame 7`` for one)."""
    parts, start = [], numbers[0]
    for a, b in zip(numbers, numbers[1:] + [None], strict=True):
        if b != a + 1:
            parts.append(f"{start}" if start == a else f"{start}–{a}")
            start = b
    return ("frames " if len(numbers) > 1 else "frame ") + ", ".join(parts)
