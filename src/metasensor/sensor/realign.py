"""Pixel realignment: raw frames of one scan period <-> view stacks (interface.md contract).

``moving="mla"`` (the meta-imaging sensor): at scan phase (r, c) the block of nnum x nnum pixels
behind lenslet (ly, lx) sits at sensor rows ``ly*nnum + r*d``, columns ``lx*nnum + c*d``
(d = nnum // period). ``moving="image"``: the blocks stay at ``ly*nnum, lx*nnum``.
Either way view (u, v) at sample ``(ly*period + r, lx*period + c)`` is pixel (u, v) of that block.
"""

from __future__ import annotations

import numpy as np

from metasensor.config import SystemConfig
from metasensor.sensor.scan import check_scan_order

__all__ = ["realign", "unrealign", "lenslet_counts"]

_MOVING = ("mla", "image")


def _geometry(cfg: SystemConfig, moving: str) -> tuple[int, int, int]:
    if moving not in _MOVING:
        raise ValueError(f"moving must be 'mla' or 'image', got {moving!r}")
    p = cfg.scan
    d = cfg.nnum // p
    margin = (p - 1) * d if moving == "mla" else 0
    return p, d, margin


def lenslet_counts(frame_shape: tuple[int, int], cfg: SystemConfig, moving: str = "mla"
                   ) -> tuple[int, int]:
    """Lenslets (Ly, Lx) whose blocks are on the sensor at every scan phase."""
    _, _, margin = _geometry(cfg, moving)
    ly = (frame_shape[0] - margin) // cfg.nnum
    lx = (frame_shape[1] - margin) // cfg.nnum
    return ly, lx


def _check_frames(frames, cfg: SystemConfig, period: int, margin: int) -> np.ndarray:
    if not isinstance(frames, np.ndarray):
        frames = np.asarray(frames)
    if frames.ndim != 3:
        raise ValueError(f"frames must be a (T, H, W) array, got shape {frames.shape}")
    if frames.dtype.kind not in "uif" or frames.dtype == np.float16:
        raise TypeError(f"frames must be an integer or float32/64 array, got dtype {frames.dtype}")
    t = frames.shape[0]
    if t != period * period:
        raise ValueError(
            f"got {t} frames but one {period}x{period} scan period needs {period * period}"
        )
    need = cfg.nnum + margin
    if frames.shape[1] < need or frames.shape[2] < need:
        raise ValueError(
            f"frames of {frames.shape[1]}x{frames.shape[2]} px are smaller than one lenslet "
            f"block over the scan ({need}x{need} px)"
        )
    if frames.dtype.kind == "f" and not np.isfinite(frames).all():
        raise ValueError("frames contain NaN or infinite values")
    return frames


def realign(frames, cfg: SystemConfig, scan_order=None, moving: str = "mla") -> np.ndarray:
    """Raw frames ``(T, H, W)`` of one scan period → views ``(nnum, nnum, Ly*p, Lx*p)``.

    ``T = cfg.scan**2`` frames in ``scan_order`` (None: row-major). The output keeps the frames'
    dtype, so integer data are realigned exactly. The input is never modified.
    """
    p, d, margin = _geometry(cfg, moving)
    order = check_scan_order(scan_order, p)
    frames = _check_frames(frames, cfg, p, margin)
    n = cfg.nnum
    ly, lx = lenslet_counts(frames.shape[1:], cfg, moving)
    views = np.empty((n, n, ly * p, lx * p), dtype=frames.dtype)
    for t, (r, c) in enumerate(order):
        oy, ox = (r * d, c * d) if moving == "mla" else (0, 0)
        block = frames[t, oy:oy + ly * n, ox:ox + lx * n].reshape(ly, n, lx, n)
        views[:, :, r::p, c::p] = block.transpose(1, 3, 0, 2)
    return views


def unrealign(views, cfg: SystemConfig, scan_order=None, moving: str = "mla",
              frame_shape: tuple[int, int] | None = None) -> np.ndarray:
    """Views ``(nnum, nnum, Ly*p, Lx*p)`` → raw frames ``(T, H, W)``: the exact inverse of
    :func:`realign` on the lenslet blocks (pixels outside every block are zero).

    ``frame_shape`` defaults to the smallest sensor holding all blocks at every phase.
    """
    p, d, margin = _geometry(cfg, moving)
    order = check_scan_order(scan_order, p)
    views = np.asarray(views)
    n = cfg.nnum
    if views.ndim != 4 or views.shape[:2] != (n, n):
        raise ValueError(f"views must have shape ({n}, {n}, H, W), got {views.shape}")
    if views.shape[2] % p or views.shape[3] % p:
        raise ValueError(f"view size {views.shape[2:]} is not a multiple of the scan period {p}")
    ly, lx = views.shape[2] // p, views.shape[3] // p
    if frame_shape is None:
        frame_shape = (ly * n + margin, lx * n + margin)
    if frame_shape[0] < ly * n + margin or frame_shape[1] < lx * n + margin:
        raise ValueError(f"frame_shape {frame_shape} cannot hold {ly}x{lx} lenslets over the scan")
    frames = np.zeros((p * p, *frame_shape), dtype=views.dtype)
    for t, (r, c) in enumerate(order):
        oy, ox = (r * d, c * d) if moving == "mla" else (0, 0)
        block = views[:, :, r::p, c::p].transpose(2, 0, 3, 1).reshape(ly * n, lx * n)
        frames[t, oy:oy + ly * n, ox:ox + lx * n] = block
    return frames
