"""``reconstruct``: views -> all-in-focus, aberration-corrected image (ISA with multisite blocks).

Contract (issue 5)::

    rec = ms.reconstruct(views, cfg, method="isa", zernike=None, field_zernike=None,
                         blocks=(1, 1), overlap=20, iterations=None, device=None, **kw)
    rec.image    # (H, W) float32 on the cfg.pixel_pitch grid (same field as Capture.truth)
    rec.zernike  # (by, bx, J) Noll vectors [waves] used or estimated per block (J >= 45)
    rec.history  # [by][bx] -> residual ||y − A I|| / ||y|| per iteration

Views ``(nnum, nnum, Ly·scan, Lx·scan)`` (NumPy, or a zarr array read block by block) give an
image ``(Ly·nnum, Lx·nnum)``. The whole prototype sensor (4.7 GB of views in Zarr, 47.3 MP out,
8 x 8 blocks) ran at 2.0-2.2 GB peak memory in 297-299 s on 2 cores with Richardson–Lucy (5
iterations) and at 2.6 GB in 1,982 s with the default HQS (``benchmarks/bench_stream.py``).
Each block gets its own PSF bank from its local aberration
(``zernike`` everywhere plus ``field_zernike`` at the block), or a given bank (``psf=``);
``method="wave"``/``"geometric"`` first estimate the block's aberration with DAO
(:func:`metasensor.dao.estimate.estimate_block_aberration`), then run ISA with it.

ISA solver (``solver=``): ``"hqs"``, phase-space deconvolution with a sparse-gradient prior
(:mod:`metasensor.solvers.hqs`; scan steps up to 5 px: a 1 x 1 scan would factor 225 x 225 systems
per frequency), or ``"rl"``, the authors' ordered-subset Richardson–Lucy
(:mod:`metasensor.solvers.richardson_lucy`; ``iterations`` and ``subsets`` apply to it). The
default (None)
is HQS, unless ``iterations`` or ``subsets`` is given (Richardson–Lucy's parameters) or the scan
step exceeds 5 px. Measured on simulated 192-px captures, 5 x 5 scan, 30 dB: SSIM 0.907 (chart) /
0.779 (camera) for HQS against 0.516 / 0.671 for RL (the best linear reconstruction on
model-exact data: 0.56 / 0.66); a ~1.4 λ aberrated block 26.2 dB against 24.0 dB; multisite
4 x 4 blocks 24.36 dB against 24.11 dB. HQS costs 21x RL's 5 iterations at 300 px, 10-11x
at 600-1,000 px and 8.1x at 2,010 px (153 s on 2 cores, 6.8 GB; solvers.hqs).

With ``register=True`` every block's views are first registered against its bank
(:mod:`metasensor.dao.bank_registration`): sub-pixel view shifts, which a defocus or aberration
error of
the bank causes, are measured, fitted by a wavefront error's gradients and folded into the PSFs
where they lower the misfit. A 0.1 λ defocus error took HQS from SSIM 0.907 to 0.313 (chart,
192 px, 30 dB); registered 0.874. Off by default: on the true banks of strongly aberrated
multisite blocks it lowered the multisite gain from 3.44 to 2.70 dB.
``Reconstruction.registration`` holds the r.m.s. shift of each round per block, and
``registration_zernike`` the wavefront those shifts amount to (minus each bank's error).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from metasensor.config import SystemConfig
from metasensor.dao.bank_registration import WAVEFRONT_MODES
from metasensor.recon.blocks import Block, Stitcher, block_zernikes, split_blocks
from metasensor.solvers.richardson_lucy import (
    DEFAULT_ITERATIONS,
    default_subsets,
    subset_major,
    view_order,
)

__all__ = ["reconstruct", "Reconstruction", "BlockTask", "reconstruct_block"]

_METHODS = ("isa", "wave", "geometric")
_SOLVERS = ("rl", "hqs")
HQS_MAX_STEP = 5  # HQS up to this scan step (pixels)


@dataclass
class Reconstruction:
    """Result of :func:`reconstruct`.

    Attributes
    ----------
    image : numpy.ndarray or array-like, (H, W) float32
        The reconstructed image on the pixel grid, in the views' intensity units (or the
        Zarr/TIFF-backed array written to ``out``).
    zernike : numpy.ndarray, (by, bx, J) float32
        The aberration used for each block: Noll vectors in waves (DAO's estimate with
        ``method="wave"``/``"geometric"``; zeros with a given PSF bank).
    history : list
        ``[by][bx]`` -> the ISA solver's per-iteration residuals.
    blocks : list of Block
        The multisite blocks (regions and windows in output pixels).
    method : str
        ``"isa"``, ``"wave"`` or ``"geometric"`` (DAO before ISA).
    config : SystemConfig
        The system configuration used.
    iterations, subsets : int
        Richardson–Lucy iterations and view subsets per iteration (solver ``"rl"``).
    seconds : float
        Wall time of the reconstruction, s.
    solver : str
        The ISA solver used: ``"hqs"`` (sparse-gradient prior) or ``"rl"`` (Richardson–Lucy).
    dao_history : list
        ``[by][bx]`` -> DAO's history (wavefront updates, waves r.m.s.) with wave/geometric DAO.
    registration : list
        ``[by][bx]`` -> r.m.s. view shift (pixels) measured in each registration round.
    registration_zernike : numpy.ndarray or None, (by, bx, J)
        The wavefront (waves, Noll) the registered shifts amount to; None without registration.
    views_used : int
        Number of views deconvolved.
    """

    image: Any  # (H, W) float32 ndarray (or the zarr/TIFF-backed array written to ``out``)
    zernike: np.ndarray  # (by, bx, J) Noll vectors in waves (zeros with a given psf bank)
    history: list  # [by][bx] -> list of per-iteration residuals
    blocks: list[Block]
    method: str
    config: SystemConfig
    iterations: int
    subsets: int
    seconds: float
    solver: str = "hqs"  # the ISA solver used: "hqs" or "rl"
    dao_history: list = field(default_factory=list)  # [by][bx] -> DAO history (wave/geometric)
    # [by][bx] -> r.m.s. view shift (px) measured in each registration round (dao.bank_registration)
    registration: list = field(default_factory=list)
    # (by, bx, J) the wavefront (waves, Noll) the registered shifts amount to: minus the error of
    # each block's bank (Registration.zernike); None without registration
    registration_zernike: np.ndarray | None = None
    views_used: int = 0  # views deconvolved (cfg.view_mask(view_radius))

    def __repr__(self) -> str:  # the arrays by shape and dtype, not their values
        from metasensor.summary import short_repr

        return short_repr(self)


@dataclass
class BlockTask:
    """Everything one block needs (picklable, for dask.distributed workers)."""

    block: Block
    cfg: SystemConfig
    views: Any  # the full view stack (NumPy or zarr, sliced lazily in the worker) or the window
    uv: list[tuple[int, int]]
    zernike: np.ndarray
    psf: np.ndarray | None
    psf_fn: Any
    method: str
    iterations: int
    subsets: int
    device: str | None
    pad: bool = True
    dao_kwargs: dict = field(default_factory=dict)
    progress: Any = None  # callable(n) for local runs only
    windowed: bool = False  # ``views`` already holds just this block's window
    solver: str = "hqs"  # reconstruct() resolves it (module docstring)
    solver_kwargs: dict = field(default_factory=dict)
    register: bool = False  # register the views against the bank first (dao.bank_registration)


@dataclass
class BlockResult:
    block: Block
    image: np.ndarray
    zernike: np.ndarray
    history: list[float]
    dao_history: list[float]
    registration: list[float] = field(default_factory=list)
    registration_zernike: np.ndarray | None = None


def _default_psfs(cfg: SystemConfig, zernike, device, size: int | None = None):
    try:
        from metasensor.optics.psf import view_psfs
    except ImportError as exc:  # the optics stage not installed
        raise ImportError(f"metasensor.optics.psf.view_psfs is needed for PSFs ({exc}); "
                          "pass psf=<(nnum, nnum, K, K) bank> instead") from None
    z = None if zernike is None or not np.any(zernike) else np.asarray(zernike, np.float64)
    kw = {} if size is None else {"size": int(size)}
    return np.asarray(view_psfs(cfg, zernike=z, depth=0.0, device=device, **kw),
                      dtype=np.float32)


def _window(views, block: Block, d: int) -> np.ndarray:
    sy, sx = block.window_samples(d)
    return np.asarray(views[:, :, sy, sx], dtype=np.float32)


def _report_dao(index, zernike: np.ndarray, history: list[float], tol: float) -> None:
    """One line per block under the progress bar: the wavefront DAO estimated (waves r.m.s.
    over Noll 4-45) and how it converged."""
    import sys

    from tqdm import tqdm

    from metasensor.dao.wavefront import zernike_rms

    rms = zernike_rms(zernike)
    last = history[-1] if history else 0.0
    note = ("negligible: no further update" if len(history) == 1 and last < tol
            else "converged" if last < tol else "not converged")
    tqdm.write(f"block {tuple(int(i) for i in index)}: wavefront {rms:.3f} λ r.m.s. (Noll "
               f"4-45), {len(history)} DAO update(s), last {last:.3f} λ: {note}",
               file=sys.stderr)


def reconstruct_block(task: BlockTask) -> BlockResult:
    """ISA (after DAO for wave/geometric) of one block; returns the block's region image."""
    import torch

    from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
    from metasensor.solvers.richardson_lucy import richardson_lucy

    cfg = task.cfg
    d = cfg.scan_step_px
    window = (np.asarray(task.views, dtype=np.float32) if task.windowed
              else _window(task.views, task.block, d))
    if not np.isfinite(window).all():
        raise ValueError(f"views contain NaN or infinite values in block {task.block.index}")
    zernike = np.asarray(task.zernike, dtype=np.float32)
    dao_history: list[float] = []
    bank = task.psf
    if task.method in ("wave", "geometric"):
        import importlib

        dao = importlib.import_module("metasensor.dao.estimate")  # lazily: the DAO stage's module
        init = zernike if np.any(zernike) else None
        shown = task.progress is not None  # a local run with a bar: show DAO's updates too
        dao_kwargs = {"progress": shown, **task.dao_kwargs}
        geometric_bank = (task.method == "geometric" and bank is None and task.psf_fn is None
                          and hasattr(dao, "run_dao") and hasattr(dao, "block_psfs"))
        if geometric_bank:  # ideal PSFs translated by the measured shifts (never reshaped)
            res = dao.run_dao(window, cfg, method="geometric", init=init, device=task.device,
                              **dao_kwargs)
            z_est, dao_history = res.zernike, res.history
            bank = dao.block_psfs(cfg, res, device=task.device)
        else:
            z_est, dao_history = dao.estimate_block_aberration(
                window, cfg, method=task.method, init=init, device=task.device, **dao_kwargs)
        z_est = np.asarray(z_est, dtype=np.float32).ravel()
        zernike = np.zeros(max(zernike.size, z_est.size), np.float32)
        zernike[:z_est.size] = z_est
        dao_history = [float(h) for h in dao_history]
        if shown:
            _report_dao(task.block.index, zernike, dao_history, dao_kwargs.get("tol", 0.1))
    if bank is None and task.psf_fn is None and task.method == "wave":
        # the window of the views used, from the estimate's ray reach (dao.estimate.psf_window;
        # 2-3x smaller than view_psfs' all-views default, >= 99.4 % of the used views' light)
        from metasensor.dao.estimate import psf_window

        bank = _default_psfs(cfg, zernike, task.device, size=psf_window(cfg, zernike))
    if bank is None:
        bank = (task.psf_fn or _default_psfs)(cfg, zernike, task.device)
    bank = np.asarray(bank, dtype=np.float32)
    if bank.ndim != 4 or bank.shape[:2] != (cfg.nnum, cfg.nnum):
        raise ValueError(f"psf bank must have shape (nnum, nnum, K, K) with nnum = {cfg.nnum}, "
                         f"got {bank.shape}")
    rows = [u for u, _ in task.uv]
    cols = [v for _, v in task.uv]
    psf = bank[rows, cols]
    data_win = window[rows, cols]
    registration: list[float] = []
    reg_zernike = None
    op = None
    if task.register:
        from metasensor.dao.bank_registration import register_views

        reg = register_views(psf, data_win, d, device=task.device, pad=task.pad, cfg=task.cfg,
                             uv=task.uv)
        psf, registration, op = reg.psf.cpu().numpy(), reg.history, reg.operator
        reg_zernike = reg.zernike
    if op is None:
        geometry = make_geometry(data_win.shape[-2:], d, psf.shape[-1] // 2, pad=task.pad)
        op = PhaseSpaceOperator(psf, geometry, device=task.device)
    geometry = op.geometry
    data, mask = geometry.embed(torch.from_numpy(data_win).to(op.device))
    if task.solver == "hqs":
        from metasensor.solvers.hqs import hyper_laplacian_isa

        result = hyper_laplacian_isa(op, psf, data, mask, progress=task.progress,
                                     **task.solver_kwargs)
    else:
        result = richardson_lucy(op, data, mask, iterations=task.iterations,
                                 subsets=task.subsets, progress=task.progress)
    window_img = geometry.crop(result.estimate).detach().cpu().numpy()
    ry, rx = task.block.region_in_window()
    return BlockResult(task.block, np.ascontiguousarray(window_img[ry, rx], dtype=np.float32),
                       zernike, result.history, dao_history, registration, reg_zernike)


def _check_views(views, cfg: SystemConfig):
    if not hasattr(views, "shape") or not hasattr(views, "__getitem__"):
        views = np.asarray(views)
    shape = tuple(views.shape)
    if len(shape) != 4 or shape[0] != shape[1]:
        raise ValueError(f"views must have shape (nnum, nnum, H, W), got {shape}")
    if shape[0] != cfg.nnum:
        raise ValueError(f"views have {shape[0]}x{shape[1]} views but cfg.nnum is {cfg.nnum}")
    dtype = np.dtype(views.dtype)
    if dtype.kind not in "uif":
        raise TypeError(f"views must be an integer or float array, got dtype {dtype}")
    if isinstance(views, np.ndarray) and dtype.kind == "f" and not np.isfinite(views).all():
        raise ValueError("views contain NaN or infinite values")
    if isinstance(views, np.ndarray) and views.size and not views.max() > 0:
        raise ValueError("views hold no light (no sample above 0): nothing to reconstruct")
    return views


def reconstruct(views, cfg: SystemConfig, method: str = "isa", zernike=None, field_zernike=None,
                blocks=(1, 1), overlap: int = 20, iterations: int | None = None, device=None,
                *, psf=None, psf_fn=None, subsets: int | None = None,
                view_radius: float | None = None,
                order: str = "spiral", margin: int | None = None, pad: bool = True,
                scheduler=None, num_workers: int | None = None, out=None, progress: bool = False,
                dao_kwargs: dict | None = None, solver: str | None = None,
                solver_kwargs: dict | None = None, register: bool = False
                ) -> Reconstruction:
    """Reconstruct the image from views (see the module docstring for the contract).

    psf : a given (nnum, nnum, K, K) bank for every block (skips PSF generation), or None.
    psf_fn : callable(cfg, zernike (J,), device) -> bank, replacing ``optics.psf.view_psfs``.
    subsets : view subsets per Richardson–Lucy iteration (1 = simultaneous, n_views = sequential;
        default 16, or 1 for scan steps above 5 px:
        :func:`metasensor.solvers.richardson_lucy.default_subsets`).
    solver : "hqs", "rl" or None (module docstring: HQS unless ``iterations``/``subsets`` is
        given or the scan step exceeds 5 px); solver_kwargs : passed to
        :func:`metasensor.solvers.hqs.hyper_laplacian_isa` (e.g. ``lam_scale``, ``noise``).
    register : register every view against the PSF bank before the solve
        (:mod:`metasensor.dao.bank_registration`: sub-pixel view shifts folded into the bank, kept
        only
        where they lower the misfit); for banks that may be off (a defocus or aberration error):
        HQS's detail depends on the exact PSFs. Default False.
    view_radius : pupil radius (views) of the views used (``cfg.view_mask``; default: the
        authors' 113 views, radius 6 for nnum 15). The pupil's own radius (7.5: 177 views) adds
        the edge views, which fill the lenslet aperture's OTF nulls most
        (``tests/optics/test_psf.py``). Measured, 30 dB, HQS: aberration-free chart 192 px SSIM
        0.907 -> 0.922, camera 0.779 -> 0.792, astronaut 256 px 0.813 -> 0.837 (RL +0.008 to
        +0.013), at 1.3-1.4x the time; but the 4 x 4 multisite capture (up to 1.8 λ) 24.36 ->
        24.24 dB, and the edge views are the ones a pupil-calibration or vignetting error hits
        first, so the default stays the authors'.
    order : "spiral" (outside in, the authors'), "radius" (inside out) or "raster".
    margin : pixels of extra view data around each block (default: the radius of a given ``psf``
        bank, else ``cfg.nnum``).
    pad : pad the estimate by the PSF radius (linear convolution; False = circular, for study).
    scheduler : None/"threads", "sync", an address "tcp://host:port", or a dask Client/cluster.
    out : None (NumPy image) or a writable (H, W) float32 array (e.g. zarr) to stitch into.
    """
    t0 = time.perf_counter()
    if not isinstance(cfg, SystemConfig):
        raise TypeError(f"cfg must be a SystemConfig, got {type(cfg).__name__}")
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    if psf is not None and method != "isa":
        raise ValueError(f"method={method!r} builds each block's bank from its DAO estimate; a "
                         "given psf would be used unchanged: pass psf_fn, or method='isa'")
    if psf is not None and (field_zernike is not None or (
            zernike is not None and np.any(np.asarray(zernike, dtype=float)))):
        raise ValueError("psf is a complete PSF bank, so zernike/field_zernike would be ignored: "
                         "give the aberration or the bank, not both")
    views = _check_views(views, cfg)
    if view_radius is not None and (isinstance(view_radius, bool) or not (
            isinstance(view_radius, int | float | np.number) and math.isfinite(view_radius)
            and view_radius >= 0)):
        raise ValueError(f"view_radius must be a finite number of views >= 0, got {view_radius!r}")
    try:
        by, bx = (int(blocks[0]), int(blocks[1]))
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"blocks must be a pair (by, bx), got {blocks!r}") from None
    d = cfg.scan_step_px
    if solver is None:
        rl_asked = iterations is not None or subsets is not None
        solver = "rl" if rl_asked or d > HQS_MAX_STEP else "hqs"
    for name, value, low in (("iterations", iterations, 0), ("subsets", subsets, 1),
                             ("num_workers", num_workers, 1)):
        if value is not None and (isinstance(value, bool) or not isinstance(value, int | np.integer)
                                  or value < low):
            raise ValueError(f"{name} must be an integer >= {low} (or None), got {value!r}")
    iterations = DEFAULT_ITERATIONS if iterations is None else int(iterations)
    if solver not in _SOLVERS:
        raise ValueError(f"solver must be one of {_SOLVERS}, got {solver!r}")
    if solver == "hqs" and d > HQS_MAX_STEP:
        raise ValueError(f"solver='hqs' needs a scan step of at most {HQS_MAX_STEP} px "
                         f"(scan >= 3 for nnum 15), got {d} px; use solver='rl'")
    if min(views.shape[2:]) < 4:
        raise ValueError(f"views of {tuple(views.shape[2:])} samples are too small to "
                         "reconstruct (at least 4 x 4)")
    shape = (views.shape[2] * d, views.shape[3] * d)
    if psf is not None:
        psf = np.asarray(psf, dtype=np.float32)
        if psf.ndim != 4 or psf.shape[:2] != (cfg.nnum, cfg.nnum) or psf.shape[2] % 2 == 0:
            raise ValueError(f"psf must have shape (nnum, nnum, K, K), K odd, nnum = {cfg.nnum}; "
                             f"got {psf.shape}")
        if not np.isfinite(psf).all():
            raise ValueError("psf contains NaN or infinite values")
        if float(psf.min()) < -1e-3 * max(float(psf.max()), 0.0):
            raise ValueError(f"psf must be non-negative (intensities), min {float(psf.min()):.3g}")
        psf = np.maximum(psf, 0.0)  # a copy: background-subtracted banks keep tiny negatives
        dark = ~(psf.sum(axis=(2, 3)) > 0) & cfg.view_mask(view_radius)
        if dark.any():
            u, v = np.argwhere(dark)[0]
            raise ValueError(f"psf carries no light in {int(dark.sum())} used view(s), e.g. "
                             f"({u}, {v}): an all-zero PSF cannot be deconvolved")
    if margin is None:
        margin = psf.shape[-1] // 2 if psf is not None else cfg.nnum
    block_list = split_blocks(shape, (by, bx), d, overlap=overlap, margin=margin)
    zern = block_zernikes(block_list, shape, (by, bx), zernike, field_zernike)
    uv = view_order(cfg.view_mask(view_radius), order)
    n_subsets = min(default_subsets(d), len(uv)) if subsets is None else int(subsets)
    if n_subsets > len(uv):
        raise ValueError(f"subsets must be at most the {len(uv)} views used, got {n_subsets}")
    uv = subset_major(uv, n_subsets)
    from metasensor.backend import resolve_device

    dev = str(resolve_device(device))
    bar = None
    if progress:
        from tqdm import tqdm

        steps = iterations
        if solver == "hqs":
            from metasensor.solvers.hqs import continuation_steps

            steps = continuation_steps(**(solver_kwargs or {}))
        bar = tqdm(total=len(block_list) * steps, desc="reconstruct", unit="it")
    local = scheduler is None or scheduler in ("threads", "sync")
    tick = bar.update if (bar is not None and local) else None
    # a remote cluster gets each block's window of an in-memory stack, not the whole stack
    ship = not local and isinstance(views, np.ndarray)
    tasks = [BlockTask(b, cfg, _window(views, b, d) if ship else views, uv, zern[b.index], psf,
                       psf_fn, method, iterations, n_subsets, dev, pad, dict(dao_kwargs or {}),
                       tick, ship, solver, dict(solver_kwargs or {}), bool(register))
             for b in block_list]
    stitcher = Stitcher(shape, out)
    history = [[[] for _ in range(bx)] for _ in range(by)]
    dao_hist = [[[] for _ in range(bx)] for _ in range(by)]
    reg_hist = [[[] for _ in range(bx)] for _ in range(by)]
    reg_zern = np.zeros((by, bx, max(WAVEFRONT_MODES)), np.float32) if register else None
    zern_used = zern.copy()

    def collect(res: BlockResult) -> None:
        stitcher.add(res.block, res.image)
        iy, ix = res.block.index
        history[iy][ix] = res.history
        dao_hist[iy][ix] = res.dao_history
        reg_hist[iy][ix] = res.registration
        if reg_zern is not None and res.registration_zernike is not None:
            reg_zern[iy, ix] = res.registration_zernike
        z = np.asarray(res.zernike, np.float32)
        zern_used[iy, ix, :] = 0
        zern_used[iy, ix, :min(z.size, zern_used.shape[-1])] = z[:zern_used.shape[-1]]
        if bar is not None and not local:
            bar.update(len(res.history))

    from metasensor.recon.parallel import run_tasks

    try:
        run_tasks(reconstruct_block, tasks, collect, scheduler=scheduler,
                  num_workers=num_workers)
    finally:
        if bar is not None:
            bar.close()
    return Reconstruction(stitcher.out, zern_used, history, block_list, method, cfg, iterations,
                          n_subsets, time.perf_counter() - t0, solver, dao_hist, reg_hist,
                          reg_zern, len(uv))
