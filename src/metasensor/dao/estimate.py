"""Digital adaptive optics in one block: wave-optics (and geometric) wavefront estimation.

Hand-written from the paper (Wu et al. 2022, Methods, "ISA with multisite DAO in wave optics").
Alternate, starting from φ = ``init`` (or 0):

1. H = PSFs of every view from the pupil A·exp(i2πφ) (:func:`metasensor.dao.banks.psf_bank`;
   "geometric": the aberration-free PSFs translated by the accumulated view shifts, never
   reshaped);
2. I = the block's image estimate: the paper's light-weighted mean of the views'
   Krishnan–Fergus deconvolutions (``estimator="views"``, :meth:`DaoBlock.estimate`), or, not in
   the paper and the default (``estimator="isa"``), once the last update is below ``isa_below``
   waves, the block's phase-space Richardson–Lucy with the current PSFs
   (:meth:`DaoBlock.estimate_isa`);
3. s_uv = shift of V_uv against the prediction of the same phase-space operator the
   reconstruction fits (:meth:`DaoBlock.measure`; sub-sample cross-correlation weighted by the
   known region of each view sample, not in the paper), clipped to ``max_shift_px``;
4. fit the shifts by Zernike modes (4–45, or the leading set the views used determine:
   :mod:`metasensor.dao.modes`) plus a common offset (:mod:`metasensor.dao.wavefront`; each
   view weighted by the precision of its shift, not in the paper), add the fit to φ.
   Stop when the r.m.s. of the update is below ``tol`` (0 runs all) or after ``max_iter``
   updates. An update whose wavefront would send the used views' rays beyond ``max_reach_px``
   (:func:`metasensor.dao.banks.ray_reach_px`; it bounds the banks' windows) is shortened to
   the largest fraction that keeps them within it (a trust region: a large aberration's first
   fit can overshoot on textures whose shifts are partly aliased); where even ``MIN_STEP`` of
   it would reach beyond, the update is not applied and DAO stops there with one warning (a
   diverging estimate). Neither is in the paper.

``DaoResult.history`` holds the r.m.s. (waves, modes 4–45) of every update. Views used:
``cfg.view_mask()`` (or ``view_mask``), and, when a pupil amplitude is given, its lit views. Why
each step and default is what it is: ``docs/decisions.md`` (``benchmarks/bench_ed_fig4.py``,
``bench_ed_fig5.py``, ``bench_dao.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import torch

from metasensor.backend import as_tensor, resolve_device, to_numpy
from metasensor.config import SystemConfig
from metasensor.dao.banks import geometric_psfs, psf_bank, psf_window, ray_reach_px
from metasensor.dao.block import DaoBlock
from metasensor.dao.modes import choose_modes
from metasensor.dao.options import DaoOptions, DaoResult, resolve_options
from metasensor.dao.wavefront import DAO_MODES, fit_shifts, gradient_matrix, zernike_rms
from metasensor.dao.wavefront import predicted_shifts as _predicted

__all__ = ["DaoOptions", "DaoResult", "run_dao", "estimate_block_aberration", "dao_unavailable",
           "dao_modes", "JMAX"]

JMAX = 45
MIN_SAMPLES = 8  # view samples per side a block needs for DAO
MIN_VIEWS = 8  # used views DAO needs
MIN_STEP = 0.25  # the shortest fraction of a fitted update applied within the rays' reach


def gradient_shifts(phi: np.ndarray, matrix) -> np.ndarray:
    """Modelled view shifts (pixels) of the modes 4–45 of a Noll vector."""
    z = np.array(phi, dtype=np.float64)
    z[:3] = 0.0
    return _predicted(z, None, matrix=matrix)


def _check_block(block_views, cfg: SystemConfig) -> np.ndarray:
    n = cfg.nnum
    v = np.asarray(block_views)
    if v.ndim != 4 or v.shape[:2] != (n, n):
        raise ValueError(f"block_views must have shape ({n}, {n}, h, w), got {v.shape}")
    if min(v.shape[2:]) < MIN_SAMPLES:
        raise ValueError(f"block too small for DAO: views of {v.shape[2:]} samples")
    if not np.isfinite(v).all():
        raise ValueError("block_views contain NaN or infinite values")
    if np.iscomplexobj(v):
        raise ValueError(f"block_views must be real, got dtype {v.dtype}")
    return v


def _initial_phase(init) -> np.ndarray:
    phi = np.zeros(JMAX)
    if init is not None:
        z0 = np.asarray(init, dtype=np.float64).ravel()
        if not np.isfinite(z0).all():
            raise ValueError("init contains NaN or infinite values")
        phi[: min(z0.size, JMAX)] = z0[:JMAX]
    return phi


def _used_views(cfg: SystemConfig, view_mask, amplitude, matrix) -> np.ndarray:
    n = cfg.nnum
    used = cfg.view_mask() if view_mask is None else np.asarray(view_mask, dtype=bool)
    if amplitude is not None:
        amp = np.asarray(amplitude, dtype=np.float64)
        if amp.shape != (n, n):
            raise ValueError(f"amplitude must have shape ({n}, {n}), got {amp.shape}")
        used = used & (amp > 0)
    used = used & (matrix[1] >= 0.5)
    if used.sum() < MIN_VIEWS:
        raise ValueError(_too_few(cfg, used, matrix))
    return used


def _too_few(cfg: SystemConfig, used: np.ndarray, matrix) -> str:
    """One line: too few usable views, which radius they reach, and what would help."""
    u = np.arange(cfg.nnum) - cfg.center
    r = np.sqrt(u[:, None] ** 2 + u[None, :] ** 2)
    reach = float(r[used].max()) if used.any() else 0.0
    pupil = cfg.pupil_radius_px
    lit = int((cfg.view_mask(pupil) & (matrix[1] >= 0.5)).sum())
    hint = (f"pass a larger view_radius (up to {pupil:.2f}: {lit} views)" if lit >= MIN_VIEWS
            else "this system has too few views to estimate a wavefront")
    return (f"only {int(used.sum())} usable views within view_radius {reach:.2f} (DAO needs at "
            f"least {MIN_VIEWS}): {hint}")


def dao_modes(cfg: SystemConfig, view_mask=None, modes=None, *, stacklevel: int = 2
              ) -> tuple[int, ...]:
    """The Noll modes :func:`run_dao` fits with the views ``view_mask`` (default
    ``cfg.view_mask()``): :func:`metasensor.dao.modes.choose_modes` of its usable views (it
    warns when fewer than 4–45 are chosen); ValueError where DAO cannot run with these views."""
    matrix = gradient_matrix(cfg, jmax=JMAX)
    return choose_modes(cfg, _used_views(cfg, view_mask, None, matrix), modes, matrix,
                        stacklevel=stacklevel + 1)


def dao_unavailable(cfg: SystemConfig, view_mask=None) -> str | None:
    """Why :func:`run_dao` cannot estimate a wavefront with the views ``view_mask`` (default
    ``cfg.view_mask()``): fewer than ``MIN_VIEWS`` views whose footprint lies at least half
    inside the pupil, or too few to determine even Noll modes 4–6; None when it can."""
    matrix = gradient_matrix(cfg, jmax=JMAX)
    try:
        choose_modes(cfg, _used_views(cfg, view_mask, None, matrix), None, matrix, warn=False)
    except ValueError as exc:
        return str(exc)
    return None


@dataclass
class _Run:
    """One run's fixed inputs and running state (:func:`run_dao`)."""

    cfg: SystemConfig
    opts: DaoOptions
    used: np.ndarray
    matrix: tuple
    amplitude: np.ndarray | None
    device: str | None
    blk: DaoBlock
    phi: np.ndarray
    total: np.ndarray  # geometric: accumulated absolute view shifts (pixels)
    ideal: np.ndarray | None = None
    history: list = field(default_factory=list)
    fits: list = field(default_factory=list)
    estimates: list = field(default_factory=list)
    shifts: np.ndarray | None = None
    image: torch.Tensor | None = None
    say: Any = None  # callable(str): what the update is doing (the progress bar's postfix)
    rejected: float = 0.0  # ray reach (px) of an update refused as beyond DAO's range
    steps: list = field(default_factory=list)  # fraction of each fitted update applied

    def tell(self, text: str) -> None:
        """Say what the update is doing (and the wavefront so far) on the progress bar."""
        if self.say is not None:
            so_far = (f"; wavefront {zernike_rms(self.phi, self.opts.modes):.3f} λ r.m.s."
                      if self.history else "")
            self.say(f"update {len(self.history) + 1}: {text}{so_far}")

    def size(self, phi) -> int | None:
        size = self.opts.psf_size
        if size == "auto":
            return psf_window(self.cfg, phi if self.opts.method == "wave" else None, self.used)
        return None if size is None else int(size)

    def bank(self) -> np.ndarray:
        """The bank of the current estimate: one-off, so not cached, except the start's (every
        block that starts from the same wavefront, e.g. none, shares it)."""
        if self.opts.method == "wave":
            return psf_bank(self.cfg, self.phi, self.amplitude, self.device,
                            self.size(self.phi), cache=not self.history)
        return geometric_psfs(self.ideal, self.total, self.device)


