"""View registration before ISA: each view's sub-pixel shift against the model, put into its PSF.

Hand-written (no library registers views through a phase-space forward model). Per round:

1. I = phase-space Richardson–Lucy of all views with the current bank (5 iterations, 16 subsets:
   it blurs rather than invents, so its predictions carry little of the model error);
2. s_uv = shift of the measured view V_uv against its prediction ``op.forward(I)`` by the same
   :class:`~metasensor.phasespace.operator.PhaseSpaceOperator` the solver fits
   (:func:`metasensor.align.shifts.measure_shifts_torch`, observed samples only), in pixels,
   less their light-weighted mean (a shift common to all views is the image's position);
3. with the system known (``cfg``, ``uv``): s_uv is replaced by its fit with the gradients of a
   wavefront error (Noll 4–21, :mod:`metasensor.dao.wavefront`), since a bank that is off is a
   wavefront that is off; a round whose fit explains less than :data:`MIN_EXPLAINED` of the
   shifts' variance is not a wavefront error and ends the registration (with fewer than
   :data:`MIN_FIT_VIEWS` views the shifts go unfitted);
4. H_uv ← the round-0 H_uv translated by the accumulated s_uv (Fourier shift, energy kept),
   accepted only if the Richardson–Lucy fit with it leaves a smaller misfit ‖y − A I‖.

Stop when a round's r.m.s. shift is below ``tol_px`` (that step is not applied), a round is not
a wavefront error, a candidate is rejected, or after ``rounds`` rounds. ``Registration.zernike``
is the wavefront the applied shifts amount to (the bank's error with the opposite sign). What it
cannot fix: a change of the PSFs' shape beyond a shift, and shifts that vary within a block.
Opt-in (``reconstruct(register=True)``); the measurements behind the defaults and the opt-in are
in ``docs/decisions.md`` (``benchmarks/bench_isa_mismatch.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from metasensor.align.shifts import fourier_shift, measure_shifts_torch
from metasensor.backend import resolve_device
from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
from metasensor.solvers.richardson_lucy import RLOptions, richardson_lucy

__all__ = ["translate_psfs", "register_views", "Registration", "RegistrationOptions",
           "WAVEFRONT_MODES", "MIN_EXPLAINED", "MIN_FIT_VIEWS"]

WAVEFRONT_MODES = tuple(range(4, 22))  # the bank error's wavefront: Noll 4-21
MIN_EXPLAINED = 0.7  # share of the shifts' variance a round's wavefront fit must explain
MIN_FIT_VIEWS = 30  # 2 x 30 shift components for 18 modes + 2 common: fewer, no fit


@dataclass(frozen=True)
class RegistrationOptions:
    """Settings of :func:`register_views` (frozen, validated).

    Attributes
    ----------
    rounds : int
        Rounds at most (>= 0; default 3).
    tol_px : float
        A round below this r.m.s. shift (pixels) ends the registration (default 0.02).
    max_shift_px : float or None
        Bound of each round's shift (pixels; default a third of the window's smaller side, at
        most 50).
    iterations, subsets : int
        Richardson–Lucy's fit of every round (defaults 5, 16).
    pad : bool
        Padded (linear) operator domains (default True).
    """

    rounds: int = 3
    tol_px: float = 0.02
    max_shift_px: float | None = None
    iterations: int = 5
    subsets: int = 16
    pad: bool = True

    def __post_init__(self) -> None:
        if self.rounds < 0:
            raise ValueError(f"rounds must be >= 0, got {self.rounds}")
        if not self.tol_px >= 0:
            raise ValueError(f"tol_px must be >= 0, got {self.tol_px!r}")
        if self.max_shift_px is not None and not self.max_shift_px > 0:
            raise ValueError(f"max_shift_px must be > 0, got {self.max_shift_px!r}")


@dataclass
class Registration:
    """psf (V, K', K') the registered bank; shifts (V, 2) float64 pixels (dy, dx) it was
    translated by; history: r.m.s. shift (pixels) measured in every round; misfits: the relative
    misfit ||y − A x||/||y|| of the Richardson–Lucy fit with the given bank, then with each
    round's candidate (a candidate that does not lower it is rejected and ends the loop)."""

    psf: torch.Tensor
    shifts: torch.Tensor
    history: list[float] = field(default_factory=list)
    misfits: list[float] = field(default_factory=list)
    operator: PhaseSpaceOperator | None = None  # built on ``psf`` (pad as asked), for reuse
    # with a system: the wavefront (Noll vector, waves, modes WAVEFRONT_MODES) the applied shifts
    # amount to (the bank's error, opposite sign), and the variance fraction each round's fit
    # explained
    zernike: np.ndarray | None = None
    explained: list[float] = field(default_factory=list)


