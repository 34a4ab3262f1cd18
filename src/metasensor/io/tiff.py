"""Checked TIFF reading: a truncated or corrupt file is one clear ``ValueError`` line.

tifffile does not raise on a broken page chain: it logs (``logging`` logger ``"tifffile"``) and
returns the pages it could reach, so a truncated 225-page stack reads as one page. The helpers
here capture those log records (the user never sees them), check that every page's data lie
inside the file and that the file holds as many pages as its description says, and raise
``TiffReadError("<path>: truncated or corrupt TIFF (...)")`` (a ``ValueError``) otherwise; a
file that is no TIFF at all is ``TiffReadError("<path>: not a readable TIFF (...)")``. Files are
opened read-only.
"""

from __future__ import annotations

import json
import logging
import math
import os
from pathlib import Path

import numpy as np

__all__ = ["TiffReadError", "TiffWarnings", "checked_pages", "first_line", "open_tiff",
           "read_tiff", "truncated", "unreadable"]


def first_line(exc: BaseException) -> str:
    """``"<type>: <first line of the message>"`` of an exception (readers raise long ones)."""
    return f"{type(exc).__name__}: {(str(exc).strip().splitlines() or [''])[0]}"


class TiffReadError(ValueError):
    """A file that is not a readable TIFF, or a truncated or corrupt one (one line)."""


class TiffWarnings(logging.Handler):
    """Collect (and keep off stderr) tifffile's logged warnings and errors while in use."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage())

    def __enter__(self) -> TiffWarnings:
        self._logger = logging.getLogger("tifffile")
        self._propagate = self._logger.propagate
        self._logger.addHandler(self)
        self._logger.propagate = False
        return self

    def __exit__(self, *exc) -> None:
        self._logger.removeHandler(self)
        self._logger.propagate = self._propagate


def truncated(path: Path | str, detail: str) -> TiffReadError:
    """The one-line error for a truncated or corrupt TIFF."""
    detail = " ".join(str(detail).split())  # one line, whatever tifffile said
    return TiffReadError(f"{path}: truncated or corrupt TIFF ({detail})")


def unreadable(path: Path | str, detail: str) -> TiffReadError:
    """The one-line error for a file that is not a readable TIFF at all."""
    detail = " ".join(str(detail).split())
    return TiffReadError(f"{path}: not a readable TIFF ({detail})")


def _expected_pages(tif, first) -> int | None:
    """How many pages the file's own metadata says it holds, or ``None`` (it does not say):
    this package's ``metasensor.view_shape`` of a view stack, tifffile's shaped
    ``{"shape": ...}``, ImageJ's ``images=``. A claimed shape whose trailing axes are not the
    first page's is no claim (a foreign or copied description)."""
    page = tuple(int(s) for s in first.shape)
    try:
        meta = json.loads(first.description or "")
    except (TypeError, ValueError, RecursionError):
        meta = None
    shape = None
    if isinstance(meta, dict):
        extra = meta.get("metasensor")
        if isinstance(extra, dict) and extra.get("kind") == "views":
            shape = extra.get("view_shape")
        elif "shape" in meta:
            shape = meta.get("shape")
    if isinstance(shape, list) and page and len(shape) >= len(page):
        try:
            shape = [int(s) for s in shape]
        except (TypeError, ValueError):
            return None
        if tuple(shape[len(shape) - len(page):]) != page:
            return None
        return math.prod(shape[: len(shape) - len(page)])
    try:
        images = (tif.imagej_metadata or {}).get("images") if tif.is_imagej else None
    except Exception:  # noqa: BLE001 - foreign metadata: no claim
        images = None
    return int(images) if isinstance(images, int) and images > 0 else None


