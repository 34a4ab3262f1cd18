"""On-disk cache of PSF banks (and of the 2D sensor's PSFs), keyed by a SHA-256 of everything
a bank depends on.

Location: the environment variable ``METASENSOR_CACHE`` if set, else the folder given to
:func:`set_cache_dir`, else the platform's user cache folder (``platformdirs``:
``~/.cache/metasensor`` on Linux or ``$XDG_CACHE_HOME/metasensor``,
``~/Library/Caches/metasensor`` on macOS, ``%LOCALAPPDATA%\\metasensor\\Cache`` on Windows).
Entries are ``.npy`` files written to a temporary name in the same folder and renamed with
``os.replace`` (atomic), so concurrent writers and readers never see a partial file (two writers
of one key write the same bytes; the last rename wins); a corrupt entry counts as a miss and is
removed. A cache folder that cannot be written (read-only, full) only costs the caching: the
computation goes on.
``stats`` counts hits and misses in this process, and ``compute_seconds``, the CPU seconds
(``time.process_time``, all threads) while banks that missed were being computed (for tests
and benchmarks; :func:`computing`); ``kind_stats`` splits the hits and misses of the PSF
functions by computation (the views' banks apart from the 2D sensor's PSFs).

Size: the folder is kept under ``METASENSOR_CACHE_MAX_GB`` GiB (default
:data:`DEFAULT_MAX_GB`; ``inf`` for no limit). After each store the least recently used banks
(a hit refreshes a bank's modification time) are removed until the folder fits, never the one
just written. Without the cap the cache only grew: 893 banks, 50 GiB, on the development machine
after a few weeks of benchmarks.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import threading
import time
from pathlib import Path

import numpy as np

__all__ = ["cache_dir", "set_cache_dir", "cache_key", "load", "load_first", "store", "stats",
           "kind_stats", "count", "computing", "clear", "max_bytes", "DEFAULT_MAX_GB"]

DEFAULT_MAX_GB = 10.0

_setting: Path | None = None
stats = {"hits": 0, "misses": 0, "compute_seconds": 0.0}
kind_stats: dict[str, dict[str, int]] = {}
"""Hits and misses of :func:`count` by computation (``"view_psfs"``, ``"widefield_psf"``)."""


_busy = {"depth": 0, "since": 0.0}
_busy_guard = threading.Lock()


@contextlib.contextmanager
def computing():
    """A context for computing one missed bank: the process's CPU seconds
    (``time.process_time``, all threads) while at least one such computation runs are added
    to ``stats["compute_seconds"]`` once, however many threads compute at a time (each
    computation timing itself would count the others' CPU too)."""
    with _busy_guard:
        if _busy["depth"] == 0:
            _busy["since"] = time.process_time()
        _busy["depth"] += 1
    try:
        yield
    finally:
        with _busy_guard:
            _busy["depth"] -= 1
            if _busy["depth"] == 0:
                stats["compute_seconds"] += time.process_time() - _busy["since"]


def count(kind: str, hit: bool) -> None:
    """Count one lookup's hit or miss in :data:`stats` and under ``kind`` in
    :data:`kind_stats`."""
    name = "hits" if hit else "misses"
    stats[name] += 1
    row = kind_stats.setdefault(str(kind), {"hits": 0, "misses": 0})
    row[name] += 1


def set_cache_dir(path: str | Path | None) -> None:
    """Set the cache folder for this process (``None``: back to the default).

    ``METASENSOR_CACHE`` in the environment still takes precedence.
    """
    global _setting
    _setting = None if path is None else Path(path).expanduser()


def cache_dir() -> Path:
    """The cache folder in effect (not created here)."""
    env = os.environ.get("METASENSOR_CACHE")
    if env:
        return Path(env).expanduser()
    if _setting is not None:
        return _setting
    from platformdirs import user_cache_dir

    return Path(user_cache_dir("metasensor", appauthor=False))


def max_bytes() -> float:
    """The size cap in bytes, from ``METASENSOR_CACHE_MAX_GB`` (GiB, > 0 or ``inf``)."""
    text = os.environ.get("METASENSOR_CACHE_MAX_GB", "").strip()
    if not text:
        return DEFAULT_MAX_GB * 2**30
    try:
        gb = float(text)
    except ValueError:
        gb = float("nan")
    if not gb > 0:
        raise ValueError(f"METASENSOR_CACHE_MAX_GB must be a positive number of GiB or 'inf', "
                         f"got {text!r}")
    return gb * 2**30


def _evict(root: Path, keep: Path, limit: float) -> int:
    """Remove the least recently used ``*.npy`` in ``root`` (not ``keep``) until the folder's
    banks fit in ``limit`` bytes; returns how many were removed."""
    entries = []
    for f in root.glob("[!.]*.npy"):  # not the ".key.XXXX.npy" files being written now
        with contextlib.suppress(OSError):
            st = f.stat()
            entries.append((st.st_mtime, st.st_size, f))
    total = sum(e[1] for e in entries)
    removed = 0
    for _, size, f in sorted(entries, key=lambda e: e[0]):
        if total <= limit:
            break
        if f == keep:
            continue
        with contextlib.suppress(OSError):
            f.unlink()
            total -= size
            removed += 1
    return removed


def cache_key(*parts) -> str:
    """SHA-256 hex digest of the parts (bytes, str, numbers, NumPy arrays, None)."""
    h = hashlib.sha256()
    for part in parts:
        if isinstance(part, np.ndarray):
            arr = np.ascontiguousarray(part)
            h.update(f"nd{arr.dtype.str}{arr.shape}".encode())
            h.update(arr.tobytes())
        elif isinstance(part, bytes):
            h.update(b"b" + part)
        else:
            h.update(repr(part).encode())
        h.update(b"|")
    return h.hexdigest()


def _path(key: str, folder: Path | None) -> Path:
    return (folder or cache_dir()) / "psf" / f"{key}.npy"


def load(key: str, folder: Path | None = None) -> np.ndarray | None:
    """The cached array for ``key``, or ``None`` (a miss). Counts in :data:`stats`."""
    return load_first([key], folder)[1]


def load_first(keys, folder: Path | None = None, count: bool = True
               ) -> tuple[int | None, np.ndarray | None]:
    """The first of ``keys`` (any iterable, consumed in order until a hit) that is cached:
    ``(its index, the array)``, or ``(None, None)``. Counts one hit or one miss in
    :data:`stats`, however many keys were tried (``count`` False: none)."""
    max_bytes()  # a bad size setting is reported before the work, not after it
    for index, key in enumerate(keys):
        arr = _load_one(key, folder)
        if arr is not None:
            stats["hits"] += count
            return index, arr
    stats["misses"] += count
    return None, None


def _load_one(key: str, folder: Path | None) -> np.ndarray | None:
    """The cached array for ``key`` or None; a damaged entry is removed (a miss)."""
    path = _path(key, folder)
    if path.is_file():
        try:
            arr = np.load(path, allow_pickle=False)
            if not np.isfinite(arr).all():  # damaged in place: a miss, recomputed
                raise ValueError("non-finite entry")
        except (OSError, ValueError, EOFError):
            with contextlib.suppress(OSError):
                path.unlink()
        else:
            with contextlib.suppress(OSError):
                os.utime(path)  # recently used: the last to be evicted
            return arr
    return None


def store(key: str, array: np.ndarray, folder: Path | None = None) -> Path | None:
    """Write ``array`` under ``key`` atomically, then evict the least recently used banks beyond
    the size cap (:func:`max_bytes`); returns the path (``None`` if not writable)."""
    limit = max_bytes()
    path = _path(key, folder)
    from metasensor.io import interrupt
    from metasensor.io.atomic import remove_stale, sibling_name

    since = interrupt.watch()

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale(path)  # what a killed writer of this key left
        tmp = path.parent / sibling_name(path, "tmp", suffix=".npy")  # unique: pid + random
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except OSError:
        return None  # an unwritable cache never breaks the computation
    try:
        with os.fdopen(fd, "wb") as fh:
            np.save(fh, np.ascontiguousarray(array), allow_pickle=False)
        interrupt.check(since)  # a swallowed Ctrl-C: no entry put in place
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError):  # a full cache folder never breaks the computation
            return None
        raise
    if limit != float("inf"):
        _evict(path.parent, path, limit)
    return path


def clear(folder: Path | None = None) -> int:
    """Remove every cached PSF bank; returns how many files were removed."""
    root = (folder or cache_dir()) / "psf"
    count = 0
    for f in root.glob("*.npy") if root.is_dir() else []:
        with contextlib.suppress(OSError):
            f.unlink()
            count += 1
    return count
