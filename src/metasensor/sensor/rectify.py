"""Rectification: resample raw frames so that every lenslet covers exactly nnum x nnum pixels,
with lenslet (0, 0) of phase (0, 0) at pixels ``[0:nnum, 0:nnum]`` (the input of ``realign``).

The map is the affine one of :class:`~metasensor.sensor.calibration.Calibration`; each frame is
resampled on its own phase's grid (measured offsets), so per-phase piezo errors are removed from
the block positions. Interpolators: ``"spline"`` (scipy.ndimage.affine_transform, cubic
B-spline with prefilter), ``"lanczos"`` (the default) and ``"cubic"`` (OpenCV warpAffine,
coordinates quantised to 1/32 px). When the grid is already exact the frame is only cropped (no
interpolation). Why Lanczos is the default (accuracy and speed measured on the synthetic
captures of ``tests/sensor``): ``docs/decisions.md`` (2026-11-25, lenslet-grid calibration).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from metasensor.sensor.calibration import Calibration

__all__ = ["rectify_frame", "rectify_frames", "check_fits", "flat_views"]

_METHODS = ("spline", "cubic", "lanczos")


def check_fits(calib: Calibration, frame_shape: tuple[int, ...], nnum: int | None = None,
               scan: int | None = None) -> None:
    """Raise a one-line ValueError when the calibration does not fit these frames."""
    if tuple(frame_shape) != tuple(calib.sensor_shape):
        raise ValueError(f"calibration is for {calib.sensor_shape[0]}x{calib.sensor_shape[1]} "
                         f"frames, got {frame_shape[0]}x{frame_shape[1]}")
    if nnum is not None and nnum != calib.nnum:
        raise ValueError(f"calibration has nnum {calib.nnum}, the configuration {nnum}")
    if scan is not None and scan != calib.scan:
        raise ValueError(f"calibration was made for scan period {calib.scan}, the capture uses "
                         f"{scan}")


def rectify_frame(frame, calib: Calibration, phase: tuple[int, int] = (0, 0), *,
                  offset: tuple[float, float] | None = None, use_offsets: bool = True,
                  method: str = "lanczos", out: np.ndarray | None = None) -> np.ndarray:
    """Rectify one raw frame ``(H, W)`` of scan ``phase`` → ``calib.rect_shape()`` float32.

    ``offset``: this frame's measured grid displacement [sensor px] (default: the
    calibration's for ``phase``, or nominal when ``use_offsets`` is False). Pixels outside the
    phase's lenslet blocks (the scan margin) are zero.
    """
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    frame = np.asarray(frame)
    if frame.ndim != 2:
        raise ValueError(f"frame must be a 2-D (H, W) image, got shape {frame.shape}")
    if frame.dtype.kind not in "uif" or frame.dtype == np.float16:
        raise TypeError(f"frame must be an integer or float32/float64 image, got {frame.dtype}")
    check_fits(calib, frame.shape)
    n = calib.nnum
    ly, lx = calib.lenslets
    nom = calib.nominal_rect(phase)
    if offset is None:
        k = calib.scan_order.index(tuple(phase)) if tuple(phase) in calib.scan_order else None
        if k is None:
            raise ValueError(f"phase {tuple(phase)} is not in the calibration's scan order")
        offset = (calib.offsets if (use_offsets and calib.offsets) else calib.nominal_offsets)[k]
    shape = calib.rect_shape()
    if out is None:
        out = np.zeros(shape, np.float32)
    else:
        out[...] = 0
    block = out[nom[0]:nom[0] + ly * n, nom[1]:nom[1] + lx * n]
    m = calib.matrix
    h = (n - 1) / 2
    shift = np.asarray(calib.center) + np.asarray(offset, float) - m @ np.array([h, h])
    exact = np.allclose(m, np.eye(2), atol=1e-9) and np.allclose(shift, np.round(shift),
                                                                 atol=1e-6)
    if exact:  # already an exact grid: crop only
        y0, x0 = (int(v) for v in np.round(shift))
        if y0 < 0 or x0 < 0 or y0 + ly * n > frame.shape[0] or x0 + lx * n > frame.shape[1]:
            raise ValueError("calibration does not fit the frames: lenslet blocks leave the "
                             "sensor")
        block[...] = frame[y0:y0 + ly * n, x0:x0 + lx * n]
        return out
    corners = np.array([[0, 0], [0, lx * n - 1], [ly * n - 1, 0], [ly * n - 1, lx * n - 1]])
    pos = corners @ m.T + shift
    if (pos < -1).any() or (pos[:, 0] > frame.shape[0]).any() or (pos[:, 1] > frame.shape[1]).any():
        raise ValueError("calibration does not fit the frames: lenslet blocks leave the sensor "
                         f"at phase {tuple(phase)}")
    if method == "spline":
        from scipy import ndimage

        coeffs = ndimage.spline_filter(frame.astype(np.float32, copy=False), order=3,
                                       output=np.float32, mode="nearest")
        ndimage.affine_transform(coeffs, m, offset=shift, output_shape=block.shape,
                                 output=block, order=3, mode="nearest", prefilter=False)
        return out
    import cv2

    # dst(q) = src(M q + shift) with (x, y) ordering for OpenCV
    aff = np.array([[m[1, 1], m[1, 0], shift[1]], [m[0, 1], m[0, 0], shift[0]]])
    flag = cv2.INTER_CUBIC if method == "cubic" else cv2.INTER_LANCZOS4
    block[...] = cv2.warpAffine(frame.astype(np.float32, copy=False), aff,
                                (block.shape[1], block.shape[0]),
                                flags=flag | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_REPLICATE)
    return out


def rectify_frames(frames: Iterable[np.ndarray], calib: Calibration, scan_order=None, *,
                   offsets=None, start_phase: int = 0, method: str = "lanczos"
                   ) -> Iterator[np.ndarray]:
    """Rectify a stream of raw frames; frame ``f`` has phase ``order[(f + start_phase) % T]``.

    ``offsets``: ``None`` (the calibration's), ``"nominal"``, or a callable
    ``offsets(f, frame, phase) -> (dy, dx)`` giving each frame's measured displacement.
    """
    from metasensor.sensor.scan import check_scan_order

    order = check_scan_order(scan_order if scan_order is not None else list(calib.scan_order),
                             calib.scan)
    tp = len(order)
    for f, frame in enumerate(frames):
        phase = order[(f + start_phase) % tp]
        if callable(offsets):
            off = offsets(f, frame, phase)
            yield rectify_frame(frame, calib, phase, offset=off, method=method)
        else:
            yield rectify_frame(frame, calib, phase, use_offsets=offsets != "nominal",
                                method=method)


def flat_views(flat: np.ndarray, nnum: int, scan: int) -> np.ndarray:
    """Flat field ``(Ly*nnum, Lx*nnum)`` (rectified, phase (0, 0)) → the same in view layout
    ``(nnum, nnum, Ly*scan, Lx*scan)``: the vignetting moves with the MLA, so every scan phase
    of a lenslet's pixel (u, v) shares one value."""
    flat = np.asarray(flat, np.float32)
    if flat.ndim != 2 or flat.shape[0] % nnum or flat.shape[1] % nnum:
        raise ValueError(f"flat field must be (Ly*{nnum}, Lx*{nnum}), got {flat.shape}")
    ly, lx = flat.shape[0] // nnum, flat.shape[1] // nnum
    per = flat.reshape(ly, nnum, lx, nnum).transpose(1, 3, 0, 2)
    return np.repeat(np.repeat(per, scan, axis=2), scan, axis=3)