def translate_psfs(psf: torch.Tensor, shifts: torch.Tensor) -> torch.Tensor:
    """PSFs ``(V, K, K)`` translated by ``shifts (V, 2)`` pixels (dy, dx), sub-pixel (Fourier
    shift, ``out(p) = psf(p − s)``), padded to hold the largest shift (K' = K + 2·pad, odd, same
    centre), clipped at zero and rescaled to each PSF's own energy."""
    if psf.ndim != 3 or psf.shape[-1] != psf.shape[-2] or psf.shape[-1] % 2 == 0:
        raise ValueError(f"psf must have shape (V, K, K) with K odd, got {tuple(psf.shape)}")
    s = torch.as_tensor(shifts, dtype=torch.float64, device=psf.device)
    if s.shape != (psf.shape[0], 2):
        raise ValueError(f"shifts must have shape ({psf.shape[0]}, 2), got {tuple(s.shape)}")
    if not torch.isfinite(s).all():
        raise ValueError("shifts contain NaN or infinite values")
    pad = int(math.ceil(float(s.abs().max()))) + 2 if s.numel() else 0
    padded = torch.nn.functional.pad(psf, (pad, pad, pad, pad))
    out = fourier_shift(padded, s.to(device=psf.device, dtype=psf.dtype)).clamp(min=0)
    e0 = psf.sum(dim=(-2, -1))
    e1 = out.sum(dim=(-2, -1))
    return out * torch.where(e1 > 0, e0 / e1.clamp(min=1e-30), torch.zeros_like(e0))[:, None, None]


def _wavefront_fit(step: torch.Tensor, cfg, uv, matrix) -> tuple[torch.Tensor, np.ndarray, float]:
    """The shifts ``step (V, 2)`` of views ``uv`` fitted by wavefront-error gradients: (fitted
    shifts (V, 2), Noll vector (waves), fraction of the shifts' variance explained)."""
    from metasensor.dao.wavefront import fit_shifts, predicted_shifts

    n = cfg.nnum
    grid = np.full((n, n, 2), np.nan)
    used = np.zeros((n, n), bool)
    for k, (u, v) in enumerate(uv):
        grid[u, v] = step[k].numpy()
        used[u, v] = True
    fit = fit_shifts(grid, cfg, mask=used, modes=WAVEFRONT_MODES, reject=0, matrix=matrix,
                     min_footprint=0.0)
    rows, cols = (list(a) for a in zip(*uv, strict=True))
    smooth = predicted_shifts(fit.zernike, cfg, matrix=matrix)[rows, cols]
    total = float((step - step.mean(dim=0)).pow(2).sum(dim=1).mean())
    explained = 1.0 - fit.residual_rms**2 / total if total > 0 else 0.0
    return torch.from_numpy(smooth), fit.zernike, explained


