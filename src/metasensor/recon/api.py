"""``reconstruct``: views -> all-in-focus, aberration-corrected image (ISA with multisite blocks).

Contract (docs/conventions.md, README)::

    rec = ms.reconstruct(views, cfg, method="isa", zernike=None, field_zernike=None,
                         blocks=(1, 1), options=None, **settings)
    rec.image    # (H, W) float32 on the cfg.pixel_pitch grid (same field as Capture.truth)
    rec.zernike  # (by, bx, J) Noll vectors [waves] used or estimated per block (J >= 45)
    rec.history  # [by][bx] -> the solver's relative residual per iteration (or per β)

Views ``(nnum, nnum, Ly·scan, Lx·scan)`` (NumPy, or a zarr array read block by block) give an
image ``(Ly·nnum, Lx·nnum)``. The field is split into blocks (:mod:`metasensor.recon.blocks`);
each block (:func:`metasensor.recon.block.reconstruct_block`) gets its own PSF bank from its
local aberration (``zernike`` everywhere plus ``field_zernike`` at the block), a given bank
(``psf``), or, with ``method="wave"``/``"geometric"``, the bank of its DAO estimate
(:mod:`metasensor.dao.estimate`); optionally registers its views against the bank; and is solved
on the phase-space operator by Richardson–Lucy or half-quadratic splitting with a prior
(:mod:`metasensor.solvers`). Blocks run through Dask (:mod:`metasensor.recon.parallel`) and are
stitched with raised-cosine weights. Every other setting is a field of
:class:`metasensor.recon.options.ReconOptions`, given as ``options`` or as keywords.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from metasensor.config import SystemConfig
from metasensor.recon.block import BlockTask, reconstruct_block
from metasensor.recon.blocks import Block, block_zernikes, split_blocks
from metasensor.recon.collect import Collector
from metasensor.recon.dao_choice import DAO_CHOICES, block_dao_options, choose_dao
from metasensor.recon.noise import capture_noise, noise_model
from metasensor.recon.options import ReconOptions

__all__ = ["reconstruct", "Reconstruction", "ReconOptions"]

_METHODS = DAO_CHOICES


@dataclass
class Reconstruction:
    """Result of :func:`reconstruct`.

    Attributes
    ----------
    image : array
        ``(H, W)`` float32 (or the zarr array stitched into).
    zernike : numpy.ndarray
        ``(by, bx, J)`` Noll vectors in waves used or estimated per block.
    history : list
        ``[by][bx]`` -> the solver's residuals.
    blocks : list of Block
    method, config, iterations, subsets, seconds, solver
        What ran (``iterations``/``subsets``: Richardson–Lucy's), wall time in seconds.
    dao_history : list
        ``[by][bx]`` -> DAO's update r.m.s. (waves).
    registration : list
        ``[by][bx]`` -> r.m.s. view shift (pixels) of each registration round.
    registration_zernike : numpy.ndarray or None
        ``(by, bx, 21)`` the wavefront (waves, Noll) the registered shifts amount to.
    views_used : int
    dao_applied : list
        ``[by][bx]`` -> whether the block's DAO estimate was applied (False: negligible, the
        block kept its starting bank; None: no DAO).
    dao_zernike : numpy.ndarray or None
        ``(by, bx, J)`` DAO's estimate per block, applied or not (waves; None: no DAO).
    noise_model : PoissonGaussian or None
        The views' noise model the solver used (:mod:`metasensor.solvers.noise_model`; None:
        one global weight).
    dao_fit_px : numpy.ndarray or None
        ``(by, bx)`` r.m.s. residual (pixels) of DAO's last shift fit per block (NaN: no DAO
        there; None: no DAO): :mod:`metasensor.recon.dao_fit`.
    depth_layers : list
        ``[by][bx]`` -> the disparities (view pixels per view step, relative to the block's
        wavefront) of the depth layers the block was solved with (``depth_layers`` option;
        empty: one bank).
    """

    image: Any
    zernike: np.ndarray
    history: list
    blocks: list[Block]
    method: str
    config: SystemConfig
    iterations: int
    subsets: int
    seconds: float
    solver: str = "hqs"
    dao_history: list = field(default_factory=list)
    registration: list = field(default_factory=list)
    registration_zernike: np.ndarray | None = None
    views_used: int = 0
    dao_applied: list = field(default_factory=list)
    dao_zernike: np.ndarray | None = None
    noise_model: Any = None
    dao_fit_px: np.ndarray | None = None
    depth_layers: list = field(default_factory=list)

    def __repr__(self) -> str:  # the arrays by shape and dtype, not their values
        from metasensor.summary import short_repr

        return short_repr(self)


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
    if min(shape[2:]) < 4:
        raise ValueError(f"views of {shape[2:]} samples are too small to reconstruct "
                         "(at least 4 x 4)")
    return views


def _check_psf(psf, cfg: SystemConfig, opts: ReconOptions) -> np.ndarray | None:
    """A given bank as a non-negative float32 copy, checked against the views used."""
    if psf is None:
        return None
    psf = np.asarray(psf, dtype=np.float32)
    if psf.ndim != 4 or psf.shape[:2] != (cfg.nnum, cfg.nnum) or psf.shape[2] % 2 == 0:
        raise ValueError(f"psf must have shape (nnum, nnum, K, K), K odd, nnum = {cfg.nnum}; "
                         f"got {psf.shape}")
    if not np.isfinite(psf).all():
        raise ValueError("psf contains NaN or infinite values")
    if float(psf.min()) < -1e-3 * max(float(psf.max()), 0.0):
        raise ValueError(f"psf must be non-negative (intensities), min {float(psf.min()):.3g}")
    psf = np.maximum(psf, 0.0)  # a copy: background-subtracted banks keep tiny negatives
    dark = ~(psf.sum(axis=(2, 3)) > 0) & cfg.view_mask(opts.view_radius)
    if dark.any():
        u, v = np.argwhere(dark)[0]
        raise ValueError(f"psf carries no light in {int(dark.sum())} used view(s), e.g. "
                         f"({u}, {v}): an all-zero PSF cannot be deconvolved")
    return psf


def _check_call(cfg, method: str, zernike, field_zernike, opts: ReconOptions) -> None:
    if not isinstance(cfg, SystemConfig):
        raise TypeError(f"cfg must be a SystemConfig, got {type(cfg).__name__}")
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    if opts.psf is not None and method in ("wave", "geometric"):
        raise ValueError(f"method={method!r} builds each block's bank from its DAO estimate; a "
                         "given psf would be used unchanged: pass psf_fn, or method='isa'")
    if opts.space_variant and (method in ("wave", "geometric") or opts.psf is not None):
        raise ValueError("space_variant builds banks at the blocks' corners from the aberration: "
                         "use it with method='isa' and no psf")
    if opts.depth_layers != "off" and (opts.psf is not None or opts.space_variant
                                       or opts.register or method == "geometric"):
        raise ValueError("depth_layers builds each layer's bank from the block's Noll vector: "
                         "not with psf, space_variant, register or method='geometric'")
    if opts.psf is not None and (field_zernike is not None or (
            zernike is not None and np.any(np.asarray(zernike, dtype=float)))):
        raise ValueError("psf is a complete PSF bank, so zernike/field_zernike would be ignored: "
                         "give the aberration or the bank, not both")


def _dao_unavailable(method: str, cfg: SystemConfig, opts: ReconOptions) -> str | None:
    """For ``"auto"``: why DAO cannot run with ``cfg``'s views (None: it can)."""
    if method != "auto":
        return None
    from metasensor.dao.estimate import dao_unavailable

    return dao_unavailable(cfg, cfg.view_mask(opts.view_radius))


