"""View registration before ISA: each view's sub-pixel shift against the model, put into its PSF.

Hand-written (no library registers views through a phase-space forward model). Per round:

1. I = phase-space Richardson–Lucy of all views with the current bank (5 iterations, 16 subsets:
   it blurs rather than invents, so its predictions carry little of the model error);
2. s_uv = shift of the measured view V_uv against its prediction S_d(I ⊛ H_uv)
   (:func:`metasensor.align.shifts.measure_shifts_torch`, observed samples only), in pixels,
   less their light-weighted mean (a shift common to all views is the image's position);
3. with the system known (``cfg``, ``uv``; what ``reconstruct`` passes): s_uv is replaced by its
   fit with the gradients of a wavefront error (Noll 4-21, :mod:`metasensor.dao.wavefront`,
   the DAO wavefront sensor's model), since a bank that is off is a wavefront that is off; a round
   whose fit explains less than MIN_EXPLAINED of the shifts' variance is not a wavefront error
   and ends the registration (with fewer than MIN_FIT_VIEWS views the shifts go unfitted);
4. H_uv ← the round-0 H_uv translated by the accumulated s_uv (Fourier shift, energy kept),
   accepted only if the Richardson–Lucy fit with it leaves a smaller misfit ||y − A I||.

Stop when a round's r.m.s. shift is below ``tol_px`` (that step is not applied), a round is not
a wavefront error, a candidate is rejected, or after ``rounds`` rounds. ``Registration.zernike``
is the wavefront the applied shifts amount to (the bank's error with the opposite sign: a bank
with 0.05 / 0.1 / 0.2 λ too much defocus reads Z4 = −0.055 / −0.101 / −0.198 λ).

Why: the sparse-gradient solver (:mod:`metasensor.solvers.hqs`) resolves detail the views determine
only through the exact PSFs, so it is fragile where the bank is slightly wrong. Such errors shift
views: a 0.05 λ r.m.s. defocus error already moves the outer views by ~0.8 px (measured below:
0.43 px r.m.s. over the 113 views), which is what an object 0.05 λ off the assumed focus, or an
aberration estimate that far off, gives. Measured (``benchmarks/bench_isa_mismatch.py``: 192-px
captures, aberration-free, 30 dB; the bank with a defocus error of 0 / 0.025 / 0.05 / 0.1 /
0.2 λ; HQS SSIM with / without registration):

* chart 0.907 / 0.907, 0.898 / 0.888, 0.887 / 0.690, 0.874 / 0.313, 0.838 / 0.643
  (Richardson–Lucy 0.516, 0.511, 0.500, 0.474, 0.457);
* camera 0.779 / 0.779, 0.778 / 0.768, 0.777 / 0.714, 0.766 / 0.530, 0.759 / 0.571
  (Richardson–Lucy 0.671, 0.667, 0.659, 0.636, 0.628).

Rounds measured 0.43 -> 0.069 -> 0.019 px r.m.s. (0.05 λ) and 1.75 -> 0.036 -> 0.017 px (0.2 λ);
a right bank reads 0.014-0.036 px and is left as it is. Cost: one Richardson–Lucy fit
(5 iterations) per applied round plus one; the registered solve averaged 9.0 s against HQS's
6.7 s over the benchmark's 192-px cases (+35 %). The 384-px demo (``make demo``, which
registers) moved from SSIM 0.816 to 0.831 (0.830 with the wavefront fit, PSNR 16.83 dB); its
4 x 4 variant, whose blocks sit between the simulator's 3 x 3 field samples, from PSNR 11.0 to
17.0 dB. What registration cannot fix is a change of the PSFs' shape beyond a shift, and
shifts that vary within a block (depth edges, a field aberration that changes across the block).

Opt-in (``reconstruct(register=True)``, ``metasensor reconstruct --register``). On strongly
aberrated multisite blocks (4 x 4, up to 1.8 λ) with their *true* banks it measures 1.2-24 px
r.m.s. of shifts that lower the Richardson–Lucy misfit but not HQS's error. The wavefront fit
stops the three largest (12-24 px; explained 0.44-0.59) but 0.77-0.98 of the others are a
wavefront's (0.1-0.5 λ). Local PSNR 24.36 -> 24.24 dB (23.71 with unconstrained shifts), one
global bank 20.91 -> 21.54 dB (21.77), so the 4 x 4 multisite gain with registration on both is
2.70 dB (1.94; 3.44 with it off). Where the bank is known to be right (calibrated, or DAO's
estimate), leave it off.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from metasensor.align.shifts import fourier_shift, measure_shifts_torch
from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
from metasensor.solvers.richardson_lucy import richardson_lucy

__all__ = ["translate_psfs", "register_views", "Registration", "DEFAULT_ROUNDS",
           "WAVEFRONT_MODES", "MIN_EXPLAINED", "MIN_FIT_VIEWS"]

DEFAULT_ROUNDS = 3  # measured: 0.43 -> 0.069 -> 0.019 px (0.05 λ error); 1.75 -> 0.036 -> 0.017
DEFAULT_TOL_PX = 0.02  # a round below this r.m.s. shift ends the registration
# With the system (cfg, uv) the measured shifts are fitted by the gradients of a wavefront error
# (Noll modes 4-21, :mod:`metasensor.dao.wavefront`) and the fit is applied: a bank error is a
# wavefront error, so its shifts are a gradient field. Fraction of the shifts' variance the fit
# explains, measured on the first round: defocus errors of 0.05 / 0.1 / 0.2 λ (192 px, chart and
# camera, 30 dB) 0.99-1.00, recovering 0.048 / 0.095 / 0.195 λ; the noise of a right bank
# 0.09-0.17 (below tol_px anyway); the 4 x 4 multisite blocks (true banks, up to 1.8 λ) 0.77-0.98,
# and 0.44-0.59 on the three whose measurement failed (12-24 px r.m.s.). A round explaining less
# than MIN_EXPLAINED ends the registration with the bank as it is.
WAVEFRONT_MODES = tuple(range(4, 22))
MIN_EXPLAINED = 0.7
MIN_FIT_VIEWS = 30  # 2 x 30 shift components for 18 modes + 2 common: fewer, no fit


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
                     jmax=max(WAVEFRONT_MODES), min_footprint=0.0)
    rows, cols = (list(a) for a in zip(*uv, strict=True))
    smooth = predicted_shifts(fit.zernike, cfg, matrix=matrix)[rows, cols]
    total = float((step - step.mean(dim=0)).pow(2).sum(dim=1).mean())
    explained = 1.0 - fit.residual_rms**2 / total if total > 0 else 0.0
    return torch.from_numpy(smooth), fit.zernike, explained


def register_views(psf, data_win, d: int, device=None, rounds: int = DEFAULT_ROUNDS,
                   tol_px: float = DEFAULT_TOL_PX, max_shift_px: float | None = None,
                   iterations: int = 5, subsets: int = 16, pad: bool = True, cfg=None,
                   uv=None) -> Registration:
    """Register the views ``data_win (V, Sy, Sx)`` (a window of view samples every ``d`` px)
    against the bank ``psf (V, K, K)`` (module docstring). ``max_shift_px`` bounds each round's
    shift (default: a third of the window's smaller side in pixels, at most 50 px). With the
    system ``cfg`` and the views' ``uv`` indices (one per bank row), each round's shifts are
    replaced by their wavefront-error fit (:data:`WAVEFRONT_MODES`), and a round whose fit
    explains less than :data:`MIN_EXPLAINED` of them ends the registration."""
    psf0 = torch.as_tensor(psf, dtype=torch.float32, device="cpu")  # moved where used
    y_win = torch.as_tensor(data_win, dtype=torch.float32, device="cpu")
    if psf0.ndim != 3 or y_win.ndim != 3 or psf0.shape[0] != y_win.shape[0]:
        raise ValueError(f"psf (V, K, K) and data_win (V, Sy, Sx) must agree in V, got "
                         f"{tuple(psf0.shape)} and {tuple(y_win.shape)}")
    if rounds < 0:
        raise ValueError(f"rounds must be >= 0, got {rounds}")
    matrix = None
    if (cfg is None) != (uv is None):
        raise ValueError("register_views needs both cfg and uv (or neither)")
    if cfg is not None:
        from metasensor.dao.wavefront import gradient_matrix

        if len(uv) != psf0.shape[0]:
            raise ValueError(f"uv lists {len(uv)} views, the bank holds {psf0.shape[0]}")
        # the fit needs views to spare: with fewer than MIN_FIT_VIEWS the shifts go unfitted
        if len(uv) >= MIN_FIT_VIEWS:
            matrix = gradient_matrix(cfg, jmax=max(WAVEFRONT_MODES))
    zsum = np.zeros(max(WAVEFRONT_MODES)) if matrix is not None else None
    explained: list[float] = []
    if max_shift_px is None:
        max_shift_px = min(50.0, min(y_win.shape[-2:]) * d / 3.0)
    light = psf0.sum(dim=(-2, -1)).to(torch.float64).cpu()

    def centred(s):  # a shift common to all views is the image's position, which the views
        # cannot tell from the bank's: keep the bank's (an offset of 0.78 px crept in without)
        return s - (light[:, None] * s).sum(dim=0) / light.sum()

    def fit(bank):  # operator, its predictions of the RL estimate, data, weights, rel. misfit
        geometry = make_geometry(tuple(y_win.shape[-2:]), d, bank.shape[-1] // 2, pad=pad)
        op = PhaseSpaceOperator(bank, geometry, device=device)
        data, mask = geometry.embed(y_win.to(op.device))
        estimate = richardson_lucy(op, data, mask, iterations=iterations,
                                   subsets=min(subsets, psf0.shape[0])).estimate
        pred = op.forward(estimate)
        m = mask.to(pred.dtype)[None]
        misfit = float(torch.linalg.vector_norm((pred - data) * m))
        return op, pred, data, m.expand_as(pred), misfit / max(
            float(torch.linalg.vector_norm(data)), 1e-30)

    total = torch.zeros((psf0.shape[0], 2), dtype=torch.float64, device="cpu")
    current = psf0
    op, pred, data, weight, misfit = fit(current)
    history: list[float] = []
    misfits = [misfit]
    for _ in range(rounds):
        step = measure_shifts_torch(pred, data, weight=weight, max_shift=max_shift_px / d)
        step = centred(step.cpu() * d)
        rms = float(step.pow(2).sum(dim=1).mean().sqrt())
        history.append(rms)
        if rms < tol_px:  # registered: a step this small changes nothing worth a fit
            break
        z_step = None
        if matrix is not None:  # a bank error is a wavefront error: keep what is one
            step, z_step, frac = _wavefront_fit(step, cfg, uv, matrix)
            step = centred(step)
            explained.append(frac)
            if frac < MIN_EXPLAINED:
                break
        candidate = translate_psfs(psf0.to(pred.device), total + step)
        fitted = fit(candidate)
        misfits.append(fitted[-1])
        if not fitted[-1] < misfit:  # the shifts do not explain the data better: keep the bank
            break
        total, current = total + step, candidate
        if z_step is not None:
            zsum = zsum + z_step
        op, pred, data, weight, misfit = fitted
    return Registration(current, total, history, misfits, op, zsum, explained)

