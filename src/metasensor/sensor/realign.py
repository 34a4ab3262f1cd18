"""Pixel realignment: raw frames of one scan period <-> view stacks (docs/conventions.md).

``moving="mla"`` (the meta-imaging sensor): at scan phase (r, c) the block of nnum x nnum pixels
behind lenslet (ly, lx) sits at sensor rows ``ly*nnum + r*d``, columns ``lx*nnum + c*d``
(d = nnum // period, which must divide nnum). ``moving="image"``: the blocks stay at
``ly*nnum, lx*nnum`` and any period is valid (pure indexing). ``moving=None`` (every function's
default) takes ``cfg.moving`` (``"mla"`` unless the configuration says otherwise).
Either way view (u, v) at sample ``(ly*period + r, lx*period + c)`` is pixel (u, v) of that block.
Frames must already be rectified (:mod:`metasensor.sensor.rectify`): lenslet (0, 0) of phase
(0, 0) covers pixels ``[0:nnum, 0:nnum]``.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

import numpy as np

from metasensor.config import SystemConfig
from metasensor.sensor.gather import gather_views, scatter_views
from metasensor.sensor.scan import check_scan_order

__all__ = ["realign", "unrealign", "lenslet_counts", "realign_sequence", "phase_offsets"]

_MOVING = ("mla", "image")
_DTYPES = {np.dtype(t) for t in ("uint8", "uint16", "uint32", "int8", "int16", "int32", "int64",
                                 "uint64", "float32", "float64")}


def _moving(cfg: SystemConfig, moving: str | None) -> str:
    if not isinstance(cfg, SystemConfig):
        raise TypeError(f"cfg must be a SystemConfig, got {type(cfg).__name__}")
    return cfg.moving if moving is None else moving


def _geometry(cfg: SystemConfig, moving: str | None) -> tuple[int, int, int]:
    moving = _moving(cfg, moving)
    if moving not in _MOVING:
        raise ValueError(f"moving must be 'mla' or 'image', got {moving!r}")
    p = cfg.scan
    if moving == "mla" and cfg.nnum % p:
        raise ValueError(f"scan period {p} does not divide nnum {cfg.nnum}, as a moving MLA "
                         "needs (moving='image' for an image scanned over a fixed MLA)")
    d = cfg.nnum // p
    margin = (p - 1) * d if moving == "mla" else 0
    return p, d, margin


def phase_offsets(order, cfg: SystemConfig, moving: str | None = None
                  ) -> list[tuple[int, int]]:
    """Nominal block origin (rows, columns) in rectified pixels of every phase of ``order``."""
    p, d, _ = _geometry(cfg, moving)
    moving = _moving(cfg, moving)
    order = check_scan_order(order, p)
    return [(r * d, c * d) if moving == "mla" else (0, 0) for r, c in order]


def lenslet_counts(frame_shape: tuple[int, int], cfg: SystemConfig,
                   moving: str | None = None) -> tuple[int, int]:
    """Lenslets (Ly, Lx) whose blocks are on the sensor at every scan phase."""
    _, _, margin = _geometry(cfg, moving)
    ly = (frame_shape[0] - margin) // cfg.nnum
    lx = (frame_shape[1] - margin) // cfg.nnum
    return ly, lx


def _native(a: np.ndarray) -> np.ndarray:
    """``a`` in this machine's byte order (big-endian TIFFs, ImageJ's default, read as such)."""
    return a if a.dtype.isnative else a.astype(a.dtype.newbyteorder("="))


def _check_dtype(dtype: np.dtype, what: str = "frames") -> None:
    if np.dtype(dtype) not in _DTYPES:
        raise TypeError(f"{what} must be an integer or float32/float64 array, got dtype {dtype}")


def _check_finite(frames: np.ndarray, what: str = "frames") -> None:
    if frames.dtype.kind != "f":
        return
    flat = frames.reshape(frames.shape[0], -1) if frames.ndim > 1 else frames[None]
    step = max(1, (1 << 24) // max(1, flat.shape[1]))
    for t0 in range(0, flat.shape[0], step):  # chunked: no full-size temporary
        if not np.isfinite(flat[t0:t0 + step]).all():
            raise ValueError(f"{what} contain NaN or infinite values")


def _check_frames(frames, cfg: SystemConfig, period: int, margin: int) -> np.ndarray:
    if not isinstance(frames, np.ndarray):
        frames = np.asarray(frames)
    if frames.ndim != 3:
        raise ValueError(f"frames must be a (T, H, W) array, got shape {frames.shape}")
    frames = _native(frames)
    _check_dtype(frames.dtype)
    t = frames.shape[0]
    if t != period * period:
        raise ValueError(
            f"got {t} frames but one {period}x{period} scan period needs {period * period}"
        )
    _check_size(frames.shape[1:], cfg, margin)
    _check_finite(frames)
    return np.asarray(frames)  # a plain ndarray view of memmaps


def _check_size(shape: tuple[int, ...], cfg: SystemConfig, margin: int) -> None:
    need = cfg.nnum + margin
    if shape[0] < need or shape[1] < need:
        raise ValueError(
            f"frames of {shape[0]}x{shape[1]} px are smaller than one lenslet "
            f"block over the scan ({need}x{need} px)"
        )


def realign(frames, cfg: SystemConfig, scan_order=None, moving: str | None = None, *,
            out: np.ndarray | None = None, engine: str = "auto",
            dtype=np.float32) -> np.ndarray:
    """Raw frames ``(T, H, W)`` of one scan period → views ``(nnum, nnum, Ly*p, Lx*p)``.

    ``T = cfg.scan**2`` rectified frames in ``scan_order`` (None: row-major; a preset name or a
    list of (row, col) phases). ``dtype``: of the views, float32 by default (docs/conventions.md;
    exact for sensor data up to 24 bits); ``None`` keeps the frames' dtype (uint16 views take
    half the memory). ``out``: optional preallocated C-contiguous output of that shape and of
    the frames' dtype (``dtype`` is then ignored). ``engine``: ``"auto"`` (compiled gather for
    large data), ``"numba"`` or ``"numpy"``. The input is never modified. A torch tensor (e.g.
    on CUDA) is realigned on its device and a new tensor (of ``dtype``) is returned.
    """
    p, _, margin = _geometry(cfg, moving)
    moving = _moving(cfg, moving)
    order = check_scan_order(scan_order, p)
    if dtype is not None:
        try:
            np.dtype(dtype)
        except TypeError:
            raise TypeError(f"dtype must be a NumPy dtype or None, got {dtype!r}") from None
    if type(frames).__module__.startswith("torch"):
        views = _realign_torch(frames, cfg, order, moving, margin)
        if dtype is None:
            return views
        import torch

        return views.to(torch.from_numpy(np.empty(0, dtype=dtype)).dtype)
    frames = _check_frames(frames, cfg, p, margin)
    n = cfg.nnum
    ly, lx = lenslet_counts(frames.shape[1:], cfg, moving)
    shape = (n, n, ly * p, lx * p)
    cast = out is None and dtype is not None and np.dtype(dtype) != frames.dtype
    if out is None:
        out = np.empty(shape, dtype=frames.dtype)
    elif (out.shape != shape or out.dtype != frames.dtype
          or not out.flags.c_contiguous or not out.flags.writeable):
        raise ValueError(f"out must be a writeable C-contiguous {frames.dtype} array of shape "
                         f"{shape}, got {out.dtype} {out.shape}")
    views = gather_views(frames, out, order, phase_offsets(order, cfg, moving), n, p, ly, lx,
                         engine=engine)
    return views.astype(dtype) if cast else views


def _realign_torch(frames, cfg: SystemConfig, order, moving: str, margin: int):
    import torch

    from metasensor.sensor.gather import gather_views_torch

    p = cfg.scan
    if frames.ndim != 3:
        raise ValueError(f"frames must be a (T, H, W) tensor, got shape {tuple(frames.shape)}")
    if frames.dtype in (torch.bool, torch.float16, torch.bfloat16) or frames.is_complex():
        raise TypeError(f"frames must be an integer or float32/float64 tensor, got dtype "
                        f"{frames.dtype}")
    if frames.shape[0] != p * p:
        raise ValueError(f"got {frames.shape[0]} frames but one {p}x{p} scan period needs "
                         f"{p * p}")
    _check_size(tuple(frames.shape[1:]), cfg, margin)
    if frames.is_floating_point() and not bool(torch.isfinite(frames).all()):
        raise ValueError("frames contain NaN or infinite values")
    ly, lx = lenslet_counts(tuple(frames.shape[1:]), cfg, moving)
    return gather_views_torch(frames, order, phase_offsets(order, cfg, moving), cfg.nnum, p,
                              ly, lx)


def unrealign(views, cfg: SystemConfig, scan_order=None, moving: str | None = None,
              frame_shape: tuple[int, int] | None = None, *, engine: str = "auto"
              ) -> np.ndarray:
    """Views ``(nnum, nnum, Ly*p, Lx*p)`` → raw frames ``(T, H, W)``: the exact inverse of
    :func:`realign` on the lenslet blocks (pixels outside every block are zero).

    ``frame_shape`` defaults to the smallest sensor holding all blocks at every phase.
    """
    p, d, margin = _geometry(cfg, moving)
    moving = _moving(cfg, moving)
    order = check_scan_order(scan_order, p)
    views = np.asarray(views)
    n = cfg.nnum
    if views.ndim != 4 or views.shape[:2] != (n, n):
        raise ValueError(f"views must have shape ({n}, {n}, H, W), got {views.shape}")
    if views.shape[2] % p or views.shape[3] % p or views.shape[2] == 0 or views.shape[3] == 0:
        raise ValueError(f"view size {views.shape[2:]} is not a multiple of the scan period {p}")
    if views.dtype.kind not in "biuf":
        raise ValueError(f"views must be real numbers (bool, integer or float), got dtype "
                         f"{views.dtype}")
    if np.issubdtype(views.dtype, np.floating) and not np.isfinite(views).all():
        raise ValueError("views contain NaN or infinite values")
    ly, lx = views.shape[2] // p, views.shape[3] // p
    if frame_shape is None:
        frame_shape = (ly * n + margin, lx * n + margin)
    frame_shape = tuple(int(s) for s in frame_shape)
    if len(frame_shape) != 2 or frame_shape[0] < ly * n + margin or \
            frame_shape[1] < lx * n + margin:
        raise ValueError(f"frame_shape {frame_shape} cannot hold {ly}x{lx} lenslets over the scan")
    frames = np.zeros((p * p, *frame_shape), dtype=views.dtype)
    return scatter_views(views, frames, order, phase_offsets(order, cfg, moving), n, p, ly, lx,
                         engine=engine)


def realign_sequence(frames: Iterable[np.ndarray], cfg: SystemConfig, scan_order=None,
                     moving: str | None = None, *, sliding: bool = True,
                     start_phase: int = 0,
                     engine: str = "auto") -> Iterator[np.ndarray]:
    """Realign a long sequence of rectified frames ``(H, W)`` (any iterable: an array, a list,
    a :class:`metasensor.io.raw.RawFrames` stream), yielding view stacks.

    Frame ``f`` has scan phase ``order[(f + start_phase) % T]`` (T = period²: the scan repeats).
    ``sliding=True`` (the paper's way to keep the frame rate): window ``t`` uses frames
    ``t .. t+T-1`` and one view stack is yielded per frame from frame ``T-1`` on (N - T + 1
    stacks for N frames). ``sliding=False``: one stack per complete period (N must then be a
    multiple of T). Only the last T frames are held in memory (a ring buffer in which slot s
    always holds the latest frame of phase ``order[s]``); after the first window only the new
    frame's phase is realigned into an internal stack, and a copy of it is yielded (a memory
    copy plus 1/T of a realignment per frame). Each yielded array is new.
    """
    p, _, margin = _geometry(cfg, moving)
    moving = _moving(cfg, moving)
    order = check_scan_order(scan_order, p)
    tp = p * p
    if not isinstance(start_phase, (int, np.integer)) or not 0 <= start_phase < tp:
        raise ValueError(f"start_phase must be an integer in 0..{tp - 1}, got {start_phase!r}")
    offsets = phase_offsets(order, cfg, moving)
    ring: np.ndarray | None = None
    state: np.ndarray | None = None
    count = 0
    for f, frame in enumerate(frames):
        frame = _native(np.asarray(frame))
        if frame.ndim != 2:
            raise ValueError(f"frame {f} must be a 2-D (H, W) array, got shape {frame.shape}")
        if ring is None:
            _check_dtype(frame.dtype, f"frame {f}")
            _check_size(frame.shape, cfg, margin)
            ring = np.empty((tp, *frame.shape), dtype=frame.dtype)
        elif frame.shape != ring.shape[1:] or frame.dtype != ring.dtype:
            raise ValueError(f"frame {f} is {frame.dtype} {frame.shape}, unlike the first frame "
                             f"({ring.dtype} {ring.shape[1:]})")
        _check_finite(frame[None], f"frame {f}")
        slot = (f + start_phase) % tp
        ring[slot] = frame
        count = f + 1
        if count < tp or not (sliding or count % tp == 0):
            continue
        n = cfg.nnum
        ly, lx = lenslet_counts(ring.shape[1:], cfg, moving)
        if sliding and state is not None:
            # only the new frame's phase changed: replace its samples in the internal stack
            (r, c), (oy, ox) = order[slot], offsets[slot]
            block = frame[oy:oy + ly * n, ox:ox + lx * n].reshape(ly, n, lx, n)
            state[:, :, r::p, c::p] = block.transpose(1, 3, 0, 2)
            yield state.copy()
            continue
        out = np.empty((n, n, ly * p, lx * p), dtype=ring.dtype)
        gather_views(ring, out, order, offsets, n, p, ly, lx, engine=engine)
        if sliding:
            state = out.copy()
        yield out
    if count < tp:
        raise ValueError(f"got {count} frames but one {p}x{p} scan period needs {tp}")
    if not sliding and count % tp:
        raise ValueError(f"frame count {count} is not a multiple of the {p}x{p} scan ({tp})")
