"""napari-LF / LFDisplay calibration files (``.lfc``, HDF5) as a :class:`Calibration`.

Layout read (h5py): group ``geometry`` with attributes ``nu``, ``nv`` (pixels behind a lenslet
after their rectification), ``ns``, ``nt`` (lenslets per row and column) and the dataset
``reverseCoefficients``: the map from lenslet coordinates (s = column, t = row; integers at
lenslet centres) to raw-pixel coordinates (x = column, y = row; pixel centres at integers), a
cubic polynomial (2, 10) with terms ``1, s, t, s², st, t², s³, s²t, st², t³`` (their
``CubicWarp``), or its affine (2, 3: ``1, s, t``) or homogeneous isometry (3, 3) forms.

This package rectifies with one similarity per sensor (pitch, rotation, centre): the lenslet
centres the polynomial gives are fitted by least squares, and the r.m.s. distance between the
two is kept as the calibration's ``fit_residual`` (a cubic distortion the similarity cannot
follow; refused above :data:`metasensor.sensor.checks.MAX_RESIDUAL_PX`). Hand-written (no
library reads these files outside napari-LF).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from metasensor.sensor.calibration import Calibration

__all__ = ["read_lfc", "lenslet_centres"]


def _terms(s: np.ndarray, t: np.ndarray, n: int) -> np.ndarray:
    one = np.ones_like(s)
    cubic = [one, s, t, s * s, s * t, t * t, s**3, s * s * t, s * t * t, t**3]
    return np.stack(cubic[:n])


def lenslet_centres(coeffs: np.ndarray, s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Raw-pixel (row, col) of lenslet centres (s, t) under ``reverseCoefficients``:
    (2, N) for the arrays ``s`` (columns) and ``t`` (rows) of N lenslets."""
    c = np.asarray(coeffs, dtype=np.float64)
    s, t = np.asarray(s, float).ravel(), np.asarray(t, float).ravel()
    if c.shape in ((2, 10), (2, 3)):
        xy = c @ _terms(s, t, c.shape[1])
    elif c.shape == (3, 3):  # homogeneous: (x, y, 1) = C (s, t, 1)
        h = c @ np.stack([s, t, np.ones_like(s)])
        xy = h[:2] / h[2]
    else:
        raise ValueError(f"reverseCoefficients must be (2, 10), (2, 3) or (3, 3), got {c.shape}")
    return np.stack([xy[1], xy[0]])  # (row = y, col = x)


def read_lfc(path: str | Path, nnum: int | None = None,
             sensor_shape: tuple[int, int] | None = None) -> Calibration:
    """A napari-LF calibration file as a :class:`Calibration` (module docstring).

    ``nnum``: pixels per lenslet (default the file's ``nu``, which must equal ``nv``);
    ``sensor_shape``: (rows, cols) of the raw frames (default the shape of the file's
    ``radiometry/radiometry`` image). Keeps the lenslets whose blocks lie on the sensor.
    """
    import h5py

    from metasensor.sensor.calibrate import _keep_lenslets
    from metasensor.sensor.checks import MAX_RESIDUAL_PX

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"calibration file not found: {path}")
    try:
        with h5py.File(path, "r") as f:
            if "geometry" not in f or "reverseCoefficients" not in f["geometry"]:
                raise ValueError(f"{path}: no geometry/reverseCoefficients (not a napari-LF "
                                 "geometric calibration)")
            geo = f["geometry"]
            coeffs = np.asarray(geo["reverseCoefficients"], dtype=np.float64)
            nu, nv = (int(geo.attrs.get(k, 0)) for k in ("nu", "nv"))
            ns, nt = (int(geo.attrs.get(k, 0)) for k in ("ns", "nt"))
            if sensor_shape is None and "radiometry" in f and "radiometry" in f["radiometry"]:
                sensor_shape = tuple(int(v) for v in f["radiometry"]["radiometry"].shape[:2])
    except (OSError, RuntimeError, KeyError) as exc:
        raise ValueError(f"{path}: not a readable HDF5 calibration ({exc})") from None
    if nnum is None:
        if nu != nv or nu < 3 or nu % 2 == 0:
            raise ValueError(f"{path}: nu = {nu}, nv = {nv}; give nnum (odd, >= 3)")
        nnum = nu
    if sensor_shape is None:
        raise ValueError(f"{path}: no radiometry image to take the sensor size from; give "
                         "sensor_shape")
    if ns < 2 or nt < 2:
        raise ValueError(f"{path}: ns = {ns}, nt = {nt} lenslets: too few to fit a grid")
    tt, ss = np.meshgrid(np.arange(nt, dtype=float), np.arange(ns, dtype=float), indexing="ij")
    pos = lenslet_centres(coeffs, ss, tt)  # (2, N) row, col
    # similarity: row = c0 + s·p sinθ + t·p cosθ ; col = c1 + s·p cosθ − t·p sinθ
    s, t = ss.ravel(), tt.ravel()
    one, zero = np.ones_like(s), np.zeros_like(s)
    a = np.concatenate([np.stack([one, zero, s, t], 1), np.stack([zero, one, -t, s], 1)])
    sol, *_ = np.linalg.lstsq(a, np.concatenate([pos[0], pos[1]]), rcond=None)
    c0, c1, ps, pc = sol
    pitch, rot = math.hypot(ps, pc), math.degrees(math.atan2(ps, pc))
    resid = float(np.sqrt(np.mean(np.sum((a @ sol - np.concatenate([pos[0], pos[1]]))
                                         .reshape(2, -1) ** 2, axis=0))))
    if resid > MAX_RESIDUAL_PX:
        raise ValueError(f"{path}: its cubic lenslet map departs from one pitch and rotation by "
                         f"{resid:.2f} px r.m.s.; this package rectifies with a similarity only")
    t_rad = math.radians(rot)
    m = pitch / nnum * np.array([[math.cos(t_rad), math.sin(t_rad)],
                                 [-math.sin(t_rad), math.cos(t_rad)]])
    origin, kept = _keep_lenslets(np.array([c0, c1]), m, nnum, sensor_shape, [np.zeros(2)])
    return Calibration(nnum=nnum, pitch=pitch, rotation=rot, center=tuple(origin),
                       lenslets=kept, sensor_shape=sensor_shape, moving="image",
                       fit_residual=round(resid, 4))
