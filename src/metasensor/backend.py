"""Torch device and dtype helpers: NumPy at the public API, PyTorch inside."""

from __future__ import annotations

import contextlib
import functools
import warnings

import numpy as np
import torch

__all__ = ["resolve_device", "address_space_limit", "as_tensor", "to_numpy", "check_memory",
           "reproducible", "one_thread_here"]


def address_space_limit() -> int | None:
    """The process's address-space limit in bytes (``ulimit -v``, ``RLIMIT_AS``), None if none."""
    try:
        import resource
    except ImportError:  # not a POSIX system
        return None
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    return None if soft == resource.RLIM_INFINITY else int(soft)


_CPU_UNDER_LIMIT_WARNED = False
CUDA_ADDRESS_SPACE = 64 * 2**30  # bytes of address space CUDA's start is given (docs/decisions.md)


def resolve_device(device: str | torch.device | None = None) -> torch.device:
    """The torch device to compute on.

    Parameters
    ----------
    device : str, torch.device or None
        ``None``: CUDA when present, else the CPU. CUDA's runtime reserves far more virtual
        address space than it allocates and fails to start under a tighter address-space limit
        (``ulimit -v``) than :data:`CUDA_ADDRESS_SPACE` bytes; ``None`` under such a limit is the
        CPU, with one warning. A string or device is checked and returned.

    Returns
    -------
    torch.device
    """
    global _CPU_UNDER_LIMIT_WARNED
    if device is None:
        if not torch.cuda.is_available():
            return torch.device("cpu")
        limit = address_space_limit()
        if limit is not None and limit < CUDA_ADDRESS_SPACE:
            if not _CPU_UNDER_LIMIT_WARNED:
                _CPU_UNDER_LIMIT_WARNED = True
                warnings.warn(f"an address-space limit ({limit / 2**30:.1f} GiB, ulimit -v) is "
                              "set: CUDA does not start under it, computing on the CPU",
                              RuntimeWarning, stacklevel=2)
            return torch.device("cpu")
        return torch.device("cuda")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise ValueError(f"device must be 'cpu', 'cuda' or 'cuda:N', got {device!r}") from exc
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {device!r} requested but CUDA is not available")
    return dev


def as_tensor(array, device: torch.device | str | None = None, dtype=torch.float32) -> torch.Tensor:
    """Convert an array to a tensor on ``device`` without modifying the input (copies if needed)."""
    dev = resolve_device(device)
    if isinstance(array, torch.Tensor):
        return array.to(device=dev, dtype=dtype)
    arr = np.asarray(array)
    return torch.tensor(arr, dtype=dtype, device=dev)  # always a copy: inputs are never modified


def to_numpy(tensor: torch.Tensor) -> np.ndarray:
    return tensor.detach().cpu().numpy()


def check_memory(nbytes: float, what: str) -> None:
    """Raise MemoryError (one line, naming ``what``) before an allocation of ``nbytes`` that the
    memory left to the process (:func:`metasensor.io.memory.memory_room`) cannot hold, instead
    of swapping for minutes first."""
    from metasensor.io.memory import memory_room

    avail = memory_room()
    if nbytes > avail:
        raise MemoryError(f"{what} needs ~{nbytes / 2**30:.1f} GiB, more than the "
                          f"{avail / 2**30:.1f} GiB of memory available")


@contextlib.contextmanager
def reproducible(seed: int):
    """Run the block on one torch thread with deterministic algorithms and torch's CPU random
    state seeded by ``seed``, for bit-for-bit reproducible training; the caller's thread count,
    determinism flag and random state come back afterwards (also on an exception).

    Parameters
    ----------
    seed : int
        ``torch.manual_seed`` inside the block.
    """
    threads, deterministic = torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()
    torch.set_num_threads(1)
    torch.use_deterministic_algorithms(True)
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            yield
    finally:
        torch.set_num_threads(threads)
        torch.use_deterministic_algorithms(deterministic)


@functools.cache
def _openmp_runtimes():
    """The OpenMP runtimes loaded in this process (torch's among them), found once."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController().select(user_api="openmp")


@contextlib.contextmanager
def one_thread_here(device: torch.device | str | None = "cpu"):
    """Run the block's CPU torch operations on one intra-op thread, in the calling thread only.

    ``torch.set_num_threads`` is process-wide: a thread whose first parallel operation falls in
    the window keeps one thread for good, and other callers see the setting change. This
    limits instead the calling thread's own OpenMP thread count (OpenMP's ``nthreads-var`` is
    per thread; ``threadpoolctl`` sets it in every loaded OpenMP runtime), which is the count
    torch's intra-op ``parallel_for`` reads; other threads, threads started meanwhile and
    ``torch.get_num_threads()`` outside the block keep theirs. Restored on exit (also on an
    exception). Where torch runs without OpenMP the block runs as it is.

    Parameters
    ----------
    device : torch.device or str or None
        The device the block computes on (None: the CPU); anything but the CPU leaves the
        threads alone.
    """
    if device is not None and torch.device(device).type != "cpu":
        yield
        return
    torch.get_num_threads()  # this thread's first call sets its count from torch's setting
    with _openmp_runtimes().limit(limits=1):
        yield
