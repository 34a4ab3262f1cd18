"""The scan phase of rectified raw frames, measured from the data (no calibration needed).

A rectified frame's lenslet lattice has period ``nnum`` along both axes; a moving MLA's scan
phase (r, c) translates it by ``nnum // scan × (r, c)`` px. The phase of the lattice's
fundamental Fourier components on a central crop of the frame
(:func:`metasensor.sensor.calibrate.lattice_components`, the measurement calibration's frame
offsets use) gives that translation modulo ``nnum``: a frame taken at another phase than its
place in the scan order shows it. Only the crop is read, so the check costs little per frame.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["lattice_shift", "phase_checked", "MIN_CONTRAST", "PHASE_TOLERANCE"]

MIN_CONTRAST = 0.02  # a frame whose lattice component is weaker than this is not measured
PHASE_TOLERANCE = 0.25  # of a scan step: a measurement farther from every phase is not judged
_CROP = 512


def lattice_shift(frame, nnum: int) -> tuple[float, float] | None:
    """Translation [px] of a rectified frame's lenslet lattice, modulo ``nnum``.

    Parameters
    ----------
    frame : array_like
        One ``(H, W)`` rectified raw frame (lenslet period ``nnum`` along both axes).
    nnum : int
        Pixels per lenslet.

    Returns
    -------
    tuple of float or None
        ``(rows, columns)`` in ``[0, nnum)``: the position of a lattice point, from the phases
        of the frame's fundamental lattice components on a central crop of at most 512 px a
        side (:func:`metasensor.sensor.calibrate.lattice_components`). None when the crop is
        under 4 periods a side, holds non-finite values, or either component is below
        :data:`MIN_CONTRAST` of the window's weighted sum (no lattice to measure: dark or
        lattice-free frames).
    """
    from metasensor.sensor.calibrate import lattice_components

    img = np.asarray(frame)
    h, w = img.shape[-2:]
    side = min(h, w, _CROP)
    if side < 4 * nnum:
        return None
    y0, x0 = (h - side) // 2, (w - side) // 2
    try:
        centre, values, norm = lattice_components(img[y0:y0 + side, x0:x0 + side],
                                                  np.eye(2) / nnum)
    except ValueError:  # non-finite samples
        return None
    if not (math.isfinite(norm) and norm > 0) or np.abs(values).min() < MIN_CONTRAST * norm:
        return None
    frac = -np.angle(values) / (2 * np.pi)
    return tuple(float(v) for v in (centre + np.array([y0, x0]) + nnum * frac) % nnum)


def phase_checked(frames, nnum: int, scan: int, order, start_phase: int = 0):
    """Yield ``frames`` (rectified, a moving MLA's scan in ``order``), refusing those whose
    lattice sits more than half a scan step from its phase's nominal offset relative to frame
    0's (:func:`lattice_shift`, :func:`metasensor.sensor.checks.check_scan_offsets` with the
    identity matrix): the first scan period's frames together once its last is read (so that
    the error can name the preset order they fit), later frames each on its own.

    Only a self-consistent measurement is judged: every measured frame within
    :data:`PHASE_TOLERANCE` of a scan step of some phase's nominal offset, the first period's
    frames at distinct phases. A scene can displace a frame's lattice component (sparse
    defocused points can); such frames, and those whose lattice cannot be
    measured (all of them when frame 0's cannot be), pass unchecked.

    Raises
    ------
    ValueError
        One line naming the frames out of place (before the first view stack is complete).
    """
    from metasensor.sensor.checks import check_scan_offsets

    order = [tuple(p) for p in order]
    t = len(order)
    step = nnum // scan
    ref = None
    period = []
    for f, frame in enumerate(frames):
        got = lattice_shift(frame, nnum)
        ref = got if f == 0 else ref
        if ref is not None and got is not None:
            # offset from the order's phase (0, 0), taking frame 0 at its nominal offset
            rel = np.subtract(got, ref) + step * np.array(order[start_phase % t], float)
            if f < t:
                period.append(rel)
            elif _consistent(rel[None], nnum, step):
                check_scan_offsets([rel], order, np.eye(2), nnum, scan, start_phase, first=f)
        if f == t - 1 and len(period) == t and _consistent(np.array(period), nnum, step):
            check_scan_offsets(period, order, np.eye(2), nnum, scan, start_phase, relative=True)
        yield frame


def _consistent(rel: np.ndarray, nnum: int, step: int) -> bool:
    """Whether every offset ``rel`` (``(F, 2)`` px) lies within :data:`PHASE_TOLERANCE` of a
    step of its nearest phase, and those phases are distinct."""
    k = np.round(rel / step)
    res = rel - step * k
    if np.abs(res).max() > PHASE_TOLERANCE * step:
        return False
    phases = {tuple(int(v) for v in row) for row in k % (nnum // step)}
    return len(phases) == len(rel)
