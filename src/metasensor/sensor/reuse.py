"""A calibration used on another capture: its lattice, one frame's measured grid offset, and the
calibration adapted to another scan (same lattice; offsets re-keyed or nominal, kept lenslets
recomputed for the new scan margin). Method as :mod:`metasensor.sensor.calibrate`."""

from __future__ import annotations

import math

import numpy as np

from metasensor.sensor.calibrate import _default_border, _keep_lenslets, measure_offsets
from metasensor.sensor.calibration import Calibration

__all__ = ["grid_of", "frame_offset", "checked_offsets", "adapt"]


def grid_of(calib: Calibration) -> dict:
    """The lattice of a calibration as :func:`find_grid` returns it (reference point: the
    centre of rectified lenslet (0, 0) at phase (0, 0))."""
    t = math.radians(calib.rotation)
    g = np.array([[math.sin(t), math.cos(t)], [math.cos(t), -math.sin(t)]]) / calib.pitch
    return {"pitch": calib.pitch, "rotation": calib.rotation, "g": g,
            "point": np.asarray(calib.center, float), "contrast": calib.contrast}


def frame_offset(frame, calib: Calibration, phase: tuple[int, int],
                 index: int | None = None, check: bool = True) -> tuple[float, float]:
    """Measured grid displacement [sensor px] of one raw frame of ``phase`` (vs the
    calibration's phase (0, 0)), the lattice translate nearest the calibration's value.
    ``index``: the frame's number in its file, for error messages. ``check``: refuse a
    displacement more than half a scan step from the phase's nominal one
    (:func:`metasensor.sensor.checks.check_scan_offsets`; a moving MLA only)."""
    from metasensor.sensor.checks import check_scan_offsets

    k = calib.scan_order.index(tuple(phase)) if tuple(phase) in calib.scan_order else None
    if k is None:
        raise ValueError(f"phase {tuple(phase)} is not in the calibration's scan order")
    expect = (calib.offsets or calib.nominal_offsets)[k]
    off = measure_offsets([frame], grid_of(calib), [expect], start=index or 0)[0]
    if check and calib.moving == "mla":
        t = len(calib.scan_order)
        check_scan_offsets([off], calib.scan_order, calib.matrix, calib.nnum, calib.scan,
                           start_phase=(k - (index or 0)) % t, first=index or 0)
    return float(off[0]), float(off[1])


def checked_offsets(calib: Calibration, start_phase: int = 0):
    """``offsets(f, frame, phase)`` for :func:`metasensor.sensor.rectify.rectify_frames`: each
    frame's measured grid offset (:func:`frame_offset`), refused by
    :func:`metasensor.sensor.checks.check_scan_offsets` when it lies more than half a scan step
    from its phase's nominal offset: the first scan period's frames together, once the last of
    them is measured (so that the error can name the order they fit), later frames each on its
    own. ``calib``: adapted to the capture's scan order (:func:`adapt`); frame ``f`` has phase
    ``calib.scan_order[(f + start_phase) % T]``."""
    from metasensor.sensor.checks import check_scan_offsets

    order = list(calib.scan_order)
    period: list[tuple[float, float]] = []

    def offsets(f, frame, phase):
        got = frame_offset(frame, calib, phase, index=f, check=f >= len(order))
        if f < len(order):
            period.append(got)
            if len(period) == len(order):
                check_scan_offsets(period, order, calib.matrix, calib.nnum, calib.scan,
                                   start_phase)
        return got

    return offsets


def adapt(calib: Calibration, scan: int, scan_order=None, moving: str = "mla",
          border: float | None = None) -> Calibration:
    """The calibration for a capture with this scan: the same grid, offsets re-keyed to
    ``scan_order`` when the scans match, else nominal offsets (measure them per frame) and the
    kept lenslets recomputed for the new scan margin."""
    from metasensor.sensor.scan import check_scan_order

    order = check_scan_order(scan_order, scan)
    if calib.scan == scan and calib.moving == moving and set(order) == set(calib.scan_order):
        offsets = None if calib.offsets is None else tuple(calib.offset(p) for p in order)
        return calib.replace(scan_order=tuple(order), offsets=offsets)
    base = calib.replace(scan=scan, scan_order=tuple(order), moving=moving, offsets=None)
    border = _default_border(border, False, scan, moving)  # nominal offsets
    origin, lenslets = _keep_lenslets(np.asarray(calib.center, float), base.matrix, calib.nnum,
                                      calib.sensor_shape, list(base.nominal_offsets), border)
    # the flat field is stored per lenslet of the original kept grid: track where we are in it
    cells = np.linalg.solve(base.matrix * calib.nnum, origin - np.asarray(calib.center))
    shift = tuple(int(v) for v in np.round(cells) + np.array(calib.flat_origin))
    return base.replace(center=tuple(origin), lenslets=lenslets, flat_origin=shift)