def _resolve_method(method: str, cfg: SystemConfig, zernike, field_zernike, opts: ReconOptions
                    ) -> tuple[str, ReconOptions]:
    """``"auto"``/``"none"`` resolved (:func:`metasensor.recon.dao_choice.choose_dao`) to the
    method run, and ``dao_negligible`` set from the choice unless given."""
    given = field_zernike is not None or (
        zernike is not None and bool(np.any(np.asarray(zernike, dtype=float))))
    choice = choose_dao(method, aberration_given=given, bank_given=opts.psf is not None,
                        unavailable=_dao_unavailable(method, cfg, opts))
    if method == "auto" and choice.method == "isa" and not given and opts.psf is None:
        import warnings

        warnings.warn(f"reconstruct: the aberration is {choice.reason}", UserWarning,
                      stacklevel=3)
    if opts.dao_negligible is None:
        opts = ReconOptions.resolve(opts, {"dao_negligible": choice.negligible})
    return choice.method, opts


def _block_grid(blocks) -> tuple[int, int]:
    try:
        return int(blocks[0]), int(blocks[1])
    except (TypeError, ValueError, IndexError):
        raise ValueError(f"blocks must be a pair (by, bx), got {blocks!r}") from None


def _solver_options(opts: ReconOptions, solver: str, n_views: int, step: int, noise=None,
                    views=None):
    """The resolved solver settings (RLOptions or HQSOptions) and RL's subsets; ``noise`` the
    Poisson–Gaussian model (None: one global weight); ``views`` the capture (HQS's noise,
    measured here once: :func:`metasensor.recon.noise.capture_noise`)."""
    from dataclasses import replace

    from metasensor.solvers.hqs import HQSOptions
    from metasensor.solvers.richardson_lucy import DEFAULT_ITERATIONS, RLOptions, default_subsets

    subsets = min(default_subsets(step), n_views) if opts.subsets is None else int(opts.subsets)
    if subsets > n_views:
        raise ValueError(f"subsets must be at most the {n_views} views used, got {subsets}")
    if solver == "hqs":
        hqs_opts = opts.solver_options or HQSOptions()
        if noise is not None and hqs_opts.noise_model is None:
            hqs_opts = replace(hqs_opts, noise_model=noise)
        return capture_noise(hqs_opts, views), subsets
    iterations = DEFAULT_ITERATIONS if opts.iterations is None else int(opts.iterations)
    shifted = noise if noise is not None and noise.a > 0 else None
    return RLOptions(iterations=iterations, subsets=subsets, noise_model=shifted), subsets


