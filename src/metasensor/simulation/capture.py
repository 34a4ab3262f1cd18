"""``simulate``: raw meta-imaging captures with known truth, and the sensors they are compared with.

Geometry (docs/conventions.md). The scene is a 2D radiance array at ``cfg.pixel_pitch`` covering
the whole sensor (frames have the scene's shape, or ``sensor_shape``, scene placed at the top
left). At scan phase (r, c) lenslet (ly, lx) has its centre on sensor pixel
``(ly·nnum + r·d + nnum//2, lx·nnum + c·d + nnum//2)``, d = nnum // scan; so view sample (Y, X)
is the lenslet centre at sensor pixel ``(Y·d + nnum//2, X·d + nnum//2)``. ``truth`` pixel
(i, j) is sensor pixel (i + o, j + o), o = (nnum − d) // 2, shape (Ly·nnum, Lx·nnum);
``sensor2d`` and ``hardware_ao`` are on the same grid.

Forward model (inverse-crime free, :mod:`metasensor.simulation.kernels`): the scene is up-sampled
3× (cubic spline, flux preserving), blurred by ``view_psfs(subsample=3)`` (per field block and
depth layer, :mod:`~metasensor.simulation.layers`; per frame under turbulence), sampled at the
lenslet centres of each scan phase (each frame sees the scene at its own time under ``motion``),
then photon + read noise and quantisation (:mod:`~metasensor.simulation.noise`), then
``unrealign`` to raw frames. ``views = realign(frames)`` exactly.

Intensity scale: detector counts (DN). The scene is multiplied by ``scale`` (DN per scene unit;
default: the brightest clean view sample lands at ``exposure`` × full scale). ``truth`` is the
scaled scene, so that ``V = H ⊛ truth`` (H = ``view_psfs``, fractions of a point's photons): a
perfect reconstruction of ``views_clean`` equals ``truth``. ``sensor2d`` (widefield PSF, sums to
1) and ``hardware_ao`` share the scale, the gain and the noise model (same photon budget per
pixel).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from metasensor.backend import resolve_device
from metasensor.config import SystemConfig
from metasensor.optics.field import evaluate_field_zernike
from metasensor.sensor.realign import lenslet_counts, realign, unrealign
from metasensor.sensor.scan import check_scan_order
from metasensor.simulation import kernels as kern
from metasensor.simulation.comparison import SegmentedMirror, zernike_wavefront
from metasensor.simulation.layers import add_zernike, build_components, field_grid
from metasensor.simulation.motion import Motion
from metasensor.simulation.noise import NoiseModel, add_noise, apply_noise, measure_snr
from metasensor.simulation.render import Lattice, sampled_conv
from metasensor.simulation.turbulence import Turbulence, screen_phase

__all__ = ["Capture", "simulate", "plain_lightfield", "OPERATING_FOCUS_OFFSET"]

#: The documented operating point [waves r.m.s. of Noll Z4]: the meta-imaging sensor focused this
#: far off the scene's plane, where every view samples the field at its own phase (see
#: ``benchmarks/bench_quality.py`` and docs/decisions.md for the measurement).
OPERATING_FOCUS_OFFSET = 0.25


@dataclass
class Capture:
    """A simulated capture. Arrays are NumPy; intensities in DN (see the module docstring).

    Attributes
    ----------
    frames : numpy.ndarray, (T, H', W') uint16
        Raw frames in ``scan_order``.
    views, views_clean : numpy.ndarray, (nnum, nnum, Ly·p, Lx·p) float32
        The noisy views (``realign(frames)``) and the noise-free, unquantised ones.
    truth : numpy.ndarray, (Ly·nnum, Lx·nnum) float32
        The scaled scene on the reconstruction grid (DN).
    zernike : numpy.ndarray or None
        The true Noll vector (waves; None = aberration-free) or, for field-dependent
        aberrations, the total (global + field) vectors ``(by, bx, J)`` at the block centres.
    sensor2d, hardware_ao : numpy.ndarray or None, (Ly·nnum, Lx·nnum) float32
        The conventional 2D sensor and hardware adaptive optics, same photon budget per pixel
        (None with ``comparison=False``); ``sensor2d_clean``, ``hardware_ao_clean``: noise-free.
    config : SystemConfig
        ``cfg`` with ``scan`` set to the period used.
    scan_order : list of (int, int)
        The scan phases (row, col) in acquisition order.
    noise : NoiseModel
        The noise model applied (gain, read noise, bit depth).
    scale : float
        DN per scene unit.
    snr_db : float
        The measured SNR of the views, dB.
    offset : int
        Sensor pixel of truth pixel (0, 0): ``(nnum - d) // 2``.
    field_zernike : numpy.ndarray or None, (by, bx, J)
        The field part of the aberration alone at the block centres (None if uniform).
    depth_planes : numpy.ndarray or None
        The depth layers rendered (m, image side), None without ``depth``.
    phase_screens : numpy.ndarray or None
        Turbulence phase screens per frame (waves), None without turbulence.
    ao_residual_rms : float or None
        Residual wavefront of the hardware AO, waves r.m.s.
    options : dict
        The simulate() arguments that made this capture (not in ``repr``).
    """

    frames: np.ndarray
    views: np.ndarray
    views_clean: np.ndarray
    truth: np.ndarray
    zernike: np.ndarray | None
    sensor2d: np.ndarray | None
    hardware_ao: np.ndarray | None
    config: SystemConfig
    scan_order: list[tuple[int, int]]
    noise: NoiseModel
    scale: float
    snr_db: float
    offset: int
    field_zernike: np.ndarray | None = None
    depth_planes: np.ndarray | None = None
    phase_screens: np.ndarray | None = None
    sensor2d_clean: np.ndarray | None = None
    hardware_ao_clean: np.ndarray | None = None
    ao_residual_rms: float | None = None
    options: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def centre_view(self) -> np.ndarray:
        c = self.config.nnum // 2
        return self.views[c, c]

    def __repr__(self) -> str:  # the arrays by shape and dtype, not their values
        from metasensor.summary import short_repr

        return short_repr(self)


def _check_scene(scene) -> np.ndarray:
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


def _place(scene: np.ndarray, shape) -> np.ndarray:
    if shape is None or tuple(shape) == scene.shape:
        return scene
    h, w = (int(s) for s in shape)
    out = np.zeros((h, w), dtype=np.float32)
    hh, ww = min(h, scene.shape[0]), min(w, scene.shape[1])
    out[:hh, :ww] = scene[:hh, :ww]
    return out


class _Banks:
    """Collapsed, cropped kernels per (component, frame), computed once per call."""

    def __init__(self, cfg, device, upsample="spline", psf=None):
        self.cfg, self.device, self.upsample, self._cache = cfg, device, upsample, {}
        self.psf = kern.fine_view_bank if psf is None else psf

    def views(self, z, depth, phase=None, key=None):
        k = ("v", None if z is None else tuple(np.round(z, 12)), depth, key)
        if k not in self._cache:
            fine = self.psf(self.cfg, z, depth, phase=phase, device=self.device)
            coll = kern.collapse(fine, upsample=self.upsample)
            self._cache[k] = kern.as_kernels(kern.crop_energy(coll), self.device)
        return self._cache[k]

    def widefield(self, z, depth, phase=None, key=None):
        k = ("w", None if z is None else tuple(np.round(z, 12)), depth, key)
        if k not in self._cache:
            fine = kern.fine_widefield(self.cfg, z, depth, phase=phase, device=self.device)
            coll = kern.collapse(fine, integrate=True, upsample=self.upsample)
            self._cache[k] = kern.as_kernels(kern.crop_energy(coll), self.device)
        return self._cache[k]


def _accumulate(image: np.ndarray, comps, kernel_of, rows: Lattice, cols: Lattice,
                out: torch.Tensor, device) -> None:
    base = torch.from_numpy(np.ascontiguousarray(image)).to(device)
    for comp in comps:
        kk = kernel_of(comp)
        c = kk.shape[-1] // 2
        img = base if comp.weight is None else base * torch.from_numpy(comp.weight).to(device)
        y0, y1, x0, x1 = comp.box
        sampled_conv(img, kk, rows.restrict(y0 - c, y1 + c), cols.restrict(x0 - c, x1 + c),
                     out=out)


def _check_run_options(seed, snr_db, photons, psf) -> None:
    """One-line errors for :func:`simulate`'s seed, noise target and PSF provider."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    for name, value in (("snr_db", snr_db), ("photons", photons)):
        if value is not None and (isinstance(value, bool)
                                  or not isinstance(value, int | float | np.number)):
            raise TypeError(f"{name} must be a number or None, got {value!r}")
    if psf is not None and not callable(psf):
        raise TypeError("psf must be a callable psf(cfg, zernike, depth, phase=, device=) -> "
                        f"(nnum, nnum, Kf, Kf) fine-grid bank, got {type(psf).__name__}")


