"""Ctrl-C (SIGINT) and SIGTERM stop a run at once and are never lost.

Three measures, hand-written (no library covers them):

- Library threads never take the signal. The kernel delivers a process signal to any thread
  that does not block it; when zarr's I/O thread (or a thread it starts) takes it, Python only
  marks it, and a main thread blocked in zarr's ``sync()`` wait does not wake until the pending
  chunk write has finished. :func:`quiet_zarr` starts zarr's event-loop thread with SIGINT and
  SIGTERM blocked (threads inherit their creator's mask, so the loop's executor threads block
  them too), and the kernel then interrupts the main thread's wait itself.
- An interrupt is counted before ``KeyboardInterrupt`` is raised (:func:`watch`), and
  :func:`check` raises it again at every commit point of :mod:`metasensor.io.atomic` when one
  arrived while that write was under way: should a finaliser or a library's broad ``except``
  swallow the first one, the write still stops before it puts its output in place (an
  interrupt the caller caught before the write began does not stop later writes).
- Commands (:func:`handle_termination`) treat SIGTERM like Ctrl-C: :class:`Terminated`, a
  ``KeyboardInterrupt``, so the same cleanup paths remove every temporary. A signal the process
  inherited as ignored (a background job of a script, ``nohup``) stays ignored. Inside a
  command, a stop signal taken at any time since the command began stops every later commit,
  even one whose write began after a finaliser swallowed the signal (a signal landing in the
  import system's lock callback is printed as "Exception ignored" and lost otherwise).
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

__all__ = ["Terminated", "watch", "handle_termination", "check", "taken", "received",
           "blocked", "quiet_zarr"]

_STOP = (signal.SIGINT, signal.SIGTERM)
_received: list[int] = []  # every stop signal taken, in order
_command_since: list[int] = []  # the count when each enclosing command began


class Terminated(KeyboardInterrupt):
    """SIGTERM arrived: the run stops as on Ctrl-C (temporaries removed)."""


def _on_signal(signum, frame) -> None:
    _received.append(signum)
    if signum == signal.SIGTERM:
        raise Terminated("terminated by SIGTERM")
    raise KeyboardInterrupt


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def watch() -> int:
    """Count Ctrl-C before raising ``KeyboardInterrupt``, as Python's own handler does;
    returns the count so far (the token a write passes to :func:`check` before its commit).

    The handler is installed only from the main thread and only where SIGINT still has
    Python's default handler (a caller's own handler is left alone).
    """
    if _main_thread() and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _on_signal)
    return len(_received)


@contextlib.contextmanager
def handle_termination() -> Iterator[None]:
    """Commands: inside the block, Ctrl-C and SIGTERM raise (:class:`Terminated` for SIGTERM)
    and are recorded; the handlers before it are restored after it.

    A signal the process was started with ignored stays ignored, as POSIX shells expect: a
    command started in the background of a script (``metasensor ... &``), or under ``nohup``,
    inherits Ctrl-C ignored so that a Ctrl-C meant for the script does not stop it.
    """
    if not _main_thread():
        yield
        return
    old = {sig: signal.getsignal(sig) for sig in _STOP}
    _command_since.append(len(_received))
    for sig in _STOP:
        if old[sig] is not signal.SIG_IGN:
            signal.signal(sig, _on_signal)
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
        _command_since.pop()


def taken() -> int:
    """How many stop signals this process has taken (a token for :func:`received`)."""
    return len(_received)


def received(since: int = 0) -> int | None:
    """The first stop signal taken after the count was ``since``, or ``None``."""
    return _received[since] if len(_received) > since else None


def check(since: int) -> None:
    """Raise again a stop signal taken after :func:`watch` returned ``since`` (called before
    an output is put in place); inside :func:`handle_termination`, any taken since the command
    began."""
    if _command_since:
        since = min(since, _command_since[0])
    if len(_received) > since:
        if _received[since] == signal.SIGTERM:
            raise Terminated("terminated by SIGTERM")
        raise KeyboardInterrupt


@contextlib.contextmanager
def blocked() -> Iterator[None]:
    """SIGINT and SIGTERM blocked in the calling thread for the block; threads started inside
    inherit the block and never take them (the main thread does)."""
    if not _main_thread() or not hasattr(signal, "pthread_sigmask"):  # Windows: no masks
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _STOP)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def quiet_zarr():
    """The ``zarr`` module, its event-loop thread started without SIGINT and SIGTERM (once;
    a loop some other code started first is left as it is)."""
    import zarr

    with contextlib.suppress(ImportError, AttributeError):
        from zarr.core import sync

        if sync.loop[0] is None:
            with blocked():
                sync._get_loop()
    return zarr
