"""Run block tasks locally (a thread pool) or on a dask.distributed cluster.

``scheduler``: ``None`` or ``"threads"`` (local threads, the default), ``"sync"`` (one after
another, for debugging), an address such as ``"tcp://10.0.0.1:8786"`` (connects a
``dask.distributed.Client``), or a ``Client`` / ``LocalCluster`` object. Results are handed to
``on_result`` as they arrive (in completion order), so the caller can write each block out and
drop it: at most ``num_workers`` blocks (local) are in flight at once. Local threads share the
process's torch threads: with ``w`` workers each block runs on ``torch.get_num_threads() // w``
of them (at least one) while they run, so the workers do not oversubscribe the cores.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

__all__ = ["local_workers", "run_tasks"]


# a block in flight holds about this many times its window's bytes (its spectra, folded AᵀA,
# factorisation and work arrays, measured on the whole-sensor stream's blocks), with a margin
BLOCK_BYTES_PER_WINDOW_BYTE = 16


def local_workers(n_tasks: int, device=None, window_bytes: int | None = None) -> int:
    """Blocks to run at once in this process for ``n_tasks`` blocks on ``device``: one per
    torch thread on the CPU (each block then runs on one thread, :func:`run_tasks`), one on
    CUDA (one device). Why one thread per block on the CPU: docs/decisions.md.

    ``window_bytes``: one block's view window (bytes, float32) where known; then no more
    blocks than half of :func:`metasensor.io.memory.memory_room` holds at
    :data:`BLOCK_BYTES_PER_WINDOW_BYTE` times a window each (at least one)."""
    import torch

    from metasensor.backend import resolve_device

    if resolve_device(device).type != "cpu":
        return 1
    workers = max(1, min(torch.get_num_threads(), int(n_tasks)))
    if window_bytes:
        from metasensor.io.memory import memory_room

        fit = memory_room() // 2 // (BLOCK_BYTES_PER_WINDOW_BYTE * int(window_bytes))
        workers = max(1, min(workers, int(fit)))
    return workers


def _client_for(scheduler):
    from distributed import Client

    if isinstance(scheduler, Client):
        return scheduler, False
    if hasattr(scheduler, "scheduler_address"):  # a LocalCluster (or any dask cluster object)
        return Client(scheduler), True
    return Client(str(scheduler)), True


def _run_local(func, tasks: list, on_result, threads: bool, num_workers, progress) -> None:
    """In this process: one after another (``threads`` False), or on ``num_workers`` threads,
    each result handed on as soon as it is done (a slow block never idles the others)."""
    workers = max(int(num_workers or 1), 1) if threads else 1
    workers = min(workers, len(tasks))
    if workers > 1:
        import torch

        total = torch.get_num_threads()
        torch.set_num_threads(max(total // workers, 1))  # intra-op threads are process-wide
        try:
            _run_pool(func, tasks, on_result, workers, progress)
        finally:
            torch.set_num_threads(total)
        return
    for task in tasks:
        on_result(func(task))
        if progress is not None:
            progress(1)


def _run_pool(func, tasks: list, on_result, workers: int, progress) -> None:
    """``workers`` threads, each result handed on as soon as it is done."""
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    pending = iter(tasks)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        running = {pool.submit(func, t) for _, t in zip(range(workers), pending, strict=False)}
        while running:
            done, running = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                on_result(future.result())
                if progress is not None:
                    progress(1)
                nxt = next(pending, None)
                if nxt is not None:
                    running.add(pool.submit(func, nxt))


def run_tasks(func: Callable[[Any], Any], tasks: Iterable[Any], on_result: Callable[[Any], None],
              scheduler=None, num_workers: int | None = None, progress=None) -> None:
    """Evaluate ``func(task)`` for every task; call ``on_result(result)`` for each, in any order.

    ``progress``: callable(n) advanced by one per finished task (e.g. a tqdm's ``update``).
    """
    tasks = list(tasks)
    if not tasks:
        return
    local = scheduler is None or (isinstance(scheduler, str) and scheduler in ("threads", "sync"))
    if local:
        _run_local(func, tasks, on_result, scheduler != "sync", num_workers, progress)
        return
    if isinstance(scheduler, str) and "://" not in scheduler:
        raise ValueError(f"scheduler must be 'threads', 'sync' or an address like "
                         f"'tcp://host:8786', got {scheduler!r}")
    from distributed import as_completed

    client, owned = _client_for(scheduler)
    try:
        futures = client.map(func, tasks, pure=False)
        for future in as_completed(futures):
            on_result(future.result())
            if progress is not None:
                progress(1)
            future.release()
    finally:
        if owned:
            client.close()