def checked_pages(tif, path: Path | str) -> list:
    """All pages of an open ``tifffile.TiffFile``, or ``ValueError`` (one line) when the page
    chain is broken, a page's data run past the end of the file, or there are fewer pages than
    the file's description says."""
    path = Path(path)
    size = os.path.getsize(path)
    try:
        with TiffWarnings() as warned:
            pages = list(tif.pages)
    except Exception as exc:  # noqa: BLE001 - tifffile raises many types for corrupt files
        raise truncated(path, first_line(exc)) from None
    if warned.messages:
        raise truncated(path, f"after page {len(pages)}: {warned.messages[0]}")
    if not pages:
        raise TiffReadError(f"{path}: TIFF has no pages")
    for k, page in enumerate(pages):
        offsets, counts = page.dataoffsets, page.databytecounts
        if not offsets or max(o + c for o, c in zip(offsets, counts, strict=True)) > size:
            raise truncated(path, f"page {k} of {len(pages)} runs past the end of the "
                                  f"{size}-byte file")
    expected = _expected_pages(tif, pages[0])
    if expected is not None and len(pages) < expected:
        first = pages[0]
        # one IFD for a contiguous series (tifffile's truncate=True, ImageJ > 4 GB) is a valid
        # layout when the file holds all the series' data; anything else lost pages
        whole = bool(first.is_contiguous and first.dataoffsets) and \
            first.dataoffsets[0] + expected * first.nbytes <= size
        if len(pages) > 1 or not whole:
            raise truncated(path, f"{len(pages)} of the {expected} pages its description names")
    return pages


def open_tiff(path: Path | str):
    """Open a TIFF read-only (tifffile's log records captured): the ``TiffFile`` and its
    :func:`checked_pages`. Close the file when done (``ValueError`` closes it for you)."""
    import tifffile

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"TIFF file not found: {path}")
    try:
        with TiffWarnings() as warned:
            tif = tifffile.TiffFile(path, mode="rb")
    except Exception as exc:  # noqa: BLE001 - tifffile raises many types for corrupt files
        raise unreadable(path, first_line(exc)) from None
    try:
        if warned.messages:
            with TiffWarnings():
                some = len(tif.pages) > 0
            if not some:  # not even a first page: not a TIFF of any use
                raise unreadable(path, warned.messages[0])
            raise truncated(path, warned.messages[0])
        pages = checked_pages(tif, path)
    except BaseException:
        tif.close()
        raise
    return tif, pages


def available_memory() -> int:
    """Bytes of memory a new allocation can take (:func:`metasensor.io.memory.memory_room`:
    psutil's ``available``, or less under an address-space limit)."""
    from metasensor.io.memory import memory_room

    return memory_room()


def _check_series(tif, path: Path, decoded: bool) -> None:
    """Refuse complex data, and (``decoded``) data whose declared size exceeds the memory
    available, before a byte is decoded (a small compressed file can declare gigabytes)."""
    if not tif.series:
        return
    series = tif.series[0]
    dtype = np.dtype(series.dtype)
    if dtype.kind not in "buif":
        raise TiffReadError(f"{path}: holds {dtype} data; real numbers are expected")
    need = math.prod(int(s) for s in series.shape) * dtype.itemsize
    if decoded and need > available_memory():
        raise TiffReadError(f"{path}: declares {need / 2**30:.1f} GiB of image data, more than "
                            f"the {available_memory() / 2**30:.1f} GiB of memory available")


def _check_uniform(tif, pages: list, path: Path) -> None:
    """A series spanning every page is read from page 0's layout: each page's own header must
    agree with it (a damaged one would be read as if it did; tifffile: "incompatible
    keyframe")."""
    if len(pages) < 2 or not tif.series:
        return
    series, first = tif.series[0], pages[0]
    if math.prod(series.shape) != len(pages) * math.prod(first.shape):
        return  # the series is not the pages (thumbnails, sub-series): nothing to compare
    for k, page in enumerate(pages[1:], 1):
        if page.shape != first.shape or page.dtype != first.dtype:
            raise truncated(path, f"page {k} is {page.dtype} {page.shape}, unlike page 0 "
                                  f"({first.dtype} {first.shape})")


def read_tiff(path: Path | str, *, mmap: bool = False) -> np.ndarray:
    """The first series of a TIFF as an array (what ``tifffile.imread`` returns), after
    :func:`checked_pages`; ``mmap`` maps uncompressed data instead of reading it. A truncated or
    corrupt file is ``TiffReadError("<path>: truncated or corrupt TIFF (...)")``."""
    path = Path(path)
    tif, pages = open_tiff(path)
    try:
        _check_series(tif, path, decoded=not mmap)
        _check_uniform(tif, pages, path)
        with TiffWarnings() as warned:
            arr = tif.asarray(out="memmap") if mmap else tif.asarray()
    except TiffReadError:
        raise
    except Exception as exc:  # noqa: BLE001 - tifffile raises many types for corrupt files
        raise truncated(path, first_line(exc)) from None
    finally:
        tif.close()
    if warned.messages:
        raise truncated(path, warned.messages[0])
    return arr