def simulate(scene, cfg: SystemConfig, zernike=None, field_zernike=None, depth=None, scan=None,
             scan_order=None, snr_db=None, motion: Motion | None = None,
             turbulence: Turbulence | None = None, seed: int = 0, *, photons=None,
             read_noise: float = 2.0, bit_depth: int | None = None, exposure: float = 0.8,
             scale: float | None = None, sensor_shape=None, field_blocks=(4, 4),
             depth_planes: int = 8, ao_segments: int = 15, comparison: bool = True,
             upsample: str = "spline", psf=None, device=None,
             progress: bool = False, focus_offset: float = 0.0) -> Capture:
    """Simulate one scan period of raw frames of ``scene`` (H, W) (see the module docstring).

    zernike: Noll vector [waves] for the whole field; field_zernike: (by, bx, J) vectors at block
    centres or a callable of normalised field coordinates (evaluated on ``field_blocks``), added
    to ``zernike``; depth: scalar or (H, W) map [m, image side] (layered, ``depth_planes``);
    scan/scan_order: period (None: cfg.scan) and order (None: row-major, or a preset name);
    snr_db: target SNR of the views [dB] or ``photons`` (photo-electrons at full scale) for
    Poisson + Gaussian read noise (``read_noise`` e-); neither: noise-free but quantised.
    motion / turbulence: dynamics (:class:`Motion`, :class:`Turbulence`); seed: all randomness.
    comparison: also render the 2D sensor and hardware AO (``ao_segments``² tip-tilt mirror).
    upsample: the continuous scene model behind the pixel array: ``"spline"`` (default, cubic
    interpolation), ``"box"`` (uniform pixels) or ``"point"`` (a point source per pixel).
    psf: optional provider ``psf(cfg, zernike, depth, phase=, device=) -> (nnum, nnum, Kf, Kf)``
    of fine view banks in photons per unit point (default: ``view_psfs(subsample=3) · 9``),
    e.g. measured PSFs.
    focus_offset: a deliberate defocus of the meta-imaging sensor [waves r.m.s., Noll Z4] (its
    MLA moved off the lens's image of the scene), added to the views' wavefront only: the
    comparison sensors stay in focus; ``cap.zernike`` includes it (pass it to ``reconstruct``).
    :data:`OPERATING_FOCUS_OFFSET` is the documented operating point (default 0: in focus).
    """
    if not (isinstance(focus_offset, int | float | np.floating) and math.isfinite(focus_offset)):
        raise ValueError(f"focus_offset must be a finite number of waves, got {focus_offset!r}")
    focus = np.array([0.0, 0.0, 0.0, float(focus_offset)]) if focus_offset else None
    if not isinstance(cfg, SystemConfig):
        raise TypeError(f"cfg must be a SystemConfig, got {type(cfg).__name__}")
    scene = _place(_check_scene(scene), sensor_shape)
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
    order = check_scan_order(scan_order, cfg.scan)
    n, p, d = cfg.nnum, cfg.scan, cfg.scan_step_px
    shape = scene.shape
    ly, lx = lenslet_counts(shape, cfg)
    if ly < 1 or lx < 1:
        raise ValueError(f"scene {shape} holds no lenslet over a {p}x{p} scan "
                         f"(needs at least {n + (p - 1) * d} px per side)")
    if scale is not None and not (isinstance(scale, int | float | np.floating)
                                  and math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number of DN per scene unit, got {scale!r}")
    if zernike is not None:
        if np.ndim(zernike) != 1:
            raise ValueError(f"zernike must be a 1-D Noll vector, got shape {np.shape(zernike)}")
        zernike = np.asarray(zernike, dtype=np.float64).ravel()
        if not np.isfinite(zernike).all():
            raise ValueError("zernike contains NaN or infinite values")
    if not (0 < exposure <= 1):
        raise ValueError(f"exposure must lie in (0, 1], got {exposure!r}")
    if motion is not None:
        if not isinstance(motion, Motion):
            raise TypeError("motion must be a metasensor.simulation.Motion")
        motion.check(shape)
    if turbulence is not None and not isinstance(turbulence, Turbulence):
        raise TypeError("turbulence must be a metasensor.simulation.Turbulence")
    _check_run_options(seed, snr_db, photons, psf)
    dev = resolve_device(device)
    seeds = np.random.SeedSequence(int(seed)).spawn(4)
    options = dict(zernike=zernike, field_zernike=field_zernike, depth=depth, motion=motion,
                   turbulence=turbulence, seed=seed, read_noise=read_noise, bit_depth=bits,
                   exposure=exposure, sensor_shape=sensor_shape, field_blocks=field_blocks,
                   depth_planes=depth_planes, ao_segments=ao_segments, upsample=upsample,
                   psf=psf, device=device, focus_offset=focus_offset)

    grid = None if field_zernike is None else field_grid(field_zernike, shape, field_blocks)
    comps, planes = build_components(shape, zernike, grid, depth, depth_planes)
    t_count = p * p
    screens = None if turbulence is None else turbulence.screens(t_count, seeds[3])
    tref = motion.reference_time(t_count) if motion is not None else (t_count - 1) / 2
    if upsample not in kern.UPSAMPLERS:
        raise ValueError(f"upsample must be one of {kern.UPSAMPLERS}, got {upsample!r}")
    banks = _Banks(cfg, dev, upsample, psf)
    reference = scene if motion is None else motion.reference_scene(scene)

    # progress at the steps a person waits on (the PSF banks show their own bar on a terminal)
    steps = tqdm(total=3 if comparison else 2, desc="simulate", unit="step",
                 disable=not progress)
    steps.set_postfix_str(f"views: {len(comps)} PSF bank(s)")

    # ---- clean views (scene units)
    views = torch.zeros((n * n, ly * p, lx * p), dtype=torch.float32, device=dev)
    if motion is None and turbulence is None:
        rows, cols = Lattice(n // 2, d, ly * p), Lattice(n // 2, d, lx * p)
        _accumulate(scene, tqdm(comps, desc="views", disable=not progress),
                    lambda cp: banks.views(add_zernike(cp.zernike, focus), cp.depth), rows, cols,
                    views, dev)
    else:
        for t, (r, c) in enumerate(tqdm(order, desc="frames", disable=not progress)):
            img = scene if motion is None else motion.scene_at(scene, t - tref)
            phase = None if screens is None else screen_phase(screens[t])
            key = None if screens is None else t
            sub = torch.zeros((n * n, ly, lx), dtype=torch.float32, device=dev)
            _accumulate(img, comps, lambda cp, ph=phase, k=key: banks.views(
                add_zernike(cp.zernike, focus), cp.depth, ph, k), Lattice(r * d + n // 2, n, ly),
                Lattice(c * d + n // 2, n, lx), sub, dev)
            views[:, r::p, c::p] = sub
    clean = views.reshape(n, n, ly * p, lx * p).cpu().numpy()
    del views
    peak = float(clean.max())
    if scale is None:
        scale = exposure * (2**bits - 1) / peak if peak > 0 else 1.0
    clean *= np.float32(scale)

    steps.update()
    steps.set_postfix_str("noise and raw frames")

    # ---- noise, quantisation, raw frames
    noisy, model = add_noise(clean, snr_db, photons, read_noise, bits, seeds[0])
    frames = unrealign(noisy.astype(np.uint16), cfg, order, moving="mla", frame_shape=shape)
    del noisy
    views_noisy = realign(frames, cfg, order, moving="mla")
    o = cfg.field_offset_px
    crop = (slice(o, o + ly * n), slice(o, o + lx * n))
    truth = (reference[crop] * np.float32(scale)).astype(np.float32)

    true_z = add_zernike(zernike, focus)
    if grid is not None:  # total (global + field) vectors at the block centres
        true_z = np.stack([np.stack([add_zernike(true_z, grid[i, j])
                                     for j in range(grid.shape[1])])
                           for i in range(grid.shape[0])])
    cap = Capture(frames=frames, views=views_noisy, views_clean=clean, truth=truth,
                  zernike=true_z, sensor2d=None, hardware_ao=None, config=cfg,
                  scan_order=order, noise=model, scale=float(scale),
                  snr_db=measure_snr(clean, views_noisy), offset=o, field_zernike=grid,
                  depth_planes=None if depth is None else planes, phase_screens=screens,
                  options=options)
    steps.update()
    if comparison:
        steps.set_postfix_str("2D sensor and hardware AO")
        _comparison_sensors(cap, reference, comps, grid, zernike, field_zernike, banks,
                            screens, tref, ao_segments, seeds, dev)
        steps.update()
    steps.close()
    return cap


def _comparison_sensors(cap: Capture, reference, comps, grid, zernike, field_zernike, banks,
                        screens, tref, ao_segments, seeds, dev) -> None:
    """Fill sensor2d and hardware_ao (clean and noisy) of ``cap`` in place (same scale/gain)."""
    cfg = cap.config
    ly, lx = cap.truth.shape
    rows, cols = Lattice(cap.offset, 1, ly), Lattice(cap.offset, 1, lx)
    screen = None if screens is None else screens[int(round(tref))]
    turb = None if screen is None else screen_phase(screen)

    def with_turb(w):
        if turb is None:
            return w
        if w is None:
            return turb
        return lambda x, y: np.asarray(w(x, y)) + turb(x, y)

    out = torch.zeros((1, ly, lx), dtype=torch.float32, device=dev)
    _accumulate(reference, comps, lambda cp: banks.widefield(cp.zernike, cp.depth, turb, "t"),
                rows, cols, out, dev)
    s2d = out[0].cpu().numpy() * np.float32(cap.scale)

    # hardware AO: the mirror fits the on-axis wavefront (+ turbulence); each block keeps W_k − D
    mirror = SegmentedMirror(ao_segments, cfg.obstruction)
    z_axis = zernike
    if field_zernike is not None:
        z_axis = add_zernike(zernike, evaluate_field_zernike(field_zernike if callable(
            field_zernike) else grid, np.zeros(1), np.zeros(1))[0])
    w_axis = with_turb(zernike_wavefront(z_axis))
    if w_axis is None:
        ao = s2d.copy()
        cap.ao_residual_rms = 0.0
    else:
        fitted = mirror.correction(w_axis)
        residuals = {}

        def ao_kernel(cp):
            w_k = with_turb(zernike_wavefront(cp.zernike)) or (lambda x, y: 0.0 * x)
            if cp.block not in residuals:
                residuals[cp.block] = lambda x, y, w=w_k: np.asarray(w(x, y)) - fitted(x, y)
            return banks.widefield(None, cp.depth, residuals[cp.block], ("ao", cp.block))

        out.zero_()
        _accumulate(reference, comps, ao_kernel, rows, cols, out, dev)
        ao = out[0].cpu().numpy() * np.float32(cap.scale)
        cap.ao_residual_rms = mirror.rms(lambda x, y: np.asarray(w_axis(x, y)) - fitted(x, y))
    cap.sensor2d_clean, cap.hardware_ao_clean = s2d, ao
    model = cap.noise
    cap.sensor2d = apply_noise(s2d, model, np.random.default_rng(seeds[1]))
    cap.hardware_ao = apply_noise(ao, model, np.random.default_rng(seeds[2]))


def replace(cap: Capture, **changes) -> Capture:
    """A shallow copy of ``cap`` with some fields changed."""
    return dataclasses.replace(cap, **changes)


def plain_lightfield(scene, cap, **kwargs):
    """A plain light-field camera (1 × 1 scan) with the optics, aberrations, dynamics, photon
    budget (gain, read noise, bit depth) and intensity scale of an existing capture ``cap``.

    Its views sample the field every ``nnum`` pixels; note that its ``truth`` grid starts at
    sensor pixel 0 (offset ``(nnum − nnum) // 2``), not at ``cap``'s offset.
    """
    opts = dict(cap.options)
    opts.update(scan=1, scan_order=None, scale=cap.scale, snr_db=None,
                photons=cap.noise.photons, comparison=False)
    opts.update(kwargs)
    return simulate(scene, cap.config.replace(scan=cap.config.scan), **opts)
