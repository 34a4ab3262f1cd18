"""One block of :func:`metasensor.reconstruct`: window → bank → optional registration → solve.

A :class:`BlockTask` carries what one block needs (picklable, for dask.distributed workers);
:func:`reconstruct_block` returns the block's region image and what was estimated on the way.
The bank is a given one, ``psf_fn``'s or ``view_psfs``' of the block's aberration, or, with DAO
(``dao`` set), the bank of the block's estimated wavefront (:func:`metasensor.dao.banks.
block_psfs`). The views of the bank's visiting order become the operator's data
(:class:`metasensor.phasespace.operator.PhaseSpaceOperator`), which the solver fits
(:func:`metasensor.solvers.solve`).
"""

from __future__ import annotations

import sys
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from metasensor.config import SystemConfig
from metasensor.dao.estimate import DaoOptions
from metasensor.recon.blocks import Block
from metasensor.recon.dao_choice import DAO_SAMPLES, PROBE_SAMPLES
from metasensor.recon.probe import probe_window

__all__ = ["BlockTask", "BlockResult", "reconstruct_block", "default_psfs", "probe_window"]

# view samples (per view) of the largest block window whose DAO always runs outside the set-up
# gate; why this size: docs/decisions.md
DAO_UNGATED_SAMPLES = 96 * 96
# DAO's memory on a window of n view samples (per view): about DAO_BASE_BYTES + n times
# DAO_BYTES_PER_SAMPLE (measured: docs/decisions.md); a larger window's DAO runs outside the
# gate too where the free memory holds twice that
DAO_BASE_BYTES = 350 * 10**6
DAO_BYTES_PER_SAMPLE = 25 * 10**3


@dataclass
class BlockTask:
    """Everything one block needs (picklable: built with keywords, no callables but
    ``psf_fn``/``progress``).

    Attributes
    ----------
    block : Block
    cfg : SystemConfig
    views : array
        The full view stack (NumPy or zarr, sliced lazily) or, with ``windowed``, the window.
    uv : list of (int, int)
        The views used, in the solver's (subset-major) order.
    zernike : numpy.ndarray
        The block's Noll vector (waves): its aberration, or DAO's start.
    solver : RLOptions or HQSOptions
        What :func:`metasensor.solvers.solve` runs.
    dao : DaoOptions or None
        DAO's settings (wave/geometric), None for plain ISA.
    dao_negligible : float
        Waves r.m.s. (Noll 4-45): an estimate that differs from ``zernike`` by less is not
        applied (the block keeps ``zernike``'s bank); 0: always applied.
    probe_samples : int
        With ``dao_negligible``: view samples per side of the sub-window the probe decides on
        (:func:`probe_window`); windows no larger are probed whole.
    dao_samples : int
        View samples per side of the sub-window DAO estimates the block's wavefront on (the
        most detailed, :func:`probe_window`); windows no larger are read whole.
    layers : DepthLayers or None
        The depth-aware model's settings (:mod:`metasensor.recon.layers`): a block whose views
        show two depth layers is solved with one bank per layer; None: one bank.
    setup_gate : threading.Semaphore or None
        Local runs of several blocks at once: held from the block's start to its solver's
        first progress call (HQS: its set-up done), so that no two blocks build their spectra
        at once (their peaks add up);
        lifted while DAO estimates the wavefront on a sub-window of at most
        ``DAO_UNGATED_SAMPLES`` view samples, so that one block's DAO does not idle the others,
        and on a larger one where the free memory holds two such DAOs (elsewhere a larger DAO
        window holds it: DAO's memory grows with its window).
    """

    block: Block
    cfg: SystemConfig
    views: Any
    uv: list
    zernike: np.ndarray
    solver: Any
    dao: DaoOptions | None = None
    psf: np.ndarray | None = None
    psf_fn: Any = None
    register: bool = False
    pad: bool = True
    device: str | None = None
    windowed: bool = False
    progress: Any = None  # callable(n), local runs only
    corner_zernike: np.ndarray | None = None  # (points², J): space-variant field points
    dao_negligible: float = 0.0
    probe_samples: int = PROBE_SAMPLES
    dao_samples: int = DAO_SAMPLES
    setup_gate: Any = None
    layers: Any = None  # DepthLayers: the depth-aware model (recon.layers); None: one bank


@dataclass
class BlockResult:
    """A block's region image ``(ry, rx)`` float32, its Noll vector (waves), the solver's and
    DAO's histories, the registration's (r.m.s. shift per round, wavefront), whether DAO's
    estimate was applied (None: no DAO) and the estimate, and the depth layers' disparities
    relative to the block's wavefront (view pixels per view step; empty: one layer)."""

    block: Block
    image: np.ndarray
    zernike: np.ndarray
    history: list[float]
    dao_history: list[float] = field(default_factory=list)
    registration: list[float] = field(default_factory=list)
    registration_zernike: np.ndarray | None = None
    dao_applied: bool | None = None
    dao_zernike: np.ndarray | None = None
    dao_fit_px: float | None = None
    layers: tuple = ()


