"""Captures of a scanning light-field system whose *image* moves over a fixed MLA (any period).

Geometry (docs/conventions.md, ``moving="image"``). Lenslet (ly, lx) covers sensor pixels
``[ly·nnum, (ly+1)·nnum)`` at every phase; at scan phase (r, c) the image is displaced by
``−(r, c)·nnum/p`` sensor pixels, so view sample (Y, X) (lenslet ``Y // p``, phase ``Y % p``)
sees the scene at the lenslet-centre position ``nnum//2 + ½ + Y·nnum/p`` (sensor px, pixel edges
at integers). The scene is given on a fine grid of ``s`` samples per sensor pixel (``s`` odd, the
smallest with ``s·nnum`` a multiple of p: 3 for 13-px lenslets and a 3 × 3 scan), each holding
the radiance per sensor-pixel area; the views are the fine scene convolved with
``view_psfs(subsample=s)`` (each fine point carrying 1/s² of a pixel's flux) and sampled at those
positions, then photon + read noise and quantisation (:mod:`metasensor.simulation.noise`),
then ``unrealign`` to raw frames.

``truth`` is the scene on the reconstruction grid (``cfg.grid_pitch``, ``(Ly·p·d, Lx·p·d)``,
d = ``cfg.scan_step_px``): the area average of the fine scene over each grid pixel, grid pixel
i centred on ``nnum//2 + ½ + (i − d//2)·nnum/(p·d)`` sensor px, so that view sample Y sits on grid
pixel ``Y·d + d//2`` (docs/conventions.md). Hand-written (the geometry is this package's own).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from metasensor.backend import resolve_device
from metasensor.config import SystemConfig
from metasensor.sensor.realign import realign, unrealign
from metasensor.sensor.scan import check_scan_order
from metasensor.simulation import kernels as kern
from metasensor.simulation.noise import add_noise
from metasensor.simulation.render import Lattice, sampled_conv

__all__ = ["ImageScanCapture", "simulate_image_scan", "fine_factor", "grid_truth"]


@dataclass
class ImageScanCapture:
    """frames (T, H, W) uint16 in ``scan_order``; views / views_clean (nnum, nnum, Ly·p, Lx·p)
    float32 (noisy = ``realign(frames)``, noise-free); truth (Ly·p·d, Lx·p·d) float32 on the
    reconstruction grid, in the views' units (DN); config has ``moving="image"``."""

    frames: np.ndarray
    views: np.ndarray
    views_clean: np.ndarray
    truth: np.ndarray
    config: SystemConfig
    scan_order: list
    scale: float


def fine_factor(cfg: SystemConfig) -> int:
    """Fine samples per sensor pixel ``s`` of the scene: the smallest odd ``s >= 3`` with
    ``s·nnum`` a multiple of the scan period (ValueError when none exists: an even period)."""
    p = cfg.scan
    for s in range(3, 4 * p + 4, 2):
        if (s * cfg.nnum) % p == 0:
            return s
    raise ValueError(f"no odd fine sampling puts every scan position of a {p}x{p} scan of "
                     f"{cfg.nnum}-px lenslets on a sample (an even period)")


def _area_matrix(n_out: int, n_fine: int, cfg: SystemConfig, s: int) -> np.ndarray:
    """(n_out, n_fine) weights averaging the fine samples over each grid pixel (1-D)."""
    d, g = cfg.scan_step_px, cfg.nnum / cfg.grid_points
    centre = cfg.nnum // 2 + 0.5 + (np.arange(n_out) - d // 2) * g
    lo, hi = (centre - g / 2) * s, (centre + g / 2) * s  # in fine samples
    j = np.arange(n_fine)
    w = np.clip(np.minimum(hi[:, None], j + 1) - np.maximum(lo[:, None], j), 0, None)
    return w / (hi - lo)[:, None]


def grid_truth(scene: np.ndarray, cfg: SystemConfig, shape: tuple[int, int]) -> np.ndarray:
    """The fine scene averaged onto the reconstruction grid, ``shape`` (rows, cols)."""
    s = fine_factor(cfg)
    wy = _area_matrix(shape[0], scene.shape[0], cfg, s)
    wx = _area_matrix(shape[1], scene.shape[1], cfg, s)
    return (wy @ scene.astype(np.float64) @ wx.T).astype(np.float32)


def simulate_image_scan(scene, cfg: SystemConfig, scan_order=None, *, zernike=None,
                        snr_db: float | None = None, read_noise: float = 2.0,
                        exposure: float = 0.8, seed: int = 0, device=None
                        ) -> ImageScanCapture:
    """One scan period of raw frames of an image scanned over a fixed MLA (module docstring).

    Parameters
    ----------
    scene : (H, W) non-negative radiance on the fine grid (``fine_factor(cfg)`` samples per
        sensor pixel); the sensor has ``(H // s, W // s)`` pixels.
    cfg : the system (any ``moving``; the capture is an image scan).
    scan_order : zero-based (row, col) phases in acquisition order, a preset name or None.
    zernike : Noll vector [waves] of the whole field, or None.
    snr_db : target SNR of the views [dB] (None: noise-free but quantised).
    read_noise, exposure : read noise [e-] and the brightest clean sample's fraction of full
        scale.
    seed : the noise's seed.
    """
    if not isinstance(cfg, SystemConfig):
        raise TypeError(f"cfg must be a SystemConfig, got {type(cfg).__name__}")
    cfg = cfg.replace(moving="image")
    scene = np.asarray(scene, dtype=np.float32)
    if scene.ndim != 2 or not np.isfinite(scene).all() or scene.min() < 0:
        raise ValueError("scene must be a finite, non-negative (H, W) array")
    s = fine_factor(cfg)
    n, p = cfg.nnum, cfg.scan
    order = check_scan_order(scan_order, p)
    sensor = (scene.shape[0] // s, scene.shape[1] // s)
    ly, lx = sensor[0] // n, sensor[1] // n
    if ly < 1 or lx < 1:
        raise ValueError(f"scene {scene.shape} holds no {n}-px lenslet at {s} samples per px")
    dev = resolve_device(device)
    from metasensor.optics.psf import view_psfs

    bank = view_psfs(cfg, zernike=zernike, subsample=s, device=dev)
    kk = kern.as_kernels(kern.crop_energy(bank), dev)
    off, stride = s * (n // 2) + s // 2, s * n // p
    views = torch.zeros((n * n, ly * p, lx * p), dtype=torch.float32, device=dev)
    sampled_conv(torch.from_numpy(scene).to(dev), kk, Lattice(off, stride, ly * p),
                 Lattice(off, stride, lx * p), out=views)
    clean = views.reshape(n, n, ly * p, lx * p).cpu().numpy()
    peak = float(clean.max())
    scale = exposure * (2**cfg.bit_depth - 1) / peak if peak > 0 else 1.0
    clean *= np.float32(scale)
    noisy, _ = add_noise(clean, snr_db, None, read_noise, cfg.bit_depth, seed)
    frames = unrealign(noisy.astype(np.uint16), cfg, order, frame_shape=sensor)
    g = cfg.grid_points
    truth = grid_truth(scene, cfg, (ly * g, lx * g)) * np.float32(scale)
    return ImageScanCapture(frames=frames, views=realign(frames, cfg, order),
                            views_clean=clean, truth=truth, config=cfg, scan_order=order,
                            scale=float(scale))
