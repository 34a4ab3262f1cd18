"""Argument checks shared by the PSF functions (:mod:`metasensor.optics.psf`,
:mod:`metasensor.optics.widefield`): each raises one line naming the argument."""

from __future__ import annotations

import math

import numpy as np

from metasensor.config import SystemConfig

__all__ = ["check_config", "check_zernike", "check_odd", "check_depth"]


def check_config(cfg) -> None:
    if not isinstance(cfg, SystemConfig):
        raise TypeError(f"cfg must be a SystemConfig, got {type(cfg).__name__}")


def check_zernike(zernike) -> np.ndarray | None:
    if zernike is None:
        return None
    try:
        z = np.asarray(zernike, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"zernike must be a 1-D Noll vector of numbers (waves), got "
                        f"{zernike!r:.60}") from None
    if z.ndim != 1 or z.size == 0:
        raise ValueError(f"zernike must be a 1-D Noll coefficient vector, got shape {z.shape}")
    if not np.isfinite(z).all():
        raise ValueError("zernike contains NaN or infinite values")
    return z


def check_odd(value, name: str) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1 \
            or value % 2 == 0:
        raise ValueError(f"{name} must be a positive odd integer, got {value!r}")
    return int(value)


def check_depth(depth) -> float:
    if isinstance(depth, bool) or not isinstance(depth, (int, float, np.floating)) \
            or not math.isfinite(depth):
        raise ValueError(f"depth must be a finite number of metres, got {depth!r}")
    return float(depth)