def default_psfs(cfg: SystemConfig, zernike, device, size: int | None = None) -> np.ndarray:
    """``view_psfs(cfg, zernike)`` (None for a zero vector) as float32; ``size``: window K."""
    from metasensor.optics.psf import view_psfs

    z = None if zernike is None or not np.any(zernike) else np.asarray(zernike, np.float64)
    kw = {} if size is None else {"size": int(size)}
    if cfg.grid_points != cfg.nnum:  # a scan period that does not divide nnum: the grid's bank
        kw["points"] = cfg.grid_points
    return np.asarray(view_psfs(cfg, zernike=z, depth=0.0, device=device, **kw),
                      dtype=np.float32)


def _report_dao(index, zernike: np.ndarray, history: list[float], tol: float,
                applied: bool, negligible: float) -> None:
    """One line per block under the progress bar: the wavefront DAO estimated (waves r.m.s.
    over Noll 4-45), how it converged, and whether it was applied."""
    import sys

    from tqdm import tqdm

    from metasensor.dao.wavefront import zernike_rms

    rms = zernike_rms(zernike)
    last = history[-1] if history else 0.0
    note = ("negligible: no further update" if len(history) == 1 and last < tol
            else "converged" if last < tol else "not converged")
    if not applied:
        note += f"; under {negligible:g} λ: not applied (the block keeps its starting bank)"
    tqdm.write(f"block {tuple(int(i) for i in index)}: wavefront {rms:.3f} λ r.m.s. (Noll "
               f"4-45), {len(history)} DAO update(s), last {last:.3f} λ: {note}",
               file=sys.stderr)


def _negligible(estimate: np.ndarray, start: np.ndarray, threshold: float) -> bool:
    """Whether ``estimate`` differs from ``start`` by less than ``threshold`` waves r.m.s.
    (Noll 4-45)."""
    from metasensor.dao.wavefront import zernike_rms

    if threshold <= 0:
        return False
    diff = np.zeros(max(estimate.size, start.size), np.float64)
    diff[:estimate.size] += estimate
    diff[:start.size] -= start
    return zernike_rms(diff) < threshold


def _window(task: BlockTask) -> np.ndarray:
    if task.windowed:
        window = np.asarray(task.views, dtype=np.float32)
    else:
        sy, sx = task.block.window_samples(task.cfg.scan_step_px)
        window = np.asarray(task.views[:, :, sy, sx], dtype=np.float32)
    if not np.isfinite(window).all():
        raise ValueError(f"views contain NaN or infinite values in block {task.block.index}")
    return window


def _view_mask(task: BlockTask) -> np.ndarray:
    """``(nnum, nnum)`` bool: the reconstruction's views (``task.uv``), those DAO measures."""
    mask = np.zeros((task.cfg.nnum, task.cfg.nnum), dtype=bool)
    mask[tuple(np.asarray(task.uv, dtype=int).T)] = True
    return mask


def _probe(task: BlockTask, window: np.ndarray, dao, init):
    """With ``dao_negligible``: one DAO update on the ISA image of the block's
    :func:`probe_window` (cheap: no per-view deconvolution, a sub-window), returned when its
    estimate is negligible, else None (the full estimate runs on the ``dao_samples``
    sub-window, from the start again: far from the truth the ISA image absorbs part of the
    error)."""
    if task.dao_negligible <= 0:
        return None
    import math

    from metasensor.dao import estimate

    probe = estimate.run_dao(probe_window(window, task.probe_samples), task.cfg,
                             replace(dao, max_iter=1, isa_below=math.inf), init=init,
                             device=task.device, view_mask=_view_mask(task))
    start = np.zeros(0) if init is None else np.asarray(init, np.float64)
    return probe if _negligible(np.asarray(probe.zernike), start, task.dao_negligible) else None