def _resolve_workers(opts: ReconOptions, blocks, view_shape, d: int) -> ReconOptions:
    """``num_workers="auto"`` as a count: :func:`metasensor.recon.parallel.local_workers` for
    the blocks and their largest float32 window (local runs; a cluster's workers are its
    own)."""
    if opts.num_workers != "auto":
        return opts
    if not (opts.scheduler is None or opts.scheduler == "threads"):
        return ReconOptions.resolve(opts, {"num_workers": None})
    from metasensor.recon.parallel import local_workers

    area = max((b.window[1] - b.window[0]) * (b.window[3] - b.window[2]) for b in blocks)
    window = view_shape[0] * view_shape[1] * 4 * area // (d * d)
    return ReconOptions.resolve(opts, {"num_workers": local_workers(len(blocks), opts.device,
                                                                    window)})


def _tasks(views, cfg: SystemConfig, method: str, grid, zern, opts: ReconOptions, plan: dict):
    """One keyword-built :class:`BlockTask` per block."""
    import threading

    dao = plan["dao"]
    local = opts.scheduler is None or opts.scheduler in ("threads", "sync")
    ship = not local and isinstance(views, np.ndarray)  # a cluster gets windows, not the stack
    gate = threading.Semaphore(1) if local and (opts.num_workers or 1) > 1 else None
    d = cfg.scan_step_px
    from metasensor.recon.layers import resolve_depth_layers

    layers = resolve_depth_layers(opts.depth_layers)
    out = []
    for b in plan["blocks"]:
        sy, sx = b.window_samples(d)
        out.append(BlockTask(
            block=b, cfg=cfg, views=np.asarray(views[:, :, sy, sx], np.float32) if ship else views,
            uv=plan["uv"], zernike=zern[b.index], solver=plan["solver"], dao=dao, psf=opts.psf,
            psf_fn=opts.psf_fn, register=bool(opts.register), pad=opts.pad,
            dao_negligible=float(opts.dao_negligible or 0.0),
            probe_samples=int(opts.dao_probe_samples), dao_samples=int(opts.dao_samples),
            setup_gate=gate, layers=layers,
            device=plan["device"], windowed=ship, progress=plan["tick"] if local else None,
            corner_zernike=None if plan["corners"] is None else plan["corners"][b.index]))
    return out


