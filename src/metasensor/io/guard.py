"""What every command checks before it reads or writes: its outputs never replace an input or
each other, its inputs are regular files (or Zarr folders), and no other run writes the same
output at the same time.

:func:`guard` is the one call a command makes with the paths it reads and the paths it will
write (generated names, figures and side files included). Paths compare by their real location
(symbolic links followed, hard links by inode); an output also conflicts with an input inside it
(a folder it replaces) or around it (a file written into an input store). Outputs are locked
(``fcntl.flock`` on a hidden ``.<name>.lock`` beside each) until the command ends, so a second
run writing the same output fails at once with one line instead of interleaving with the first.
Hand-written: no library offers this set of checks.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from collections.abc import Iterable
from pathlib import Path

from metasensor.io.atomic import _on_exit, command_context, is_own_zarr, sibling_name

__all__ = ["guard", "npy_argument", "OutputLocked", "remove_free_lock"]

_held: list[tuple[int, Path, tuple]] = []


class OutputLocked(ValueError):
    """Another run is writing the same output (one line naming it)."""


def npy_argument(text: str | os.PathLike | None) -> Path | None:
    """The file of an option that takes either inline values or a ``.npy`` path (``--zernike``),
    or ``None`` when it names no file."""
    if text is None:
        return None
    s = str(text).strip()
    return Path(s) if s.lower().endswith(".npy") else None


class _Resolver:
    """Real paths (links followed) as strings, each folder resolved once."""

    def __init__(self) -> None:
        self._dirs: dict[str, str] = {}

    def __call__(self, p: Path) -> str:
        p = Path(os.path.abspath(p))
        if os.path.islink(p):
            return os.path.realpath(p)
        parent = str(p.parent)
        if parent not in self._dirs:
            self._dirs[parent] = os.path.realpath(parent)
        return os.path.join(self._dirs[parent], p.name)


def _real(p: Path) -> Path:
    return Path(os.path.realpath(os.path.abspath(p)))


def _same(a: Path, b: Path) -> bool:
    if _real(a) == _real(b):
        return True
    try:  # hard links: the same inode under two names
        return os.path.samefile(a, b)
    except OSError:
        return False


def _within(inner: Path, outer: Path) -> bool:
    """``inner`` lies inside folder ``outer`` (by real path)."""
    try:
        _real(inner).relative_to(_real(outer))
    except ValueError:
        return False
    return _real(inner) != _real(outer)


def _check_input(p: Path) -> None:
    try:
        mode = os.stat(p).st_mode
    except OSError:
        return  # missing: the command names it in its own words
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise ValueError(f"input {p} is not a regular file (a named pipe, socket or device): "
                         "refused, reading it could block forever")


def _check_output(p: Path, store: bool) -> None:
    try:
        st = os.lstat(p)
    except OSError:
        return
    mode = os.stat(p).st_mode if stat.S_ISLNK(st.st_mode) and p.exists() else st.st_mode
    if store or p.suffix.lower() == ".zarr":
        if stat.S_ISDIR(mode) and not is_own_zarr(p):
            raise ValueError(f"output {p} exists and is not a Zarr store written by metasensor: "
                             "not replaced (move it away or choose another name)")
        if not stat.S_ISDIR(mode) and stat.S_ISREG(mode):
            raise ValueError(f"output {p} exists and is a file, not a Zarr store: not replaced")
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise ValueError(f"output {p} exists and is not a regular file (a named pipe, socket "
                         "or device): not replaced")


def guard(inputs: Iterable, outputs: Iterable, *, folders: Iterable = (),
          lock: bool | Iterable = True) -> None:
    """Refuse (one-line ``ValueError``) a command whose outputs would replace its inputs.

    Parameters
    ----------
    inputs : iterable of path or None
        Everything the command reads (files, Zarr stores); ``None`` entries are skipped. An
        existing input that is not a regular file or folder (a named pipe) is refused.
    outputs : iterable of path or None
        Every file or store the command writes or replaces, generated names included. Two
        outputs naming the same file, an output that is an input, lies inside an input folder
        or contains an input, and an existing ``.zarr`` folder that is not a metasensor store,
        are refused.
    folders : iterable of path or None
        Result folders the command writes into (their files belong in ``outputs``): refused when
        one is an input or a file; locked like the outputs.
    lock : bool or iterable of path
        Hold a lock on every output (or on the paths given: one per family of generated names)
        until the command ends (:class:`OutputLocked` if another run holds one); only inside a
        command (a click context), not from the API.
    """
    ins = [Path(p) for p in inputs if p is not None]
    outs = [Path(p) for p in outputs if p is not None]
    dirs = [Path(p) for p in folders if p is not None]
    for p in ins:
        _check_input(p)
    real = _Resolver()
    in_real = [(p, real(p)) for p in ins]
    in_ids = {}  # hard links: the same inode under another name
    for p in ins:
        with contextlib.suppress(OSError):
            st = os.stat(p)
            in_ids[(st.st_dev, st.st_ino)] = p
    seen: dict[str, Path] = {}
    for out in outs:
        r = real(out)
        other = seen.setdefault(r, out)
        if other is not out:
            raise ValueError(f"two outputs of this command are the same file: {other} and "
                             f"{out}")
        for inp, ri in in_real:
            if r == ri or r.startswith(ri + os.sep) or ri.startswith(r + os.sep):
                raise ValueError(f"output {out} would overwrite the input {inp}")
        try:
            st = os.stat(out)
        except OSError:
            continue  # not there yet: nothing to compare or replace
        if (st.st_dev, st.st_ino) in in_ids:
            raise ValueError(f"output {out} would overwrite the input "
                             f"{in_ids[(st.st_dev, st.st_ino)]}")
        _check_output(out, store=False)
    for d in dirs:
        if d.exists() and not d.is_dir():
            raise ValueError(f"output folder {d} exists and is not a folder")
        for inp in ins:
            if _same(d, inp) or _within(d, inp):
                raise ValueError(f"output {d} would overwrite the input {inp}")
    if lock is not False and command_context() is not None:
        paths = [*dirs, *(o for o in outs if not any(_within(o, d) for d in dirs))] \
            if lock is True else [Path(p) for p in lock]
        _lock_all(paths)


def _lock_all(paths: list[Path]) -> None:
    from metasensor.io.interrupt import blocked

    taken = []
    with blocked():  # Ctrl-C waits until every lock made is registered for its release
        try:
            for p in paths:
                taken.append(_lock(p))
        except BaseException:
            for item in reversed(taken):  # last made, first removed
                _release(item)
            raise
        _held.extend(taken)
        # released however the command ends, the last taken first
        _on_exit(lambda: [_release(t) for t in reversed(taken) if t in _held])


def _lock(p: Path) -> tuple[int, Path, tuple]:
    """Take ``.<name>.lock`` beside ``p`` (created, and removed on release)."""
    p = Path(os.path.abspath(p))
    try:
        return _try_lock(p)
    except OSError as exc:  # a read-only or full folder: named, one line
        from metasensor.io.atomic import write_error

        raise write_error(p, exc) from None


def _try_lock(p: Path) -> tuple[int, Path, tuple]:
    import fcntl

    made = [d for d in (p.parent, *p.parent.parents) if not d.exists()]
    p.parent.mkdir(parents=True, exist_ok=True)
    lock = p.parent / sibling_name(p, "lock", pid=False)
    for _ in range(20):
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno not in (errno.EAGAIN, errno.EACCES):
                raise
            raise OutputLocked(f"another metasensor run is writing {p} (lock {lock.name}); "
                               "wait for it to finish or choose another output") from None
        try:  # the holder before us may have removed the file it locked: lock the new one
            if os.fstat(fd).st_ino == os.stat(lock).st_ino:
                os.ftruncate(fd, 0)
                os.write(fd, f"{os.getpid()}\n".encode())
                return fd, lock, tuple(made)
        except FileNotFoundError:
            pass
        os.close(fd)
    raise OutputLocked(f"cannot lock {lock}: it keeps being replaced")  # pragma: no cover


def _release(item: tuple[int, Path, tuple]) -> None:
    fd, lock, made = item
    if item in _held:
        _held.remove(item)
    with contextlib.suppress(OSError):
        lock.unlink()  # still ours: unlinked before the lock is let go
    with contextlib.suppress(OSError):
        os.close(fd)
    for d in made:  # folders made only for the lock, left empty by a failed run
        with contextlib.suppress(OSError):
            d.rmdir()


def remove_free_lock(p: str | os.PathLike) -> bool:
    """Remove the lock file beside output ``p`` (``.<name>.lock``) if no process holds it (a run
    ended by force left it); a held lock is never touched. Returns whether one was removed."""
    import fcntl

    p = Path(os.path.abspath(p))
    lock = p.parent / sibling_name(p, "lock", pid=False)
    try:
        fd = os.open(lock, os.O_RDWR)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return False  # a live run holds it
    try:  # held by us now: unlinked before release, as a finishing run does
        if os.fstat(fd).st_ino != os.stat(lock).st_ino:
            return False  # replaced meanwhile by another run's: not ours to remove
        lock.unlink()
        return True
    except OSError:
        return False
    finally:
        os.close(fd)