def _bank(task: BlockTask, window: np.ndarray
          ) -> tuple[np.ndarray, np.ndarray, list[float], np.ndarray | None, float | None]:
    """The block's bank ``(nnum, nnum, K, K)``, the Noll vector it was made of, DAO's history,
    DAO's estimate (None: no DAO; applied when it is that Noll vector) and the r.m.s. residual
    (pixels) of DAO's last shift fit (None: no DAO)."""
    zernike = np.asarray(task.zernike, dtype=np.float32)
    if task.dao is None:
        if task.psf is not None:
            return task.psf, zernike, [], None, None
        return ((task.psf_fn or default_psfs)(task.cfg, zernike, task.device), zernike, [], None,
                None)
    from metasensor.dao import banks, estimate

    if task.dao_negligible > 0 and min(window.shape[-2:]) < estimate.MIN_SAMPLES:
        import warnings  # "auto": a block too small to estimate keeps its start

        warnings.warn(f"blocks of {window.shape[-2]} x {window.shape[-1]} view samples are too "
                      f"small for DAO (at least {estimate.MIN_SAMPLES}): the aberration is not "
                      "estimated there", UserWarning, stacklevel=2)
        return ((task.psf_fn or default_psfs)(task.cfg, zernike, task.device), zernike, [], None,
                None)
    init = zernike if np.any(zernike) else None
    shown = task.progress is not None  # a local run with a bar: show DAO's updates too
    dao = replace(task.dao, progress=True) if shown else task.dao
    res = _probe(task, window, dao, init)
    if res is None:  # not negligible (or no probe): the full estimate, on a sub-window
        sub = probe_window(window, task.dao_samples)
        with _gate_lifted(task.setup_gate if _dao_ungated(sub) else None):
            res = estimate.run_dao(sub, task.cfg, dao, init=init, device=task.device,
                                   view_mask=_view_mask(task))
    z_est = np.asarray(res.zernike, dtype=np.float32).ravel()
    merged = np.zeros(max(zernike.size, z_est.size), np.float32)
    merged[:z_est.size] = z_est
    history = [float(h) for h in res.history]
    fit = float(res.fits[-1]) if res.fits else None
    applied = not _negligible(merged, zernike, task.dao_negligible)
    if shown:
        _report_dao(task.block.index, merged, history, task.dao.tol, applied,
                    task.dao_negligible)
    if not applied:  # the starting aberration's bank (cached), not a one-off bank of noise
        start = np.zeros_like(merged)
        start[:zernike.size] = zernike
        bank = (task.psf_fn or default_psfs)(task.cfg, zernike, task.device)
        return bank, start, history, merged, fit
    bank = (task.psf_fn(task.cfg, merged, task.device) if task.psf_fn is not None
            else banks.block_psfs(task.cfg, res, device=task.device))
    if shown:  # the estimate's bank is new: say it is done before the solver's first step
        from tqdm import tqdm

        tqdm.write(f"block {tuple(int(i) for i in task.block.index)}: PSF bank of the "
                   f"estimate ready ({np.shape(bank)[-1]} px), solving", file=sys.stderr)
    return bank, merged, history, merged, fit


def _dao_ungated(sub: np.ndarray) -> bool:
    """Whether DAO on the sub-window ``sub`` runs outside the set-up gate: a small window, or
    one whose DAO (:data:`DAO_BASE_BYTES`, :data:`DAO_BYTES_PER_SAMPLE`) the free memory
    (:func:`metasensor.io.memory.memory_room`) holds twice over, another block's beside it."""
    n = sub.shape[-2] * sub.shape[-1]
    if n <= DAO_UNGATED_SAMPLES:
        return True
    from metasensor.io.memory import memory_room

    return memory_room() >= 2 * (DAO_BASE_BYTES + DAO_BYTES_PER_SAMPLE * n)


def _operator(task: BlockTask, psf: np.ndarray, data_win: np.ndarray):
    """The block's operator (on the registered bank with ``register``), the registration's
    r.m.s. shifts per round and its wavefront."""
    from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry

    if task.register:
        from metasensor.dao.bank_registration import register_views

        reg = register_views(psf, data_win, task.cfg.scan_step_px, cfg=task.cfg, uv=task.uv,
                             device=task.device, pad=task.pad)
        return reg.operator, reg.history, reg.zernike
    geometry = make_geometry(data_win.shape[-2:], task.cfg.scan_step_px, psf.shape[-1] // 2,
                             pad=task.pad)
    return PhaseSpaceOperator(psf, geometry, device=task.device), [], None


@contextmanager
def _gate_lifted(gate):
    """Release the held ``gate`` (None: nothing) for the body, and take it back after."""
    if gate is None:
        yield
        return
    gate.release()
    try:
        yield
    finally:
        gate.acquire()


class _Release:
    """Releases ``gate`` once (at the solver's first progress call: HQS's set-up done,
    Richardson–Lucy's first iteration; or when the block ends)."""

    def __init__(self, gate) -> None:
        self.gate = gate

    def __call__(self, *_) -> None:
        gate, self.gate = self.gate, None
        if gate is not None:
            gate.release()


def reconstruct_block(task: BlockTask) -> BlockResult:
    """Window → bank → optional registration → solve (module docstring) for one block (its
    set-up under ``task.setup_gate``, when given)."""
    if task.setup_gate is None:
        return _reconstruct(task, None)
    task.setup_gate.acquire()
    release = _Release(task.setup_gate)
    try:
        return _reconstruct(task, release)
    finally:
        release()


