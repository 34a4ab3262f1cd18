"""Checked inputs of :func:`metasensor.simulation.capture.simulate`: the scene on the sensor, the
configuration with its scan period and bit depth, the scan order, the aberration, and the run's
settings, each refused with a one-line error naming what is wrong."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from metasensor.config import SystemConfig
from metasensor.sensor.realign import lenslet_counts
from metasensor.sensor.scan import check_scan_order
from metasensor.simulation import kernels as kern
from metasensor.simulation.motion import Motion
from metasensor.simulation.turbulence import Turbulence

__all__ = ["SimInputs", "check_inputs", "check_scene", "place_scene"]


@dataclass(frozen=True)
class SimInputs:
    """What :func:`check_inputs` resolved.

    Attributes
    ----------
    scene : numpy.ndarray
        ``(H, W)`` float32 radiance on the sensor grid (a copy; ``sensor_shape`` applied).
    cfg : SystemConfig
        The configuration with ``scan`` = the period used and ``bit_depth`` = the one used.
    order : list of (int, int)
        The scan phases in acquisition order.
    zernike : numpy.ndarray or None
        The global Noll vector (waves, float64).
    focus : numpy.ndarray or None
        The deliberate defocus (Noll vector, waves) of the views only.
    lenslets : (int, int)
        Lenslets ``(Ly, Lx)`` on the sensor at every phase.
    """

    scene: np.ndarray
    cfg: SystemConfig
    order: list
    zernike: np.ndarray | None
    focus: np.ndarray | None
    lenslets: tuple[int, int]


def check_scene(scene) -> np.ndarray:
    """``scene`` as a float32 copy, or a one-line error (not 2-D, not numeric, not finite,
    negative)."""
    scene = np.asarray(scene)
    if scene.ndim != 2:
        raise ValueError(f"scene must be a 2D array (H, W), got shape {scene.shape}")
    if scene.dtype.kind not in "uif":
        raise TypeError(f"scene must be numeric, got dtype {scene.dtype}")
    scene = scene.astype(np.float32)
    if not np.isfinite(scene).all():
        raise ValueError("scene contains NaN or infinite values")
    if (scene < 0).any():
        raise ValueError("scene must be non-negative (radiance)")
    return scene


def place_scene(scene: np.ndarray, shape) -> np.ndarray:
    """``scene`` at the top left of a zero sensor of ``shape`` (None: the scene's own)."""
    if shape is None or tuple(shape) == scene.shape:
        return scene
    h, w = (int(s) for s in shape)
    out = np.zeros((h, w), dtype=np.float32)
    hh, ww = min(h, scene.shape[0]), min(w, scene.shape[1])
    out[:hh, :ww] = scene[:hh, :ww]
    return out


def _check_run_options(seed, snr_db, photons, psf, upsample) -> None:
    """One-line errors for the seed, the noise target, the PSF provider and the up-sampler."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    for name, value in (("snr_db", snr_db), ("photons", photons)):
        if value is not None and (isinstance(value, bool)
                                  or not isinstance(value, int | float | np.number)):
            raise TypeError(f"{name} must be a number or None, got {value!r}")
    if psf is not None and not callable(psf):
        raise TypeError("psf must be a callable psf(cfg, zernike, depth, phase=, device=) -> "
                        f"(nnum, nnum, Kf, Kf) fine-grid bank, got {type(psf).__name__}")
    if upsample not in kern.UPSAMPLERS:
        raise ValueError(f"upsample must be one of {kern.UPSAMPLERS}, got {upsample!r}")


def _sampling(cfg: SystemConfig, scan, scan_order, bit_depth) -> tuple[SystemConfig, list]:
    """The configuration with the scan period and bit depth used, and the scan order."""
    if scan is not None and not (isinstance(scan, int | np.integer) and scan >= 1):
        raise ValueError(f"scan must be a positive integer period, got {scan!r}")
    period = cfg.scan if scan is None else scan
    if scan_order is not None and not isinstance(scan_order, str) and scan is None:
        from metasensor.sensor.scan import period_of

        period = period_of(scan_order)
    cfg = cfg.replace(scan=int(period))
    bits = cfg.bit_depth if bit_depth is None else int(bit_depth)
    if bits not in (8, 10, 12, 14, 16):
        raise ValueError(f"bit_depth must be 8, 10, 12, 14 or 16, got {bit_depth!r}")
    cfg = cfg.replace(bit_depth=bits)
    return cfg, check_scan_order(scan_order, cfg.scan)


def _check_zernike(zernike) -> np.ndarray | None:
    if zernike is None:
        return None
    if np.ndim(zernike) != 1:
        raise ValueError(f"zernike must be a 1-D Noll vector, got shape {np.shape(zernike)}")
    zernike = np.asarray(zernike, dtype=np.float64).ravel()
    if not np.isfinite(zernike).all():
        raise ValueError("zernike contains NaN or infinite values")
    return zernike


def _check_dynamics(motion, turbulence, shape) -> None:
    if motion is not None:
        if not isinstance(motion, Motion):
            raise TypeError("motion must be a metasensor.simulation.Motion")
        motion.check(shape)
    if turbulence is not None and not isinstance(turbulence, Turbulence):
        raise TypeError("turbulence must be a metasensor.simulation.Turbulence")


def check_inputs(scene, cfg: SystemConfig, zernike, scan, scan_order, opts: dict) -> SimInputs:
    """Every input of ``simulate`` checked (``opts``: its keyword settings by name)."""
    focus_offset = opts["focus_offset"]
    if not (isinstance(focus_offset, int | float | np.floating) and math.isfinite(focus_offset)):
        raise ValueError(f"focus_offset must be a finite number of waves, got {focus_offset!r}")
    focus = np.array([0.0, 0.0, 0.0, float(focus_offset)]) if focus_offset else None
    if not isinstance(cfg, SystemConfig):
        raise TypeError(f"cfg must be a SystemConfig, got {type(cfg).__name__}")
    if cfg.moving != "mla":  # its frames and views follow the moving MLA's geometry only
        raise ValueError("ms.simulate models a moving MLA (cfg.moving='mla'); for "
                         f"moving={cfg.moving!r} use "
                         "metasensor.simulation.image_scan.simulate_image_scan")
    scene = place_scene(check_scene(scene), opts["sensor_shape"])
    cfg, order = _sampling(cfg, scan, scan_order, opts["bit_depth"])
    n, p, d = cfg.nnum, cfg.scan, cfg.scan_step_px
    ly, lx = lenslet_counts(scene.shape, cfg)
    if ly < 1 or lx < 1:
        raise ValueError(f"scene {scene.shape} holds no lenslet over a {p}x{p} scan "
                         f"(needs at least {n + (p - 1) * d} px per side)")
    scale = opts["scale"]
    if scale is not None and not (isinstance(scale, int | float | np.floating)
                                  and math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number of DN per scene unit, got {scale!r}")
    zernike = _check_zernike(zernike)
    if not (0 < opts["exposure"] <= 1):
        raise ValueError(f"exposure must lie in (0, 1], got {opts['exposure']!r}")
    _check_dynamics(opts["motion"], opts["turbulence"], scene.shape)
    _check_run_options(opts["seed"], opts["snr_db"], opts["photons"], opts["psf"],
                       opts["upsample"])
    return SimInputs(scene, cfg, order, zernike, focus, (ly, lx))
