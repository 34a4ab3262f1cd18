"""Memory-speed pixel gathering for :func:`metasensor.sensor.realign.realign` (hand-written).

``realign`` is pure data movement: view (u, v) sample ``(i*p + r, j*p + c)`` is pixel
``(oy[t] + i*nnum + u, ox[t] + j*nnum + v)`` of frame ``t`` (the frame of phase (r, c)). NumPy's
strided assignment does this one phase at a time and streams the whole output ``p²`` times with
strided writes; the compiled kernel below instead builds every output row in one pass from the
``p`` source rows it needs (which stay in cache) and writes it contiguously, threads over rows.
No library offers this gather; numba (a dependency of aotools) compiles it. Without numba the
NumPy path is used. The kernel runs on at most torch's intra-op thread count
(``torch.get_num_threads()``), and torch's count is set back after it: numba's OpenMP threading
layer, when it starts (on the first call of a process that loads the kernel from numba's
cache), sets OpenMP's thread count to every core, which torch then reads as its own, so that a
process limited to one thread (``OMP_NUM_THREADS=1`` or ``torch.set_num_threads(1)``) went on
computing on all cores after its first realign.
"""

from __future__ import annotations

import numpy as np

__all__ = ["gather_views", "scatter_views", "gather_views_torch", "have_numba"]

try:  # numba is optional: present through aotools, but the NumPy path always works
    import numba

    @numba.njit(parallel=True, nogil=True, cache=True)
    def _copy_numba(frames, views, tidx, offy, offx, p, ly, lx, to_frames):  # pragma: no cover
        # one view row (u, v, y) per (u, y) and v: its p source rows stay in cache; gather
        # (views from frames) or, with to_frames, its inverse scatter
        n = views.shape[0]
        for k in numba.prange(n * ly * p):
            u = k // (ly * p)
            y = k % (ly * p)
            i = y // p
            r = y % p
            for c in range(p):
                t = tidx[r, c]
                row = frames[t, offy[t] + i * n + u, offx[t]:]
                for v in range(n):
                    samples = views[u, v, y]
                    if to_frames:
                        for j in range(lx):
                            row[j * n + v] = samples[j * p + c]
                    else:
                        for j in range(lx):
                            samples[j * p + c] = row[j * n + v]

    _HAVE_NUMBA = True
except ImportError:  # pragma: no cover - environment dependent
    _HAVE_NUMBA = False

# below this many output samples the NumPy path is faster than compiling / threading
_NUMBA_MIN_SIZE = 1 << 22
_NUMBA_DTYPES = {np.dtype(t) for t in ("uint8", "uint16", "uint32", "int16", "int32",
                                       "float32", "float64")}


def _run_compiled(*args) -> None:
    """``_copy_numba(*args)`` on at most torch's intra-op threads, torch's count restored."""
    import torch

    threads = torch.get_num_threads()
    try:
        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
        _copy_numba(*args)
    finally:
        torch.set_num_threads(threads)


def have_numba() -> bool:
    """Whether the compiled gather kernel is available."""
    return _HAVE_NUMBA


def _gather_numpy(frames, out, order, offsets, n, p, ly, lx) -> None:
    for t, (r, c) in enumerate(order):
        oy, ox = offsets[t]
        block = frames[t][oy:oy + ly * n, ox:ox + lx * n].reshape(ly, n, lx, n)
        out[:, :, r::p, c::p] = block.transpose(1, 3, 0, 2)


def _use_numba(engine: str, src: np.ndarray, dst: np.ndarray) -> bool:
    if engine not in ("auto", "numba", "numpy"):
        raise ValueError(f"engine must be 'auto', 'numba' or 'numpy', got {engine!r}")
    use = (engine != "numpy" and _HAVE_NUMBA and isinstance(src, np.ndarray)
           and src.dtype == dst.dtype and src.dtype in _NUMBA_DTYPES
           and (engine == "numba" or src.size >= _NUMBA_MIN_SIZE))
    if engine == "numba" and not use:
        raise ValueError("engine='numba' needs numba and arrays of a plain dtype")
    return use


def _tables(order, offsets, p):
    tidx = np.zeros((p, p), dtype=np.int64)
    for t, (r, c) in enumerate(order):
        tidx[r, c] = t
    offy = np.array([o[0] for o in offsets], dtype=np.int64)
    offx = np.array([o[1] for o in offsets], dtype=np.int64)
    return tidx, offy, offx


def scatter_views(views: np.ndarray, frames: np.ndarray, order: list[tuple[int, int]],
                  offsets: list[tuple[int, int]], n: int, p: int, ly: int, lx: int,
                  engine: str = "auto") -> np.ndarray:
    """The inverse of :func:`gather_views`: write the view samples back into the lenslet
    blocks of ``frames`` ``(T, H, W)`` (other pixels untouched)."""
    if not _use_numba(engine, views, frames):
        for t, (r, c) in enumerate(order):
            oy, ox = offsets[t]
            block = views[:, :, r::p, c::p].transpose(2, 0, 3, 1).reshape(ly * n, lx * n)
            frames[t, oy:oy + ly * n, ox:ox + lx * n] = block
        return frames
    _run_compiled(frames, np.ascontiguousarray(views), *_tables(order, offsets, p), p, ly, lx,
                  True)
    return frames


def gather_views(frames, out: np.ndarray, order: list[tuple[int, int]],
                 offsets: list[tuple[int, int]], n: int, p: int, ly: int, lx: int,
                 engine: str = "auto") -> np.ndarray:
    """Fill ``out`` ``(n, n, ly*p, lx*p)`` from ``frames`` (a ``(T, H, W)`` array or a sequence
    of ``T`` 2-D arrays) whose frame ``t`` has phase ``order[t]`` and block origin
    ``offsets[t]`` (rows, columns). ``engine``: ``"auto"``, ``"numba"`` or ``"numpy"``."""
    if not _use_numba(engine, frames, out):
        _gather_numpy(frames, out, order, offsets, n, p, ly, lx)
        return out
    _run_compiled(frames, out, *_tables(order, offsets, p), p, ly, lx, False)
    return out


def gather_views_torch(frames, order: list[tuple[int, int]], offsets: list[tuple[int, int]],
                       n: int, p: int, ly: int, lx: int):
    """The same gather for a torch tensor ``(T, H, W)`` on its own device (CUDA: at GPU memory
    speed); returns a new tensor ``(n, n, ly*p, lx*p)``."""
    import torch

    out = torch.empty((n, n, ly * p, lx * p), dtype=frames.dtype, device=frames.device)
    for t, (r, c) in enumerate(order):
        oy, ox = offsets[t]
        block = frames[t, oy:oy + ly * n, ox:ox + lx * n].reshape(ly, n, lx, n)
        out[:, :, r::p, c::p] = block.permute(1, 3, 0, 2)
    return out