def _reconstruct(task: BlockTask, started) -> BlockResult:
    cfg = task.cfg
    window = _window(task)
    rows, cols = [u for u, _ in task.uv], [v for _, v in task.uv]
    if task.corner_zernike is not None:  # banks at the core's corners, blended
        from metasensor.recon.space_variant import space_variant_operator

        op, registration, reg_zernike = space_variant_operator(task, window[rows, cols], rows,
                                                               cols)
        return _solve(task, op, window[rows, cols], np.asarray(task.zernike, np.float32), [],
                      registration, reg_zernike, started=started)
    bank, zernike, dao_history, estimate, fit = _bank(task, window)
    bank = np.asarray(bank, dtype=np.float32)
    if bank.ndim != 4 or bank.shape[:2] != (cfg.nnum, cfg.nnum):
        raise ValueError(f"psf bank must have shape (nnum, nnum, K, K) with nnum = {cfg.nnum}, "
                         f"got {bank.shape}")
    op, registration, reg_zernike = _operator(task, bank[rows, cols], window[rows, cols])
    res, full, x = _solve(task, op, window[rows, cols], zernike, dao_history, registration,
                          reg_zernike, estimate, started, full=True)
    res = replace(res, dao_fit_px=fit)
    if task.layers is None:
        return res
    return _layered(task, window, zernike, rows, cols, (res, full, x), op, dao_history, estimate)


def _layered(task: BlockTask, window: np.ndarray, zernike, rows, cols, one: tuple, one_op,
             dao_history, estimate) -> BlockResult:
    """The depth-aware model (:mod:`metasensor.recon.layers`): where the block's views show two
    depth layers (decided on its one-bank image, the window's pixels) and the two-layer fit
    explains the data of the layer it defocuses most better than the one-bank fit (``one``:
    its result, image and estimate on ``one_op``'s domain), the block solved with one bank per
    layer; else the one-bank result."""
    from metasensor.recon.layer_segments import pool_to_views
    from metasensor.recon.layers import layered_operator, layers_fit_better

    res, full, one_x = one
    guide = pool_to_views(full, task.cfg.scan_step_px)
    layered = layered_operator(task, window, zernike, rows, cols, guide)
    if layered is None:
        return res
    op, found = layered
    quiet = replace(task, progress=None)  # the bar counts one solve per block
    data = window[rows, cols]
    two, _, two_x = _solve(quiet, op, data, zernike, dao_history, [], None, estimate, full=True)
    region = task.block.region_samples(task.cfg.scan_step_px)
    if not layers_fit_better(found.labels, region, misfit_map(one_op, one_x, data),
                             misfit_map(op, two_x, data), found.disparity,
                             task.layers.misfit_ratio):
        return res
    return replace(two, dao_fit_px=res.dao_fit_px,
                   layers=tuple(float(v) for v in found.disparity))


def misfit_map(op, estimate, data_win: np.ndarray) -> np.ndarray:
    """``(Sy, Sx)`` r.m.s. over the views of the model's misfit ``A·estimate − data`` at each of
    the window's view samples (``data_win`` ``(V, Sy, Sx)``, ``estimate`` on ``op``'s
    domain)."""
    import torch

    with torch.no_grad():
        data, _ = op.geometry.embed(torch.from_numpy(np.asarray(data_win)).to(op.device))
        sy, sx = op.geometry.sample_slices()
        res = op.forward(estimate)[:, sy, sx] - data[:, sy, sx]
        return torch.sqrt((res.double() ** 2).mean(0)).cpu().numpy()


def _solve(task: BlockTask, op, data_win: np.ndarray, zernike, dao_history, registration,
           reg_zernike, estimate=None, started=None, full: bool = False):
    """Solve the block on ``op`` and cut its region out of the estimate (``estimate``: DAO's,
    applied when it is ``zernike`` itself; ``started``: called at the solver's every step);
    ``full``: also the estimate over the whole window and on the operator's domain (a
    ``(BlockResult, image, domain estimate)`` triple)."""
    import torch

    from metasensor.solvers import solve

    progress = task.progress
    if started is not None:
        def progress(n: int, inner=task.progress) -> None:
            started()
            if inner is not None:
                inner(n)

    data, mask = op.geometry.embed(torch.from_numpy(data_win).to(op.device))
    result = solve(op, data, mask, task.solver, progress=progress)
    image = op.geometry.crop(result.estimate).detach().cpu().numpy()
    ry, rx = task.block.region_in_window()
    out = BlockResult(task.block, np.ascontiguousarray(image[ry, rx], dtype=np.float32),
                      zernike, result.history, dao_history, registration, reg_zernike,
                      None if estimate is None else estimate is zernike,  # applied: the same
                      estimate)
    return (out, image, result.estimate.detach()) if full else out
