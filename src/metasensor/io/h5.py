"""HDF5 files written whole or not at all, and read with one-line errors.

h5py writing straight to a file on a full disk prints HDF5's error stack and can crash the
interpreter (a segmentation fault when the library's buffers fail to flush). :func:`atomic_h5`
builds the file in memory (h5py on a ``BytesIO``) and writes the bytes with plain Python I/O
(:func:`metasensor.io.atomic.atomic_write_bytes`), so a full disk is one ``OSError`` line naming
the file. :func:`h5_errors` turns whatever h5py raises on a damaged file into one
``ValueError`` line naming it.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from pathlib import Path

__all__ = ["atomic_h5", "h5_errors"]


@contextlib.contextmanager
def atomic_h5(path: str | Path) -> Iterator:
    """Yield a writable ``h5py.File`` held in memory; on success write it to ``path``
    atomically (nothing is written on error)."""
    import h5py

    from metasensor.io.atomic import atomic_write_bytes

    buffer = io.BytesIO()
    with h5py.File(buffer, "w") as f:
        yield f
    atomic_write_bytes(path, buffer.getvalue())


@contextlib.contextmanager
def h5_errors(path: str | Path, what: str = "HDF5 file") -> Iterator[None]:
    """Re-raise any error of reading ``path`` (h5py's ``OSError``, ``KeyError``,
    ``RuntimeError`` on damaged files) as one ``ValueError`` line naming it."""
    try:
        yield
    except (ValueError, FileNotFoundError, MemoryError):
        raise
    except Exception as exc:  # noqa: BLE001 - damaged files raise many types
        text = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        raise ValueError(f"{path}: not a readable {what} ({text})") from None
