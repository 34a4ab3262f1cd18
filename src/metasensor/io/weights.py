"""Network weights as ``.npz`` files (float32 arrays, no pickle): what the shipped networks
(the plug-and-play denoiser, the depth-edge refiner) are stored and read as."""

from __future__ import annotations

import io
from importlib import resources
from pathlib import Path

import numpy as np
import torch

__all__ = ["save_state", "read_state", "packaged_file"]


def save_state(model: torch.nn.Module, path: str | Path, **sizes: int) -> None:
    """Write ``model``'s parameters and buffers as float32 arrays and its integer ``sizes``
    (the constructor's arguments) as ``_name`` entries, atomically.

    Parameters
    ----------
    model : torch.nn.Module
    path : str or Path
        The ``.npz`` file.
    **sizes : int
        Named integers that rebuild the model (e.g. ``features=32``).
    """
    from metasensor.io.atomic import atomic_write_bytes

    arrays = {k: v.detach().cpu().numpy().astype(np.float32) for k, v in model.state_dict().items()}
    arrays.update({f"_{k}": np.array(int(v)) for k, v in sizes.items()})
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    atomic_write_bytes(Path(path), buf.getvalue())


def read_state(path: str | Path) -> tuple[dict[str, int], dict[str, torch.Tensor]]:
    """The ``sizes`` and the state dict :func:`save_state` wrote to ``path`` (no pickle).

    Returns
    -------
    sizes : dict of str to int
    state : dict of str to torch.Tensor
    """
    with np.load(Path(path), allow_pickle=False) as z:
        sizes = {k[1:]: int(z[k]) for k in z.files if k.startswith("_")}
        state = {k: torch.from_numpy(np.array(z[k])) for k in z.files if not k.startswith("_")}
    return sizes, state


def packaged_file(package: str, name: str):
    """Context manager: a filesystem path of ``data/name`` inside ``package`` (shipped data)."""
    return resources.as_file(resources.files(package).joinpath("data", name))
