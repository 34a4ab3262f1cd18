"""Torch device and dtype helpers: NumPy at the public API, PyTorch inside."""

from __future__ import annotations

import numpy as np
import torch

__all__ = ["resolve_device", "as_tensor", "to_numpy", "check_memory"]


def resolve_device(device: str | torch.device | None = None) -> torch.device:
    """``None`` → CUDA when present, else CPU; a string or device is checked and returned."""
    if device is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
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