def _fit(bank, y_win, d: int, options: RegistrationOptions, device):
    """The operator of ``bank``, its prediction of the RL estimate, the embedded data, the mask
    as weights, and the relative misfit ‖y − A I‖/‖y‖ over observed samples."""
    geometry = make_geometry(tuple(y_win.shape[-2:]), d, bank.shape[-1] // 2, pad=options.pad)
    op = PhaseSpaceOperator(bank, geometry, device=device)
    data, mask = geometry.embed(y_win.to(op.device))
    rl = RLOptions(iterations=options.iterations, subsets=min(options.subsets, bank.shape[0]))
    pred = op.forward(richardson_lucy(op, data, mask, rl).estimate)
    m = mask.to(pred.dtype)[None]
    misfit = float(torch.linalg.vector_norm((pred - data) * m))
    return op, pred, data, m.expand_as(pred), misfit / max(
        float(torch.linalg.vector_norm(data)), 1e-30)


def _fit_matrix(cfg, uv, n_bank: int):
    """The wavefront-gradient matrix when the system is known and views are to spare."""
    if (cfg is None) != (uv is None):
        raise ValueError("register_views needs both cfg and uv (or neither)")
    if cfg is None:
        return None
    from metasensor.dao.wavefront import gradient_matrix

    if len(uv) != n_bank:
        raise ValueError(f"uv lists {len(uv)} views, the bank holds {n_bank}")
    # the fit needs views to spare: with fewer than MIN_FIT_VIEWS the shifts go unfitted
    return gradient_matrix(cfg, jmax=max(WAVEFRONT_MODES)) if len(uv) >= MIN_FIT_VIEWS else None


def register_views(psf, data_win, d: int, options: RegistrationOptions | None = None, *,
                   cfg=None, uv=None, device=None, **settings) -> Registration:
    """Register views against a bank (module docstring).

    Parameters
    ----------
    psf : array_like
        ``(V, K, K)`` the bank, one PSF per view.
    data_win : array_like
        ``(V, Sy, Sx)`` a window of view samples every ``d`` pixels.
    d : int
        Scan step (pixels).
    options : RegistrationOptions, optional
        ``settings`` (keywords named as its fields) override it.
    cfg : SystemConfig, optional
    uv : list of (int, int), optional
        The views' indices (one per bank row); with ``cfg``, each round's shifts are replaced
        by their wavefront-error fit (:data:`WAVEFRONT_MODES`).
    device : str, optional

    Returns
    -------
    Registration
    """
    from dataclasses import replace

    opts = replace(options or RegistrationOptions(), **settings)
    dev = resolve_device(device)  # the bank and the data go to the device once
    psf0 = torch.as_tensor(psf, dtype=torch.float32, device=dev)
    y_win = torch.as_tensor(data_win, dtype=torch.float32, device=dev)
    if psf0.ndim != 3 or y_win.ndim != 3 or psf0.shape[0] != y_win.shape[0]:
        raise ValueError(f"psf (V, K, K) and data_win (V, Sy, Sx) must agree in V, got "
                         f"{tuple(psf0.shape)} and {tuple(y_win.shape)}")
    matrix = _fit_matrix(cfg, uv, psf0.shape[0])
    zsum = np.zeros(max(WAVEFRONT_MODES)) if matrix is not None else None
    explained: list[float] = []
    max_shift = opts.max_shift_px or min(50.0, min(y_win.shape[-2:]) * d / 3.0)
    light = psf0.sum(dim=(-2, -1)).to(torch.float64).cpu()

    def centred(s):  # a shift common to all views is the image's position, which the views
        # cannot tell from the bank's: keep the bank's (an offset of 0.78 px crept in without)
        return s - (light[:, None] * s).sum(dim=0) / light.sum()

    total = torch.zeros((psf0.shape[0], 2), dtype=torch.float64, device="cpu")
    current = psf0
    op, pred, data, weight, misfit = _fit(current, y_win, d, opts, device)
    history: list[float] = []
    misfits = [misfit]
    for _ in range(opts.rounds):
        step = measure_shifts_torch(pred, data, weight=weight, max_shift=max_shift / d)
        step = centred(step.cpu() * d)
        rms = float(step.pow(2).sum(dim=1).mean().sqrt())
        history.append(rms)
        if rms < opts.tol_px:  # registered: a step this small changes nothing worth a fit
            break
        z_step = None
        if matrix is not None:  # a bank error is a wavefront error: keep what is one
            step, z_step, frac = _wavefront_fit(step, cfg, uv, matrix)
            step = centred(step)
            explained.append(frac)
            if frac < MIN_EXPLAINED:
                break
        candidate = translate_psfs(psf0, total + step)
        fitted = _fit(candidate, y_win, d, opts, device)
        misfits.append(fitted[-1])
        if not fitted[-1] < misfit:  # the shifts do not explain the data better: keep the bank
            break
        total, current = total + step, candidate
        if z_step is not None:
            zsum = zsum + z_step
        op, pred, data, weight, misfit = fitted
    return Registration(current, total, history, misfits, op, zsum, explained)
