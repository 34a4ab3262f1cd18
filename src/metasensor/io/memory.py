"""Memory left to this process, for the checks made before a large allocation or decode."""

from __future__ import annotations

__all__ = ["memory_room"]


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
