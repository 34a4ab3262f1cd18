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
depth layer, :mod:`~metasensor.simulation.layers`; per frame under turbulence, or per key
frame interpolated in time and at the turbulence's own ``subsample``: ``Turbulence.key_every``,
``Turbulence.subsample``), sampled at the
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
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from metasensor.backend import resolve_device
from metasensor.config import SystemConfig
from metasensor.sensor.realign import realign, unrealign
from metasensor.simulation.comparison import comparison_sensors
from metasensor.simulation.inputs import SimInputs, check_inputs
from metasensor.simulation.layers import add_zernike, build_components, field_grid
from metasensor.simulation.motion import Motion
from metasensor.simulation.noise import NoiseModel, add_noise, measure_snr
from metasensor.simulation.sampling import KernelBanks, RenderPlan, clean_views
from metasensor.simulation.turbulence import Turbulence

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
        (None with ``comparison=False``; ``hardware_ao`` None with ``comparison="2d"``);
        ``sensor2d_clean``, ``hardware_ao_clean``: noise-free.
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


def _plan(inp: SimInputs, field_zernike, depth, settings: dict, dev, seeds) -> RenderPlan:
    """The field blocks and depth layers, the dynamics and the kernel banks of one call."""
    shape = inp.scene.shape
    grid = (None if field_zernike is None
            else field_grid(field_zernike, shape, settings["field_blocks"]))
    comps, planes = build_components(shape, inp.zernike, grid, depth, settings["depth_planes"])
    t_count = inp.cfg.scan ** 2
    motion, turbulence = settings["motion"], settings["turbulence"]
    screens = None if turbulence is None else turbulence.screens(t_count, seeds[3])
    tref = motion.reference_time(t_count) if motion is not None else (t_count - 1) / 2
    banks = KernelBanks(inp.cfg, dev, settings["upsample"], settings["psf"])
    sampling = ({} if turbulence is None else
                {"key_every": turbulence.key_every, "subsample": turbulence.subsample})
    return RenderPlan(comps, grid, planes, banks, motion, screens, tref, **sampling)


def _raw(inp: SimInputs, clean: np.ndarray, noise: dict, seed) -> tuple:
    """Noise, quantisation and the raw frames of the scaled clean views: (frames, noisy views,
    noise model)."""
    noisy, model = add_noise(clean, noise["snr_db"], noise["photons"], noise["read_noise"],
                             inp.cfg.bit_depth, seed)
    frames = unrealign(noisy.astype(np.uint16), inp.cfg, inp.order, moving="mla",
                       frame_shape=inp.scene.shape)
    del noisy
    return frames, realign(frames, inp.cfg, inp.order, moving="mla"), model


def _true_zernike(inp: SimInputs, grid) -> np.ndarray | None:
    """The true Noll vector of the views (global + focus offset), or the total vectors at the
    field blocks' centres ``(by, bx, J)``."""
    true_z = add_zernike(inp.zernike, inp.focus)
    if grid is None:
        return true_z
    return np.stack([np.stack([add_zernike(true_z, grid[i, j]) for j in range(grid.shape[1])])
                     for i in range(grid.shape[0])])