def reconstruct(views, cfg: SystemConfig, method: str = "isa", zernike=None, field_zernike=None,
                blocks=(1, 1), options: ReconOptions | None = None, **settings
                ) -> Reconstruction:
    """Reconstruct the image from views (module docstring).

    Parameters
    ----------
    views : array_like
        ``(nnum, nnum, Ly·scan, Lx·scan)`` view stack (NumPy or zarr), not modified.
    cfg : SystemConfig
    method : str
        ``"isa"`` (or ``"none"``), ``"wave"``/``"geometric"`` (DAO per block first), or
        ``"auto"`` (:mod:`metasensor.recon.dao_choice`: wave DAO unless ``zernike``,
        ``field_zernike`` or ``psf`` is given; blocks with a negligible estimate keep the
        aberration-free bank). ``Reconstruction.method`` is the method run.
    zernike : array_like, optional
        ``(J,)`` Noll vector (waves) of the whole field.
    field_zernike : array_like or callable, optional
        Field-dependent aberration (docs/conventions.md), on the reconstruction grid.
    blocks : (int, int)
        Multisite blocks ``(by, bx)``.
    options : ReconOptions, optional
        Every other setting; ``settings`` (keywords named as its fields: ``overlap``,
        ``iterations``, ``device``, ``psf``, ``solver``, ``register``, ...) override it.

    Returns
    -------
    Reconstruction
    """
    t0 = time.perf_counter()
    opts = ReconOptions.resolve(options, settings)
    _check_call(cfg, method, zernike, field_zernike, opts)
    method, opts = _resolve_method(method, cfg, zernike, field_zernike, opts)
    if opts.space_variant and method != "isa":  # "auto" with nothing given estimates it
        raise ValueError("space_variant builds banks at the blocks' corners from the given "
                         "aberration: give zernike or field_zernike, or use method='isa'")
    views = _check_views(views, cfg)
    grid = _block_grid(blocks)
    d = cfg.scan_step_px
    solver = opts.resolved_solver(d)
    if opts.space_variant and solver != "hqs":
        raise ValueError(f"space_variant needs solver='hqs' (got {solver!r})")
    if opts.depth_layers != "off" and solver != "hqs":
        raise ValueError(f"depth_layers needs solver='hqs' (got {solver!r})")
    psf = _check_psf(opts.psf, cfg, opts)
    opts = ReconOptions.resolve(opts, {"psf": psf})
    shape = (views.shape[2] * d, views.shape[3] * d)
    margin = opts.margin if opts.margin is not None else (
        psf.shape[-1] // 2 if psf is not None else cfg.nnum)
    block_list = split_blocks(shape, grid, d, overlap=opts.overlap, margin=margin)
    opts = _resolve_workers(opts, block_list, views.shape, d)
    zern = block_zernikes(block_list, shape, grid, zernike, field_zernike)
    from metasensor.phasespace.views import subset_major, view_order

    mask = cfg.view_mask(opts.view_radius)
    uv = view_order(mask, opts.order)
    dao = block_dao_options(method, cfg, opts.dao, mask, stacklevel=3)
    noise = noise_model(views, opts, solver)
    solver_opts, subsets = _solver_options(opts, solver, len(uv), d, noise, views)
    corners = None
    if opts.space_variant:
        from metasensor.recon.space_variant import corner_zernikes

        corners = corner_zernikes(block_list, shape, zernike, field_zernike,
                                  points=opts.field_points)
    return _run(views, cfg, method, grid, zern, opts, {
        "blocks": block_list, "uv": subset_major(uv, subsets), "solver": solver_opts,
        "subsets": subsets, "shape": shape, "t0": t0, "name": solver, "corners": corners,
        "noise": getattr(solver_opts, "noise_model", None), "dao": dao})


def _run(views, cfg, method, grid, zern, opts: ReconOptions, plan: dict) -> Reconstruction:
    """Run the blocks (progress bar closed on error too) and assemble the result."""
    from contextlib import nullcontext

    from metasensor.backend import resolve_device
    from metasensor.recon.parallel import run_tasks

    plan["device"] = str(resolve_device(opts.device))
    steps = plan["solver"].steps
    bar_cm = nullcontext()
    if opts.progress:
        from tqdm import tqdm

        bar_cm = tqdm(total=len(plan["blocks"]) * steps, desc="reconstruct", unit="it")
    with bar_cm as bar:
        local = opts.scheduler is None or opts.scheduler in ("threads", "sync")
        plan["tick"] = bar.update if bar is not None else None
        collect = Collector(plan["shape"], grid, zern, opts.out, bool(opts.register),
                             None if (bar is None or local) else bar.update)
        run_tasks(reconstruct_block, _tasks(views, cfg, method, grid, zern, opts, plan),
                  collect, scheduler=opts.scheduler, num_workers=opts.num_workers)
    from metasensor.solvers.richardson_lucy import DEFAULT_ITERATIONS

    iterations = DEFAULT_ITERATIONS if opts.iterations is None else int(opts.iterations)
    from metasensor.recon.dao_fit import warn_dao_fit

    warn_dao_fit(collect.dao_fit, grid)
    return Reconstruction(
        image=collect.stitcher.out, zernike=collect.zernike, history=collect.history,
        blocks=plan["blocks"], method=method, config=cfg, iterations=iterations,
        subsets=plan["subsets"], seconds=time.perf_counter() - plan["t0"], solver=plan["name"],
        dao_history=collect.dao, registration=collect.registration,
        registration_zernike=collect.reg_zernike, views_used=len(plan["uv"]),
        dao_applied=collect.applied, dao_zernike=collect.dao_zernike,
        noise_model=plan["noise"], dao_fit_px=collect.dao_fit, depth_layers=collect.layers)
