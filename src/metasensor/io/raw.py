"""Raw frame streams: multi-page TIFF read one frame at a time (never the whole sequence).

Uncompressed contiguous files are memory-mapped (read-only); others are decoded page by page
with tifffile. A truncated or corrupt file (a broken page chain, a page whose data run past the
end of the file: :mod:`metasensor.io.tiff`) is reported at open time as one clear line. The
file is opened read-only and never modified.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from metasensor.io.tiff import open_tiff

__all__ = ["RawFrames", "open_raw", "read_raw", "write_raw"]


class RawFrames:
    """A read-only sequence of 2-D frames from a multi-page TIFF (or a ``(T, H, W)`` array).

    ``len(raw)``, ``raw.shape`` ``(T, H, W)``, ``raw.dtype``, ``raw[t]`` → a new ``(H, W)``
    array, iteration in page order, ``raw.read(t0, t1)`` → ``(t1-t0, H, W)``. Use as a context
    manager (or call :meth:`close`) to release the file.
    """

    def __init__(self, source, *, mmap: bool = True) -> None:
        self.path: Path | None = None
        self._tif = None
        self._mm: np.ndarray | None = None
        if isinstance(source, np.ndarray):
            if source.ndim == 2:
                source = source[None]
            if source.ndim != 3:
                raise ValueError(f"raw frames must be (T, H, W), got shape {source.shape}")
            self._mm = source
            self.shape = tuple(int(s) for s in source.shape)
            self.dtype = source.dtype.newbyteorder("=")
            return
        self.path = Path(source)
        self._open(mmap)

    def _open(self, mmap: bool) -> None:
        import tifffile

        path = self.path
        if not path.is_file():
            raise FileNotFoundError(f"raw frames not found: {path}")
        tif, pages = open_tiff(path)  # truncated/corrupt files: one ValueError line
        self._tif = tif
        try:
            first = pages[0]
            shape = tuple(first.shape)
            if len(shape) != 2:
                raise ValueError(f"{path}: frames must be 2-D greyscale pages, got {shape}")
            if np.dtype(first.dtype).kind not in "buif":
                raise ValueError(f"{path}: holds {first.dtype} frames; real numbers are expected")
            from metasensor.io.tiff import available_memory

            if math.prod(shape) * np.dtype(first.dtype).itemsize > available_memory():
                raise ValueError(f"{path}: one frame declares {shape}, more than the memory "
                                 "available")
            for k, page in enumerate(pages):
                if tuple(page.shape) != shape or page.dtype != first.dtype:
                    raise ValueError(f"{path}: page {k} is {page.dtype} {page.shape}, unlike "
                                     f"page 0 ({first.dtype} {shape})")
        except ValueError:
            self.close()
            raise
        except Exception as exc:
            self.close()
            raise ValueError(f"{path}: corrupt TIFF ({type(exc).__name__}: {exc})") from None
        self._pages = pages
        self.shape = (len(pages), *shape)
        self.dtype = np.dtype(first.dtype).newbyteorder("=")  # frames in native byte order
        series = tuple(tif.series[0].shape) if tif.series else ()
        if len(series) == 3 and series[1:] == shape and series[0] > len(pages):
            # one IFD for a contiguous series (tifffile truncate=True, ImageJ over 4 GB): the
            # frames are only reachable through the series' data, mapped
            try:
                self._mm = tifffile.memmap(path, mode="r").reshape(series)
            except Exception as exc:
                self.close()
                raise ValueError(f"{path}: {series[0]} frames stored as one contiguous series "
                                 f"that cannot be memory-mapped ({type(exc).__name__})") from None
            self.shape = series
            return
        if mmap and tif.series and tif.series[0].dataoffset is not None \
                and tuple(tif.series[0].shape) in (self.shape, self.shape[1:]):
            try:
                mm = tifffile.memmap(path, mode="r")
                self._mm = mm.reshape(self.shape)
            except Exception:  # fall back to page-by-page decoding
                self._mm = None

    # ---------------------------------------------------------------- sequence protocol
    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, t: int) -> np.ndarray:
        t = int(t)
        if t < 0:
            t += len(self)
        if not 0 <= t < len(self):
            raise IndexError(f"frame {t} out of range 0..{len(self) - 1}")
        if self._mm is not None:
            return np.array(self._mm[t], dtype=self.dtype)
        try:
            frame = self._pages[t].asarray()
        except Exception as exc:
            raise ValueError(f"{self.path}: cannot decode page {t} ({exc})") from None
        return np.asarray(frame, dtype=self.dtype)

    def __iter__(self) -> Iterator[np.ndarray]:
        for t in range(len(self)):
            yield self[t]

    def read(self, t0: int = 0, t1: int | None = None) -> np.ndarray:
        """Frames ``t0 .. t1-1`` as one new ``(t1-t0, H, W)`` array."""
        t1 = len(self) if t1 is None else t1
        if not 0 <= t0 <= t1 <= len(self):
            raise IndexError(f"frame range {t0}..{t1} out of 0..{len(self)}")
        out = np.empty((t1 - t0, *self.shape[1:]), dtype=self.dtype)
        for k in range(t0, t1):
            out[k - t0] = self[k] if self._mm is None else self._mm[k]
        return out

    def close(self) -> None:
        self._mm = None
        if self._tif is not None:
            self._tif.close()
            self._tif = None

    def __enter__(self) -> RawFrames:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"RawFrames({self.path or 'array'}, shape={self.shape}, dtype={self.dtype})"


def open_raw(source, *, mmap: bool = True) -> RawFrames:
    """Open raw frames (a multi-page TIFF path or an array) for streaming."""
    return RawFrames(source, mmap=mmap)


def read_raw(source, t0: int = 0, t1: int | None = None) -> np.ndarray:
    """Read raw frames ``t0 .. t1-1`` into one new array.

    Parameters
    ----------
    source : str, Path or array_like
        A multi-page TIFF (one 2-D frame per page, as ``metasensor simulate`` writes
        ``frames.tif``) or a ``(T, H, W)`` array.
    t0, t1 : int
        The frames to read (default: all).

    Returns
    -------
    numpy.ndarray
        ``(t1 - t0, H, W)`` in the file's dtype (counts, DN). Use :func:`open_raw` to stream
        frames one at a time instead.
    """
    with RawFrames(source) as raw:
        return raw.read(t0, t1)


def write_raw(path: str | Path, frames: np.ndarray, description: str | None = None) -> Path:
    """Write frames ``(T, H, W)`` as an uncompressed multi-page TIFF, atomically."""
    import tifffile

    from metasensor.io.atomic import atomic_path

    frames = np.asarray(frames)
    if frames.ndim == 2:
        frames = frames[None]
    if frames.ndim != 3:
        raise ValueError(f"raw frames must be (T, H, W), got shape {frames.shape}")
    with atomic_path(path) as tmp:
        tifffile.imwrite(tmp, frames, description=description, metadata=None,
                         photometric="minisblack",
                         bigtiff=frames.nbytes > 2**31 - 2**25)
    return Path(path)
