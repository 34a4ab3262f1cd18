"""Atomic output: files, Zarr stores and result folders appear complete under their final name
or not at all.

Everything is written under a unique temporary name beside its target
(``.<name>.<pid>-<random>.tmp<suffix>``, shortened with a hash to fit 255 bytes) and renamed
into place. A store or folder that already exists is renamed away first, the new one renamed
in, and only then the old one deleted, so a crash at any point leaves the old result, the new
one, or nothing under the final name. Temporaries are removed on every exit path Python sees
(errors, Ctrl-C); those of a killed run (its pid gone, our naming, our user) are removed by the
next run that writes the same target. Hand-written: no library does the folder swap.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import secrets
import shutil
from collections.abc import Iterable, Iterator
from pathlib import Path

from metasensor.io import interrupt

__all__ = ["atomic_path", "atomic_write_text", "atomic_write_bytes", "refuse_overwrite",
           "StagedFolder", "replace_tree", "sibling_name", "remove_stale",
           "is_own_zarr", "discard_tree", "staged_zarr", "write_error"]

_NAME_MAX = 255


def sibling_name(path: str | Path, tag: str, *, suffix: str = "", pid: bool = True) -> str:
    """A hidden name beside ``path``: ``.<name>.<pid>-<random>.<tag><suffix>`` (``pid=False``:
    ``.<name>.<tag>``), with ``<name>`` cut and given a hash when the whole would pass 255
    bytes (the same cut for the same path, so a later run finds its temporaries)."""
    name = Path(path).name
    unique = f"{os.getpid()}-{secrets.token_hex(4)}." if pid else ""
    tail = f".{unique}{tag}{suffix}"
    room = _NAME_MAX - 1 - len(tail.encode())
    raw = name.encode()
    if len(raw) > room:
        digest = hashlib.sha256(raw).hexdigest()[:12]
        name = raw[:room - 13].decode("utf-8", "ignore") + "~" + digest
    return f".{name}{tail}"


def _stale_pattern(path: Path) -> re.Pattern:
    base = sibling_name(path, "x", pid=False)[:-2]  # ".<name>" as this module cuts it
    return re.compile(re.escape(base) + r"\.(\d+)-[0-9a-f]{8}\.(tmp|old)")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale(path: str | Path) -> list[Path]:
    """Remove the temporaries a killed run left beside ``path``: our naming, owned by this
    user, and made by a process that no longer exists. Returns what was removed."""
    path = Path(path)
    pattern = _stale_pattern(path)
    removed = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    for entry in entries:
        m = pattern.match(entry.name)
        if m is None or int(m.group(1)) == os.getpid() or _alive(int(m.group(1))):
            continue
        with contextlib.suppress(OSError):
            if entry.stat(follow_symlinks=False).st_uid != os.getuid():
                continue
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
            removed.append(Path(entry.path))
    return removed


def write_error(path: str | Path, exc: OSError) -> OSError:
    """One line naming the file asked for (not a temporary) and the cause (``errno`` kept)."""
    code, cause = exc.errno, exc.strerror or str(exc)
    if code in (errno.ENOSPC, errno.EDQUOT):
        cause = "no space left on the device"
    elif code == errno.EFBIG:
        cause = "file too large for the device or the file-size limit"
    elif code is None and "written" in cause:  # a short write (tifffile: "N requested and M
        # written"): the disk filled up or the file reached the file-size limit
        code = errno.ENOSPC
        cause = f"the disk is full or the file-size limit is reached ({cause})"
    out = OSError(f"cannot write {path}: {' '.join(str(cause).split())}")
    out.errno = code
    return out


def _umask_mode(p: Path) -> None:
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(p, (0o777 if p.is_dir() else 0o666) & ~umask)


@contextlib.contextmanager
def atomic_path(path: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success rename it onto ``path``.

    The temporary file keeps ``path``'s suffix (so libraries that look at the extension, such
    as tifffile or h5py, behave) unless ``suffix`` is given. On any error, Ctrl-C included, the
    temporary is removed; an ``OSError`` (a full disk) becomes one line naming ``path``.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(f"cannot write {path}: it is a folder")
    since = interrupt.watch()
    tmp_path = path.parent / sibling_name(path, "tmp", suffix=suffix if suffix is not None
                                          else path.suffix)
    try:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            remove_stale(path)
            os.close(os.open(tmp_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        except OSError as exc:  # name the file asked for, not a temporary
            raise write_error(path, exc) from None
        try:
            yield tmp_path
            if tmp_path.is_file():
                _umask_mode(tmp_path)
            interrupt.check(since)  # a Ctrl-C something swallowed: nothing put in place
            os.replace(tmp_path, path)
        except OSError as exc:
            interrupt.check(since)  # stopped meanwhile: the interrupt, not what it broke
            if str(path) in str(exc):  # already names the file
                raise
            raise write_error(path, exc) from None
    except BaseException:
        with contextlib.suppress(OSError):
            if tmp_path.is_dir() and not tmp_path.is_symlink():
                shutil.rmtree(tmp_path)
            else:
                tmp_path.unlink()
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def atomic_write_text(path: str | Path, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def refuse_overwrite(outputs, inputs) -> None:
    """One-line ``ValueError`` if any output path (file or folder) is one of the inputs, or two
    outputs are the same (:func:`metasensor.io.guard.guard` without the lock)."""
    from metasensor.io.guard import guard

    guard(inputs, outputs, lock=False)


_ZARR_META = {"zarr.json", ".zarray", ".zattrs", ".zgroup", ".zmetadata"}
_CHUNK = re.compile(r"^\d+(\.\d+)*$")


def is_own_zarr(path: str | Path) -> bool:
    """``path`` is a Zarr array written by this package: a folder holding only Zarr metadata and
    chunk keys, whose attributes carry the ``"metasensor"`` entry (never a user's folder); or
    an OME-Zarr group of this package (its attributes carry the entry, and every sub-folder is
    a Zarr array of chunk keys only)."""
    path = Path(path)
    if _is_zarr_tree(path, group=True):
        return _has_own_attrs(path)
    return _is_zarr_tree(path, group=False) and _has_own_attrs(path)


def _is_zarr_tree(path: Path, group: bool) -> bool:
    """A folder of Zarr metadata and chunk keys only (``group``: its entries besides metadata
    are Zarr arrays of that kind, the levels of a multiscale image)."""
    if not path.is_dir() or path.is_symlink():
        return False
    try:
        names = set(os.listdir(path))
    except OSError:
        return False
    if not names & ({"zarr.json", ".zgroup"} if group else {"zarr.json", ".zarray"}):
        return False
    for name in names - _ZARR_META:
        if group:
            if name.startswith(".") or not _is_zarr_tree(path / name, group=False):
                return False
        elif name == "c" and (path / "c").is_dir():
            for root, _, files in os.walk(path / "c"):
                parts = Path(root).relative_to(path / "c").parts
                if not all(_CHUNK.match(s) for s in (*parts, *files)):
                    return False
        elif not (_CHUNK.match(name) and (path / name).is_file()):
            return False
    return True


def _has_own_attrs(path: Path) -> bool:
    """The folder's Zarr attributes carry the ``"metasensor"`` entry."""
    names = set(os.listdir(path))
    try:
        if "zarr.json" in names:
            attrs = json.loads((path / "zarr.json").read_text()).get("attributes", {})
        else:
            attrs = json.loads((path / ".zattrs").read_text())
    except (OSError, ValueError, AttributeError, RecursionError):
        return False
    return isinstance(attrs, dict) and "metasensor" in attrs


def replace_tree(new: Path, final: Path) -> None:
    """Move folder ``new`` onto ``final``: an existing ``final`` is renamed away first and
    deleted only after ``new`` is in place (a crash leaves the old or the new one)."""
    old = None
    if final.exists() or final.is_symlink():
        old = final.parent / sibling_name(final, "old")
        os.rename(final, old)
    try:
        os.rename(new, final)
    except BaseException:
        if old is not None:
            os.rename(old, final)
        raise
    if old is not None:
        try:
            _remove(old)
        except KeyboardInterrupt:  # finish removing what is no longer anyone's, then stop
            _remove(old)
            raise


def discard_tree(path: str | Path, settle_s: float = 0.05, tries: int = 40) -> None:
    """Remove a temporary folder that a background writer may still be adding to.

    Zarr writes its chunks from an I/O thread of its own; when Ctrl-C stops the main thread,
    that thread finishes the chunk it holds and can re-create the folder after a first
    removal. The folder is removed until it stays absent for ``settle_s`` seconds (at most
    ``tries`` rounds).

    Parameters
    ----------
    path : str or Path
        The temporary folder.
    settle_s : float
        Seconds the folder must stay absent after a removal.
    tries : int
        Rounds at most.
    """
    import time

    path = Path(path)
    for _ in range(tries):
        shutil.rmtree(path, ignore_errors=True)
        time.sleep(settle_s)
        if not path.exists():
            return


@contextlib.contextmanager
def staged_zarr(path: str | Path) -> Iterator[Path]:
    """Yield a unique temporary folder beside the Zarr store ``path``; on success swap it in
    (:func:`replace_tree`), on any error (Ctrl-C included) remove it (:func:`discard_tree`).

    An existing folder at ``path`` is replaced only if it is a store of this package
    (:func:`is_own_zarr`); anything else is refused with a ``ValueError``, untouched. An
    ``OSError`` becomes one line naming ``path`` (:func:`write_error`).
    """
    path = Path(path)
    since = interrupt.watch()
    if path.exists() and not is_own_zarr(path):
        raise ValueError(f"{path} exists and is not a Zarr store written by metasensor: not "
                         "replaced")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale(path)
    except OSError as exc:
        raise write_error(path, exc) from None
    tmp = path.parent / sibling_name(path, "tmp", suffix=".zarr")  # unique per run
    try:
        yield tmp
        interrupt.check(since)  # a Ctrl-C something swallowed: nothing put in place
        replace_tree(tmp, path)  # the old store renamed away, the new one in, then old deleted
    except BaseException as exc:
        discard_tree(tmp)  # no half-written store left behind
        if isinstance(exc, OSError):
            interrupt.check(since)  # stopped meanwhile: the interrupt, not what it broke
            raise write_error(path, exc) from None
        raise


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()


class StagedFolder:
    """A folder of results built under a temporary sibling (:attr:`path`) and put in place by
    :meth:`commit`; removed when the command ends (or the process exits) if never committed.

    ``names`` are the entries this command writes. A new folder, or one holding only such
    entries (an earlier run's), is replaced as a whole (:func:`replace_tree`); a folder holding
    anything else (the user's files) keeps it: the new entries are moved in one by one, and the
    earlier run's entries that this one did not write are removed.
    """

    def __init__(self, out: str | Path, names: Iterable[str]) -> None:
        self.out = Path(os.path.abspath(out))  # "--out ." has a parent to build beside
        self.names = set(names)
        if self.out.exists() and not self.out.is_dir():
            raise ValueError(f"--out {self.out} exists and is not a folder")
        self.path = self.out.parent / sibling_name(self.out, "tmp")
        self._since = interrupt.watch()
        _on_exit(self.discard)  # before the folder exists: no moment without a cleanup
        try:
            self.out.parent.mkdir(parents=True, exist_ok=True)
            remove_stale(self.out)
            self.path.mkdir()
        except OSError as exc:
            raise write_error(self.out, exc) from None

    def discard(self) -> None:
        """Remove the temporary folder (nothing, once committed)."""
        shutil.rmtree(self.path, ignore_errors=True)

    def commit(self) -> Path:
        """Put the built folder in place; returns the final folder."""
        out, stage = self.out, self.path
        interrupt.check(self._since)  # a Ctrl-C something swallowed: nothing put in place
        try:
            foreign = set(os.listdir(out)) - self.names if out.is_dir() else set()
            here = Path(os.getcwd())
            if not foreign and here != out and out not in here.parents:  # never move the cwd
                replace_tree(stage, out)
                return out
            for name in sorted(self.names):
                src, dst = stage / name, out / name
                if src.is_dir():
                    replace_tree(src, dst)
                elif src.exists():
                    os.replace(src, dst)
                elif dst.is_dir() and not dst.is_symlink():
                    shutil.rmtree(dst)
                elif dst.exists():
                    dst.unlink()
            self.discard()
        except OSError as exc:
            raise write_error(out, exc) from None
        finally:
            import atexit

            atexit.unregister(self.discard)  # if registered there: done with
        return out


def command_context():
    """The click context of the running command, or ``None`` (called from the API)."""
    for name in ("typer._click.globals", "click.globals"):
        with contextlib.suppress(ImportError):
            return __import__(name, fromlist=["x"]).get_current_context(silent=True)
    return None  # pragma: no cover


def _on_exit(callback) -> None:
    """Run ``callback`` when the running command ends (its click context closes, errors and
    Ctrl-C included), else when the process exits."""
    import atexit

    ctx = command_context()
    if ctx is not None:
        ctx.call_on_close(callback)
    else:
        atexit.register(callback)