def _image(run: _Run) -> torch.Tensor:
    """Step 2: the block's image estimate for this update."""
    blk, opts = run.blk, run.opts
    last = run.history[-1] if run.history else math.inf  # inf <= isa_below only for inf
    if opts.estimator == "isa" and last <= opts.isa_below:
        return blk.estimate_isa(tick=lambda i, n: run.tell(f"ISA image, iteration {i}/{n}"))
    s = torch.zeros((blk.views.shape[0], 2), device=blk.views.device, dtype=torch.float64)
    for r in range(opts.inner):
        def tick(i, n, r=r):
            run.tell(f"image from the views, round {r + 1}/{opts.inner}, {i}/{n} views")

        image = blk.estimate(s.to(blk.views.dtype), tick)
        if r + 1 < opts.inner:
            run.tell(f"view shifts, round {r + 1}/{opts.inner}")
            s = blk.measure(image, opts.max_shift_px)
    return image


def _update(run: _Run) -> None:
    """Steps 1-4: one phase update."""
    n, opts, used = run.cfg.nnum, run.opts, run.used
    run.tell("PSF bank of the current wavefront")
    run.blk.set_psfs(run.bank())
    run.image = _image(run)
    run.tell("view shifts and the wavefront fit")
    s, prec = run.blk.measure(run.image, opts.max_shift_px, precision=True)
    s_full = np.full((n, n, 2), np.nan)
    s_full[used] = to_numpy(s)
    clipped = np.abs(s_full).max(axis=-1) >= opts.max_shift_px - 1e-6
    wts = None
    if opts.weigh_views:
        wts = np.zeros((n, n))
        wts[used] = np.nan_to_num(to_numpy(prec), nan=0.0, posinf=0.0)
        mean_w = float(wts[used & ~clipped].mean()) if (used & ~clipped).any() else 0.0
        wts = wts / mean_w if mean_w > 0 else None
    fit = fit_shifts(np.nan_to_num(s_full), run.cfg, mask=used & ~clipped, modes=opts.modes,
                     weights=wts, matrix=run.matrix)
    step = _step_within_reach(run, fit.zernike)
    if step is None:  # rays beyond DAO's reach even for a short step: a divergence
        run.rejected = ray_reach_px(run.cfg, run.phi + fit.zernike, used)
        return
    run.steps.append(step)
    run.fits.append(fit.residual_rms)
    run.history.append(zernike_rms(step * fit.zernike, DAO_MODES))
    run.phi = run.phi + step * fit.zernike
    run.estimates.append(run.phi.copy())
    run.shifts = np.nan_to_num(s_full)
    if opts.method == "geometric":
        run.total = run.total + step * np.where(used[..., None], run.shifts - fit.tilt, 0.0)


