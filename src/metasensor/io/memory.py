"""Memory left to this process, for the checks made before a large allocation or decode, and
the process's own peak, for the benchmarks' memory figures."""

from __future__ import annotations

__all__ = ["memory_room", "peak_resident_bytes"]


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
