"""Memory left to this process, for the checks made before a large allocation or decode, and
the process's own peak, for the benchmarks' memory figures."""

from __future__ import annotations

__all__ = ["memory_room", "peak_resident_bytes", "reset_peak_resident"]


def memory_room() -> int:
    """Bytes a new allocation can take: the machine's available memory (psutil), or less where
    the process's address-space limit (``RLIMIT_AS``, e.g. ``ulimit -v``) leaves less room."""
    import psutil

    avail = int(psutil.virtual_memory().available)
    try:
        import resource

        soft, _ = resource.getrlimit(resource.RLIMIT_AS)
        if soft != resource.RLIM_INFINITY:
            avail = min(avail, max(0, soft - psutil.Process().memory_info().vms))
    except (ImportError, OSError):  # pragma: no cover - no resource module (Windows)
        pass
    return avail


def peak_resident_bytes() -> int:
    """This process's peak resident memory (bytes) since it started or last ``exec``'d.

    Linux: ``VmHWM`` of ``/proc/self/status``, which an ``exec`` resets. ``getrusage``'s
    ``ru_maxrss`` is not used there: it survives ``fork`` + ``exec``, so a child started by
    ``subprocess`` would report its parent's peak wherever that is the larger. Elsewhere:
    ``ru_maxrss`` (kilobytes on most systems, bytes on macOS), with that caveat.
    :func:`reset_peak_resident` starts a new peak within the process.
    """
    import sys

    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    import resource

    peak = int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    return peak if sys.platform == "darwin" else peak * 1024


def reset_peak_resident() -> bool:
    """Set this process's peak resident memory back to its current resident memory, so that
    :func:`peak_resident_bytes` then reports the peak of the work that follows, not of work done
    before in the same process (a benchmark runner that runs one benchmark after another).

    Linux 4.0 or later: writes ``5`` to ``/proc/self/clear_refs`` (proc(5)), which resets
    ``VmHWM``.

    Returns
    -------
    bool
        True where the peak was reset; False where it cannot be (not Linux, or the file is not
        writable): :func:`peak_resident_bytes` then still includes the earlier work's peak.
    """
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as f:
            f.write("5")
    except OSError:
        return False
    return True
