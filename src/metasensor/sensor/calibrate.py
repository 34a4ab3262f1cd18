"""Lenslet-grid calibration from a white (flat-field) frame or any textured raw frame.

Method (hand-written; numpy/scipy do the transforms and the optimisation):

1. The lenslet pattern is a 2-D lattice: its Fourier transform has peaks at the reciprocal
   lattice vectors ``g1 = (sin t, cos t) / pitch`` (the "x" peak) and ``g2 = (cos t, -sin t) /
   pitch`` (rows, columns; t = rotation). An FFT of the Hann-windowed frame finds them coarsely.
2. Each peak is refined sub-bin by maximising the windowed DFT magnitude ``|F(g)|`` over the
   continuous frequency (Newton steps with analytic derivatives; ``F(g) = e_y(g)^T (I w)
   e_x(g)`` and its derivatives cost one pass over the image). On a white frame the maximum
   is unbiased. On a textured frame the scene's own spectrum near the lattice frequency adds to
   the peak and moves it; the bias falls fast with the frame's size (the lattice peak grows with
   the area, the scene's spectrum near it much less). Calibrate from a white frame where one
   exists, else from the whole sensor (figures: ``docs/decisions.md``, 2026-11-25, lenslet-grid
   calibration).
3. Pitch and rotation are the similarity that fits both peaks; the phases of ``F(g1)``,
   ``F(g2)`` (coordinates relative to the window centre) give a lattice point: a lenslet centre.
4. Scan-phase offsets: the phase change of the same two Fourier components between frames
   gives each frame's grid displacement modulo the lattice; the lattice translate nearest the
   nominal step is taken.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import fft as sfft
from scipy import ndimage

from metasensor.sensor.calibration import Calibration
from metasensor.sensor.checks import check_scan_offsets, lattice_residual

__all__ = ["find_grid", "measure_offsets", "lattice_components", "calibrate", "flat_field"]

_MAX_SIDE = 4096  # the grid fit uses at most this central crop per axis (plenty of lenslets)


def _as_image(frame, what: str = "frame") -> np.ndarray:
    frame = np.asarray(frame)
    if frame.ndim != 2:
        raise ValueError(f"{what} must be a 2-D (H, W) image, got shape {frame.shape}")
    if frame.dtype.kind not in "uif" or frame.dtype == np.float16:
        raise TypeError(f"{what} must be an integer or float32/float64 image, got {frame.dtype}")
    img = frame.astype(np.float64)
    if not np.isfinite(img).all():
        raise ValueError(f"{what} contains NaN or infinite values")
    return img


class _Dft:
    """Windowed DFT of one image at arbitrary 2-D frequencies (cycles/px), coordinates
    relative to the image centre."""

    def __init__(self, img: np.ndarray) -> None:
        h, w = img.shape
        win = np.outer(np.hanning(h), np.hanning(w))
        self.weighted = (img - img.mean()) * win
        self.norm = float((img * win).sum())
        self.y = np.arange(h) - (h - 1) / 2
        self.x = np.arange(w) - (w - 1) / 2

    def __call__(self, g: np.ndarray) -> complex:
        ey = np.exp(-2j * np.pi * g[0] * self.y)
        ax = -2 * np.pi * g[1] * self.x
        rows = self.weighted @ np.cos(ax) + 1j * (self.weighted @ np.sin(ax))  # real BLAS
        return complex(ey @ rows)

    def derivatives(self, g: np.ndarray) -> tuple[complex, np.ndarray, np.ndarray]:
        """F(g), its gradient (2,) and Hessian (2, 2) in g, from one pass over the image."""
        ax = -2 * np.pi * g[1] * self.x
        cols = np.stack([np.cos(ax), np.sin(ax)], axis=1)  # (w, 2)
        cols = np.concatenate([cols, cols * self.x[:, None], cols * self.x[:, None] ** 2], 1)
        r = self.weighted @ cols  # (h, 6): one pass, real BLAS
        rb = [r[:, 2 * b] + 1j * r[:, 2 * b + 1] for b in range(3)]  # sum_x W x^b e_x
        ey = np.exp(-2j * np.pi * g[0] * self.y)
        a = {(i, b): complex((ey * self.y**i) @ rb[b]) for i in range(3) for b in range(3 - i)}
        k = -2j * np.pi
        grad = np.array([k * a[1, 0], k * a[0, 1]])
        hess = np.array([[k * k * a[2, 0], k * k * a[1, 1]], [k * k * a[1, 1], k * k * a[0, 2]]])
        return a[0, 0], grad, hess


def _lit_span(profile: np.ndarray, min_len: int) -> tuple[int, int]:
    """[start, stop) of ``profile`` (row or column means) without its unlit ends: leading and
    trailing entries below 2 % of the median (e.g. the scan margin of a simulated frame, where
    no lenslet lies at this phase)."""
    lit = np.flatnonzero(profile > 0.02 * np.median(profile))
    if lit.size == 0 or lit[-1] + 1 - lit[0] < min_len:
        return 0, profile.size
    return int(lit[0]), int(lit[-1]) + 1


def _crop(img: np.ndarray, min_side: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The lit part of the frame (dark edge strips off: their hard edge inside the Hann window
    biases the lattice fit), centrally
    cropped to at most ``_MAX_SIDE`` per axis; returns (crop, its (row, col) origin)."""
    r0, r1 = _lit_span(img.mean(axis=1), min_side)
    c0, c1 = _lit_span(img.mean(axis=0), min_side)
    h, w = r1 - r0, c1 - c0
    y0 = r0 + max(0, (h - _MAX_SIDE) // 2)
    x0 = c0 + max(0, (w - _MAX_SIDE) // 2)
    return (img[y0:y0 + min(h, _MAX_SIDE), x0:x0 + min(w, _MAX_SIDE)],
            np.array([y0, x0], float))


def _coarse_peaks(imgs: list[np.ndarray], nnum: int, pitch_range: tuple[float, float]):
    """The two lattice peaks of the summed FFT magnitudes of ``imgs`` (same shape)."""
    h, w = imgs[0].shape
    win = np.outer(np.hanning(h), np.hanning(w))
    spec = sum(np.abs(sfft.fft2(((img - img.mean()) * win).astype(np.float32), workers=-1))
               for img in imgs)
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    rad = np.hypot(fy, fx)
    ring = (rad >= 1 / pitch_range[1]) & (rad <= 1 / pitch_range[0])
    peaks = []
    for along, across in ((fx, fy), (fy, fx)):  # g1 near +x, g2 near +y
        sel = ring & (along > 0) & (np.abs(across) < along * math.tan(math.radians(30)))
        if not sel.any():
            raise ValueError(f"frame of {h}x{w} px is too small to hold a lenslet grid of "
                             f"~{nnum} px pitch")
        k = np.argmax(np.where(sel, spec, -1.0))
        iy, ix = np.unravel_index(k, spec.shape)
        peaks.append((np.array([fy[iy, 0], fx[0, ix]]), spec[iy, ix]))
    floor = np.median(spec[ring]) + 1e-12
    return peaks, floor


def _refine(dfts: list[_Dft], g0: np.ndarray, bins: np.ndarray, iters: int = 12) -> np.ndarray:
    """Newton ascent of ``Σ_t |F_t(g)|²`` over the frames' DFTs from the coarse FFT peak
    (analytic derivatives; each step is one pass over each image). Steps are capped at a
    quarter bin (gradient direction when the Hessian is not negative definite)."""
    g = np.asarray(g0, float).copy()
    for _ in range(iters):
        grad, hess = np.zeros(2), np.zeros((2, 2))
        for dft in dfts:
            f, df, d2f = dft.derivatives(g)
            grad += 2 * np.real(np.conj(f) * df)
            hess += 2 * np.real(np.outer(np.conj(df), df) + np.conj(f) * d2f)
        hess = 0.5 * (hess + hess.T)
        if np.all(np.linalg.eigvalsh(hess) < 0):
            step = -np.linalg.solve(hess, grad)
        else:
            step = grad / (np.linalg.norm(grad / bins) + 1e-300) * 0.25
        size = np.max(np.abs(step / bins))
        if size > 0.25:
            step *= 0.25 / size
        g += step
        if size < 1e-6:
            break
    return g


def find_grid(frame, nnum: int, pitch_range: tuple[float, float] | None = None,
              stack=None) -> dict:
    """Lenslet grid of one raw frame: ``{"pitch", "rotation" (deg), "point" (row, col) of one
    lenslet centre near the frame centre, "g" (2 x 2 reciprocal vectors), "contrast",
    "strength"}`` (strength: the weaker lattice peak over the median of the spectrum's ring).

    ``pitch_range``: search range of the pitch in px (default ``nnum`` ± 25 %). ``stack``:
    optional further frames of the same lattice, possibly translated (the frames of a scan):
    pitch and rotation then maximise the summed ``|F_t(g)|²`` of all of them (translations
    change only the phases), the point still comes from ``frame``.
    """
    img = _as_image(frame)
    if min(img.shape) < 3 * nnum:
        raise ValueError(f"frame of {img.shape[0]}x{img.shape[1]} px is too small to calibrate "
                         f"a {nnum}-px lenslet grid (needs at least 3 lenslets per side)")
    crop, origin = _crop(img, 3 * nnum)
    pitch_range = pitch_range or (0.75 * nnum, 1.25 * nnum)
    crops = [crop]
    for k, other in enumerate(stack or []):
        other = _as_image(other, f"frame {k}")
        if other.shape != img.shape:
            raise ValueError(f"frame {k} has shape {other.shape}, the first {img.shape}")
        crops.append(_crop(other, 3 * nnum)[0])  # its own lit part (no hard edges)
    same = [c for c in crops if c.shape == crop.shape]
    ((p1, a1), (p2, a2)), floor = _coarse_peaks(same, nnum, pitch_range)
    if min(a1, a2) < 8 * floor:
        _check_period(same, nnum)
        raise ValueError("no lenslet grid found in the frame (the lattice peaks are not above the "
                         "background: a flat or lens-less frame?)")
    dfts = [_Dft(c) for c in crops]
    dft = dfts[0]
    bins = 1.0 / np.array(crop.shape, float)
    g1 = _refine(dfts, p1, bins)
    g2 = _refine(dfts, p2, bins)
    # similarity fit: g1 = (sin t, cos t)/P, g2 = (cos t, -sin t)/P
    t1 = math.atan2(g1[0], g1[1])
    t2 = math.atan2(-g2[1], g2[0])
    t = math.atan2(math.sin(t1) + math.sin(t2), math.cos(t1) + math.cos(t2))
    pitch = 2.0 / (np.hypot(*g1) + np.hypot(*g2))
    g = np.array([[math.sin(t), math.cos(t)], [math.cos(t), -math.sin(t)]]) / pitch
    vals = np.array([dft(gk) for gk in g])
    frac = -np.angle(vals) / (2 * np.pi)  # g . (c - centre) = frac (mod 1)
    centre = (np.array(crop.shape, float) - 1) / 2
    point = centre + np.linalg.solve(g, frac) + origin
    point = _brightest_phase(img, point, g, pitch)
    return {"pitch": float(pitch), "rotation": math.degrees(t), "point": point, "g": g,
            "contrast": float(np.abs(vals).mean() / max(dft.norm, 1e-300)),
            "strength": float(min(a1, a2) / floor)}


def _check_period(crops: list[np.ndarray], nnum: int) -> None:
    """Refuse frames whose lenslet period contradicts ``nnum``
    (:func:`metasensor.sensor.checks.period_mismatch`): the grid search near ``nnum`` cannot
    find it, and the error names the size."""
    from metasensor.sensor.checks import period_mismatch

    got = period_mismatch(crops, nnum)
    if got is not None:
        raise ValueError(f"the frame's lenslet period measures {got:.2f} px but nnum is "
                         f"{nnum}; set nnum = {round(got)} if the lenslets are that size")


def _brightest_phase(img: np.ndarray, point: np.ndarray, g: np.ndarray, pitch: float):
    """Lenslet centres are bright: if the half-period-shifted lattice is brighter (a negative
    pattern coefficient), move the point by half a lattice cell."""
    a = np.linalg.inv(g).T  # rows: lattice vectors a_x, a_y (sensor px)
    k = np.arange(-3, 4)
    ii, jj = np.meshgrid(k, k, indexing="ij")
    pts = point + ii.ravel()[:, None] * a[1] + jj.ravel()[:, None] * a[0]
    half = pts + 0.5 * (a[0] + a[1])
    on = ndimage.map_coordinates(img, pts.T, order=1, mode="nearest").mean()
    off = ndimage.map_coordinates(img, half.T, order=1, mode="nearest").mean()
    return point + 0.5 * (a[0] + a[1]) if off > on else point


def lattice_components(frame, g, what: str = "frame") -> tuple[np.ndarray, np.ndarray, float]:
    """``(centre [px] (2,), values (2,) complex, norm)``: the Hann-windowed DFT of the lit part
    of the ``(H, W)`` ``frame`` at the lattice frequencies ``g`` ((2, 2), cycles/px, a row
    each). A lattice point ``c`` has ``g · (c − centre) = −angle(values) / 2π`` (mod 1); ``norm``
    is the window's weighted sum of the frame (a lattice of full contrast gives about
    ``norm / 2``). ``what``: the frame's name in error messages."""
    g = np.asarray(g, float)
    img = _as_image(frame, what)
    crop, origin = _crop(img, int(3 / np.hypot(*g[0])))
    centre = (np.array(crop.shape, float) - 1) / 2 + origin
    dft = _Dft(crop)
    return centre, np.array([dft(gk) for gk in g]), dft.norm


def measure_offsets(frames, grid: dict, nominal: list[tuple[float, float]],
                    start: int = 0) -> np.ndarray:
    """Grid displacement [sensor px] of every frame from ``grid["point"]`` (the lattice of the
    reference frame), ``(T, 2)``: the phase change of the lattice components gives it modulo
    the lattice; the translate nearest ``nominal[t]`` (sensor px) is taken. ``start``: the
    number of the first frame in its file (errors name frames by it)."""
    g = np.asarray(grid["g"])
    ref = np.asarray(grid["point"], float)
    out = []
    for t, frame in enumerate(frames):
        centre, values, _ = lattice_components(frame, g, f"frame {start + t}")
        frac = -np.angle(values) / (2 * np.pi)
        # lattice point of this frame: g . (c_t - centre) = frac (mod 1)
        want = g @ (ref + np.asarray(nominal[t], float) - centre)
        frac = frac + np.round(want - frac)
        out.append(centre + np.linalg.solve(g, frac) - ref)
    return np.array(out)


_BORDER = -0.5  # a block may overhang the sensor by half a pixel (known offsets)
# Offsets only nominal (one frame of a scan, or adapt() to another scan): the stage's actual
# steps, measured per frame by realign, may differ by a pixel or two, and a block pushed off the
# sensor stops realign; keep this margin for them.
_JITTER_BORDER = 2.0


def _default_border(border: float | None, measured: bool, scan: int, moving: str) -> float:
    if border is not None:
        return float(border)
    return _BORDER if measured or scan == 1 or moving != "mla" else _JITTER_BORDER


def _keep_lenslets(point, matrix, nnum: int, shape: tuple[int, int], shifts: list,
                   border: float = _BORDER) -> tuple[np.ndarray, tuple[int, int]]:
    """Largest rectangle of lattice cells whose blocks lie on the sensor at every phase: the
    centres of a block's outermost pixels at least ``border`` px inside the sensor's outermost
    pixel centres (0 and H - 1). The default, -0.5, keeps a block that exactly tiles the sensor
    edge (its first pixel centre on pixel 0, as in simulated frames) despite a sub-pixel error of
    the fitted grid; rectification samples such pixels within the sensor (edge replicated for
    the interpolator's last taps). Returns (sensor centre of its cell (0, 0), (Ly, Lx))."""
    h = (nnum - 1) / 2
    a = matrix * nnum  # columns: lattice vectors along rectified rows, cols
    span = int(max(shape) / (np.linalg.norm(a, axis=0).min())) + 2
    k = np.arange(-span, span + 1)
    ii, jj = np.meshgrid(k, k, indexing="ij")
    corners = np.array([[-h, -h], [-h, h], [h, -h], [h, h]])  # outermost pixel centres
    valid = np.ones(ii.shape, bool)
    for shift in shifts:
        base = point + np.asarray(shift, float)
        for cy in corners:
            pos = (base[:, None, None] + a[:, :1, None] * ii + a[:, 1:, None] * jj
                   + (matrix @ cy)[:, None, None])
            valid &= ((pos[0] >= border) & (pos[0] <= shape[0] - 1 - border)
                      & (pos[1] >= border) & (pos[1] <= shape[1] - 1 - border))
    if not valid.any():
        raise ValueError("no lenslet stays on the sensor at every scan phase")
    rows = np.flatnonzero(valid.any(1))
    cols = np.flatnonzero(valid.any(0))
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    while not valid[r0:r1, c0:c1].all():  # shave the worst edge until all cells are valid
        sub = ~valid[r0:r1, c0:c1]
        bad = [sub[0].mean(), sub[-1].mean(), sub[:, 0].mean(), sub[:, -1].mean()]
        e = int(np.argmax(bad))
        r0, r1, c0, c1 = (r0 + (e == 0), r1 - (e == 1), c0 + (e == 2), c1 - (e == 3))
        if r0 >= r1 or c0 >= c1:
            raise ValueError("no lenslet stays on the sensor at every scan phase")
    origin = point + a @ np.array([k[r0], k[c0]], float)
    return origin, (int(r1 - r0), int(c1 - c0))


def calibrate(white, nnum: int, frames=None, scan: int = 1, scan_order=None,
              moving: str = "mla", pitch_range: tuple[float, float] | None = None,
              border: float | None = None) -> Calibration:
    """Calibrate the lenslet grid from ``white`` ``(H, W)`` (a flat-field frame, or any raw
    frame of phase (0, 0) of a textured scene).

    ``frames``: optional ``(T, H, W)`` frames of one scan period (T = scan², in
    ``scan_order``; a sequence of 2-D frames works too): their actual grid displacements are
    measured (``moving="mla"``) and stored against nominal. Returns a :class:`Calibration`
    whose rectified grid keeps the lenslets whose blocks lie on the sensor at every phase (their
    outermost pixel centres ``border`` px inside the sensor's). Default: -0.5 (half a pixel of
    overhang, so a block that exactly tiles the sensor edge is kept) when the offsets are
    measured (``frames``) or nothing moves; 2 px when they are nominal, a margin for the
    stage's actual steps that realign measures per frame.
    """
    from metasensor.sensor.scan import check_scan_order

    white = _as_image(white, "white frame")
    order = check_scan_order(scan_order, scan)
    fit_img, stack = white, None
    if frames is not None and len(frames) > 1:
        if moving == "image":  # one lattice in every frame: their sum shows it best
            fit_img = np.sum([_as_image(f, f"frame {k}") for k, f in enumerate(frames)], axis=0)
        else:  # translated lattices: pitch and rotation from all frames jointly
            stack = [f for f in frames if f is not white]
    grid = find_grid(fit_img, nnum, pitch_range, stack=stack)
    residual, _ = lattice_residual(fit_img, grid["g"], grid["point"])
    _check_fit(grid["strength"], residual, fit_img, nnum)
    t = math.radians(grid["rotation"])
    s = grid["pitch"] / nnum
    m = s * np.array([[math.cos(t), math.sin(t)], [-math.sin(t), math.cos(t)]])
    d = nnum // scan
    nominal = [m @ np.array([r * d, c * d], float) if moving == "mla" else np.zeros(2)
               for r, c in order]
    offsets = None
    if frames is not None:
        if len(frames) != len(order):
            raise ValueError(f"got {len(frames)} calibration frames but a {scan}x{scan} scan "
                             f"needs {len(order)}")
        for k, fr in enumerate(frames):
            if np.shape(fr) != white.shape:
                raise ValueError(f"calibration frame {k} has shape {np.shape(fr)}, the white "
                                 f"frame {white.shape}")
        if moving == "mla":
            meas = measure_offsets(frames, grid, nominal)
            k0 = order.index((0, 0))
            grid["point"] = grid["point"] + meas[k0]  # phase (0, 0) of this scan is the origin
            offsets = [tuple(o - meas[k0]) for o in meas]
            check_scan_offsets(offsets, order, m, nnum, scan)
        else:
            offsets = [(0.0, 0.0)] * len(order)
    shifts = offsets if offsets is not None else nominal
    border = _default_border(border, offsets is not None, scan, moving)
    origin, lenslets = _keep_lenslets(grid["point"], m, nnum, white.shape, shifts, border)
    return Calibration(nnum=nnum, pitch=grid["pitch"], rotation=grid["rotation"],
                       center=tuple(origin), lenslets=lenslets, sensor_shape=white.shape,
                       scan=scan, moving=moving, scan_order=tuple(order), offsets=offsets,
                       contrast=grid["contrast"], peak_strength=round(grid["strength"], 2),
                       fit_residual=None if not math.isfinite(residual) else round(residual, 4))


def _check_fit(strength: float, residual: float, image: np.ndarray, nnum: int) -> None:
    """Refuse a lattice fit that does not describe the field (module docstring of
    :mod:`metasensor.sensor.checks`), naming the lenslet size when ``image`` measures one far
    from ``nnum`` (the fit then locked on a harmonic or cross term of that lattice)."""
    from metasensor.sensor.checks import MAX_RESIDUAL_PX

    if math.isfinite(residual) and residual > MAX_RESIDUAL_PX:
        _check_period([image], nnum)
        raise ValueError(f"untrustworthy lenslet-grid fit: the fitted lattice misses the "
                         f"lenslets across the field by {residual:.2f} px r.m.s. (lattice peak "
                         f"{strength:.0f}x the background); calibrate from a white frame, or "
                         "from more frames (a whole scan period)")


def flat_field(white, calib: Calibration) -> np.ndarray:
    """Flat-field (vignetting) map per pixel of the rectified phase-(0, 0) grid,
    ``(Ly*nnum, Lx*nnum)`` float32, normalised to 1 at the bright (99.5th percentile) level.
    In views it is phase independent (the vignetting moves with the MLA): see
    :func:`metasensor.sensor.rectify.flat_views`."""
    from metasensor.sensor.rectify import rectify_frame

    white = _as_image(white, "white frame")
    rect = rectify_frame(white, calib, (0, 0), use_offsets=False)
    ly, lx = calib.lenslets
    flat = rect[: ly * calib.nnum, : lx * calib.nnum]
    level = np.percentile(flat, 99.5)
    if not level > 0:
        raise ValueError("white frame is dark: cannot build a flat field")
    return (flat / level).astype(np.float32)
