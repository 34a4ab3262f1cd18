"""System-aberration calibration for depth: per-view shift maps and the warp that removes them.

A calibration is, per view (u, v), a map ``s_uv(p) = (dy, dx)`` in VIEW pixels: the shift that the
system aberration adds to the view's parallax (its disparity at field point p, from the global
aberration calibration, :mod:`metasensor.dao.system_aberration`). The aberrated view content
at ``p + s_uv(p)`` is the unaberrated content at ``p``, so the corrected view is
``V'_uv(p) = V_uv(p + s_uv(p))``.

Accepted forms: an array ``(nnum, nnum, 2, H, W)`` (or ``(nnum, nnum, 2)`` for field-constant
shifts); an object with ``.shift_maps(shape) -> (nnum, nnum, 2, H, W)`` (the DAO stage's
``SystemAberration``); or a path to its calibration file, loaded with
``metasensor.dao.system_aberration.SystemAberration.load(path)``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

__all__ = ["resolve_shift_maps", "warp_views"]


def resolve_shift_maps(calibration, nnum: int, shape: tuple[int, int]) -> np.ndarray | None:
    """The calibration as a float32 array ``(nnum, nnum, 2, H, W)`` (view px), or ``None``."""
    if calibration is None:
        return None
    if isinstance(calibration, (str, Path)):
        path = Path(calibration)
        if not path.exists():
            raise FileNotFoundError(f"system calibration not found: {path}")
        try:
            from metasensor.dao.system_aberration import SystemAberration
        except ImportError:
            raise ValueError(
                f"cannot read {path}: metasensor.dao.system_aberration.SystemAberration is "
                "not available"
            ) from None
        calibration = SystemAberration.load(path)
    if hasattr(calibration, "shift_maps"):
        maps = np.asarray(calibration.shift_maps(tuple(shape)), dtype=np.float32)
    else:
        maps = np.asarray(calibration, dtype=np.float32)
    if maps.ndim == 3 and maps.shape == (nnum, nnum, 2):
        maps = np.broadcast_to(maps[..., None, None], (nnum, nnum, 2, *shape))
    if maps.shape != (nnum, nnum, 2, *shape):
        raise ValueError(
            f"calibration shift maps must have shape {(nnum, nnum, 2, *shape)}, got {maps.shape}"
        )
    if not np.isfinite(maps).all():
        raise ValueError("calibration shift maps contain NaN or infinite values")
    return maps


def warp_views(views: torch.Tensor, shifts: torch.Tensor, chunk: int = 8) -> torch.Tensor:
    """``V'_i(p) = V_i(p + s_i(p))`` for views ``(N, H, W)`` and shifts ``(N, 2, H, W)`` (dy, dx)
    in pixels; bilinear (torch's bicubic, Keys a = −0.75, shifts content by up to ~0.05 px),
    border values repeated. Returns a new tensor."""
    n, h, w = views.shape
    ys = torch.arange(h, dtype=torch.float32, device=views.device)[:, None]
    xs = torch.arange(w, dtype=torch.float32, device=views.device)[None, :]
    out = torch.empty_like(views)
    for start in range(0, n, chunk):
        sl = slice(start, min(n, start + chunk))
        py = ys + shifts[sl, 0]
        px = xs + shifts[sl, 1]
        grid = torch.stack([2 * px / max(w - 1, 1) - 1, 2 * py / max(h - 1, 1) - 1], dim=-1)
        out[sl] = torch.nn.functional.grid_sample(views[sl, None], grid, mode="bilinear",
                                                  padding_mode="border", align_corners=True)[:, 0]
    return out