def _step_within_reach(run: _Run, update: np.ndarray) -> float | None:
    """The fraction of ``update`` to apply: 1 where the rays of ``phi + update`` stay within
    ``max_reach_px``, else the largest fraction that keeps them there (bisection, to
    1/1024), or None where that is below ``MIN_STEP`` (or the current estimate already
    reaches beyond)."""
    limit = run.opts.max_reach_px

    def within(alpha: float) -> bool:
        return ray_reach_px(run.cfg, run.phi + alpha * update, run.used) <= limit

    if within(1.0):
        return 1.0
    if not within(MIN_STEP):
        return None
    lo, hi = MIN_STEP, 1.0
    for _ in range(10):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if within(mid) else (lo, mid)
    return lo


def _warn_rejected(run: _Run) -> None:
    """One warning: the last update was refused (even a quarter of it sends the rays beyond
    ``max_reach_px``), the estimate stays at the updates before it."""
    import warnings

    warnings.warn(f"DAO stopped after {len(run.history)} update(s): the next estimate's rays "
                  f"would reach {run.rejected:.0f} px, beyond max_reach_px "
                  f"({run.opts.max_reach_px:g} px) even for a quarter of the update; the "
                  "estimate so far is kept",
                  RuntimeWarning, stacklevel=3)


def run_dao(block_views, cfg: SystemConfig, options: DaoOptions | None = None, *, init=None,
            device=None, amplitude=None, view_mask=None, **settings) -> DaoResult:
    """Wavefront estimation in one block (module docstring).

    Parameters
    ----------
    block_views : array_like
        ``(nnum, nnum, h, w)`` the block's views (scan-step grid, any intensity scale).
    cfg : SystemConfig
    options : DaoOptions, optional
        The loop's settings; ``settings`` (keywords named as its fields, e.g. ``method="wave"``,
        ``max_iter=3``) override them.
    init : array_like, optional
        Initial Noll vector (waves), e.g. the local system aberration; None = 0.
    device : str, optional
    amplitude : array_like, optional
        ``(nnum, nnum)`` pupil amplitude (:mod:`metasensor.dao.pupil`).
    view_mask : array_like, optional
        ``(nnum, nnum)`` views to use (default ``cfg.view_mask()``).

    Returns
    -------
    DaoResult
        Its ``modes``: those fitted (``options.modes``, or where None the leading set the used
        views determine, with a warning when fewer than 4–45: :mod:`metasensor.dao.modes`).
    """
    opts = resolve_options(options, settings)
    v = _check_block(block_views, cfg)
    phi = _initial_phase(init)
    matrix = gradient_matrix(cfg, jmax=JMAX)
    used = _used_views(cfg, view_mask, amplitude, matrix)
    modes = choose_modes(cfg, used, opts.modes, matrix, stacklevel=3)
    if modes != opts.modes:
        opts = replace(opts, modes=modes)
    n = cfg.nnum
    views = as_tensor(v.reshape(n * n, *v.shape[2:])[used.ravel()], resolve_device(device))
    run = _Run(cfg, opts, used, matrix, amplitude, device, DaoBlock(views, cfg, used, opts.lam,
               opts.chunk), phi, np.where(used[..., None], gradient_shifts(phi, matrix), 0.0))
    if opts.method == "geometric":
        run.ideal = psf_bank(cfg, None, amplitude, device, run.size(None))
    from tqdm.auto import tqdm

    with tqdm(total=opts.max_iter, desc=f"DAO ({opts.method})", disable=not opts.progress,
              leave=False) as bar:
        run.say = lambda text: bar.set_postfix_str(text, refresh=True)
        for _ in range(opts.max_iter):
            _update(run)
            if run.rejected:
                _warn_rejected(run)
                break
            bar.set_postfix_str(f"update {run.history[-1]:.3f} λ, wavefront "
                                f"{zernike_rms(run.phi, opts.modes):.3f} λ r.m.s.", refresh=False)
            bar.update(1)
            if run.history[-1] < opts.tol:
                break
    shifts = run.total if opts.method == "geometric" else np.where(
        used[..., None], gradient_shifts(run.phi, matrix), 0.0)
    image = None if run.image is None else to_numpy(run.image) * run.blk.scale
    return DaoResult(zernike=run.phi, history=run.history, shifts=shifts, method=opts.method,
                     residual_shifts=run.shifts, image=image, fits=run.fits,
                     psf_size=run.size(run.phi), estimates=run.estimates, steps=run.steps,
                     modes=opts.modes)


def estimate_block_aberration(block_views, cfg: SystemConfig, method: str = "wave", init=None,
                              device=None, **settings) -> tuple[np.ndarray, list[float]]:
    """One block's aberration: ``run_dao(..., method=method, **settings)``'s Noll vector
    ``(45,)`` (waves, float64) and the r.m.s. of every update. For ``method="geometric"``
    reconstruct with :func:`metasensor.dao.banks.block_psfs` of the full :class:`DaoResult`
    (ideal PSFs translated by the measured shifts), not with PSFs of this vector."""
    res = run_dao(block_views, cfg, init=init, device=device, method=method, **settings)
    return res.zernike.astype(np.float64), list(res.history)
