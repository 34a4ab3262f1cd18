"""Provenance of a result folder: what ``summary.json`` records about how it was made."""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

__all__ = ["provenance", "file_digest"]


def file_digest(path: str | Path, chunk: int = 1 << 22) -> str:
    """SHA-256 of a file (streamed), or of a folder's files (names and contents, sorted: a
    Zarr store)."""
    path = Path(path)
    h = hashlib.sha256()
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    for p in files:
        if path.is_dir():
            h.update(str(p.relative_to(path)).encode())
        with open(p, "rb") as fh:
            while block := fh.read(chunk):
                h.update(block)
    return h.hexdigest()


def provenance(inputs: dict[str, str | Path | None], settings: dict | None = None) -> dict:
    """``{"version", "command", "inputs": {name: {"path", "sha256"}}, "settings"}``: the package
    version, the command line (``sys.argv``), a checksum of every input file given (None
    entries skipped) and the settings used."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        ver = version("metasensor")
    except PackageNotFoundError:  # pragma: no cover - run from a source tree
        ver = "unknown"
    files = {name: {"path": str(p), "sha256": file_digest(p)}
             for name, p in inputs.items() if p is not None and Path(p).exists()}
    return {"version": ver, "command": [Path(sys.argv[0]).name, *sys.argv[1:]],
            "inputs": files, "settings": dict(settings or {})}
