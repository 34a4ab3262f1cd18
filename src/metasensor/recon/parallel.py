"""Run block tasks through Dask: the local threaded scheduler, or a dask.distributed cluster.

``scheduler``: ``None`` or ``"threads"`` (dask's local threaded scheduler, the default),
``"sync"`` (one thread, for debugging), an address such as ``"tcp://10.0.0.1:8786"`` (connects a
``dask.distributed.Client``), or a ``Client`` / ``LocalCluster`` object. Results are handed to
``on_result`` as they arrive, so the caller can write each block out and drop it: at most
``num_workers`` blocks (local) are held in memory at once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

__all__ = ["run_tasks"]


def _client_for(scheduler):
    from distributed import Client

    if isinstance(scheduler, Client):
        return scheduler, False
    if hasattr(scheduler, "scheduler_address"):  # a LocalCluster (or any dask cluster object)
        return Client(scheduler), True
    return Client(str(scheduler)), True


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
        import dask

        mode = "threads" if scheduler is None else scheduler
        workers = 1 if mode == "sync" else max(int(num_workers or 1), 1)
        for start in range(0, len(tasks), workers):
            batch = [dask.delayed(func, pure=False)(t) for t in tasks[start:start + workers]]
            for result in dask.compute(*batch, scheduler=mode, num_workers=workers):
                on_result(result)
                if progress is not None:
                    progress(1)
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