def simulate(scene, cfg: SystemConfig, zernike=None, field_zernike=None, depth=None, scan=None,
             scan_order=None, snr_db=None, motion: Motion | None = None,
             turbulence: Turbulence | None = None, seed: int = 0, *, photons=None,
             read_noise: float = 2.0, bit_depth: int | None = None, exposure: float = 0.8,
             scale: float | None = None, sensor_shape=None, field_blocks=(4, 4),
             depth_planes: int = 8, ao_segments: int = 15, comparison: bool | str = True,
             upsample: str = "spline", psf=None, device=None,
             progress: bool = False, focus_offset: float = 0.0) -> Capture:
    """Simulate one scan period of raw frames of ``scene`` (H, W) (see the module docstring).

    cfg: a moving-MLA system (``cfg.moving == "mla"``; an image scanned over a fixed MLA is
    refused: :func:`metasensor.simulation.image_scan.simulate_image_scan` simulates those).

    zernike: Noll vector [waves] for the whole field; field_zernike: (by, bx, J) vectors at block
    centres or a callable of normalised field coordinates (evaluated on ``field_blocks``), added
    to ``zernike``; depth: scalar or (H, W) map [m, image side] (layered, ``depth_planes``);
    scan/scan_order: period (None: cfg.scan) and order (None: row-major, or a preset name);
    snr_db: target SNR of the views [dB] or ``photons`` (photo-electrons at full scale) for
    Poisson + Gaussian read noise (``read_noise`` e-); neither: noise-free but quantised.
    motion / turbulence: dynamics (:class:`Motion`, :class:`Turbulence`); seed: all randomness.
    comparison: also render the 2D sensor and hardware AO (``ao_segments``² tip-tilt mirror);
    ``"2d"``: the 2D sensor only (``hardware_ao`` None; the 2D sensor's pixels unchanged).
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
    settings = dict(snr_db=snr_db, motion=motion, turbulence=turbulence, seed=seed,
                    photons=photons, read_noise=read_noise, bit_depth=bit_depth,
                    exposure=exposure, scale=scale, sensor_shape=sensor_shape,
                    field_blocks=field_blocks, depth_planes=depth_planes, upsample=upsample,
                    psf=psf, focus_offset=focus_offset)
    if not (isinstance(comparison, bool) or isinstance(comparison, str) and comparison == "2d"):
        raise ValueError(f"comparison must be True, False or '2d', got {comparison!r}")
    inp = check_inputs(scene, cfg, zernike, scan, scan_order, settings)
    dev = resolve_device(device)
    seeds = np.random.SeedSequence(int(seed)).spawn(4)
    plan = _plan(inp, field_zernike, depth, settings, dev, seeds)
    # progress at the steps a person waits on (the PSF banks show their own bar on a terminal)
    with tqdm(total=3 if comparison else 2, desc="simulate", unit="step",
              disable=not progress) as steps:  # closed on any error too
        steps.set_postfix_str(f"views: {len(plan.comps)} PSF bank(s)")
        clean = clean_views(inp.scene, inp, plan, progress)
        reference = inp.scene if motion is None else motion.reference_scene(inp.scene)
        if scale is None:
            peak = float(clean.max())
            scale = exposure * (2**inp.cfg.bit_depth - 1) / peak if peak > 0 else 1.0
        clean *= np.float32(scale)
        steps.update()
        steps.set_postfix_str("noise and raw frames")
        frames, views, model = _raw(inp, clean, settings, seeds[0])
        o = inp.cfg.field_offset_px
        (ly, lx), n = inp.lenslets, inp.cfg.nnum
        truth = (reference[o:o + ly * n, o:o + lx * n] * np.float32(scale)).astype(np.float32)
        options = {**settings, "zernike": inp.zernike, "field_zernike": field_zernike,
                   "depth": depth, "bit_depth": inp.cfg.bit_depth, "ao_segments": ao_segments,
                   "device": device}
        for name in ("snr_db", "photons", "scale"):  # given per call, not kept with the capture
            options.pop(name)
        cap = Capture(frames=frames, views=views, views_clean=clean, truth=truth,
                      zernike=_true_zernike(inp, plan.grid), sensor2d=None, hardware_ao=None,
                      config=inp.cfg, scan_order=inp.order, noise=model, scale=float(scale),
                      snr_db=measure_snr(clean, views), offset=o, field_zernike=plan.grid,
                      depth_planes=None if depth is None else plan.planes,
                      phase_screens=plan.screens, options=options)
        steps.update()
        if comparison:
            steps.set_postfix_str("2D sensor" if comparison == "2d"
                                  else "2D sensor and hardware AO")
            comparison_sensors(cap, reference, plan, inp.zernike, field_zernike,
                               ao_segments if comparison is True else 0, seeds)
            steps.update()
        return cap


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
