"""ISA with a hyper-Laplacian image prior: half-quadratic splitting on the phase-space operator.

Hand-written (no library solves a multi-view, sampled deconvolution with a sparse-gradient
prior). It extends Krishnan & Fergus (NeurIPS 2009; :mod:`metasensor.solvers.krishnan_fergus`, the
per-view deconvolution of DAO) from one convolution to the whole scanning light-field
measurement ``A`` of :class:`metasensor.phasespace.operator.PhaseSpaceOperator`:

    min_x  (lam/2)·||A x − y||²  +  Σ |∇x|^alpha

split with auxiliary gradients w and a weight beta raised from ``beta0`` to ``beta_max``:

    w-step: w = argmin |w|^alpha + (beta/2)(w − ∇x)²     (closed form, element-wise)
    x-step: (AᵀA + (beta/lam)·∇ᵀ∇) x = Aᵀy + (beta/lam)·∇ᵀw

The x-step is exact: AᵀA is block-diagonal in the Fourier domain (:class:`FoldedNormal`), and so
is ∇ᵀ∇, so it costs two FFTs and a batched d² x d² product with the system's inverse (factored
once per beta).

Why: Richardson–Lucy stops at what the data determine. 70 % of AᵀA's eigenvalues are below
1e-4 of the largest for a 5 x 5 scan, so at 30 dB even the best *linear* reconstruction reaches
SSIM 0.56 (chart) / 0.66 (natural image) (``benchmarks/bench_isa_limit.py``). The sparse-gradient
prior fills those directions with edges instead of noise. Measured on simulated 192-px captures
(inverse-crime free), 30 dB: SSIM 0.907 (chart) / 0.779 (camera) against Richardson–Lucy's
0.516 / 0.671. Before the start and model-error changes below (not re-measured since): astronaut
0.793 (lam_scale 0.4, RL 0.646); 20 dB 0.846 / 0.728 (RL 0.491 / 0.560); 40 dB 0.941 / 0.817
(RL 0.519 / 0.689). Cost at 2,010 x 2,010 px, 2 cores: 153 s, 8.1x Richardson–Lucy's 5
iterations (6.8 GB peak memory): 120 folded solves, 118 masked normal products, 9 forward calls.
The masked normal products go through the folded normal operator and two margin bands
(:mod:`metasensor.phasespace.masked_normal`, exact): before, each was a full forward and
adjoint, and
the run took 383 s (21x RL; 444 s before the solves used the precomputed inverse). What remains is
no longer FFTs (28.6 s of them, ratio 5.4): the d² x d² products, the fold copies and the
factorisations (2.5 s per beta). The gain grows with the window: 300 px 7.0 -> 6.4 s (21x RL),
600 px 23.2 -> 14.0 s (11x), 1,005 px 67.5 -> 32.3 s (10x); windows whose bands would cover more
than 70 % of the domain keep the direct product. Across scenes and sizes with the contract call
(``bench_isa_quality``, 30 dB): chart 0.757 / 0.907 / 0.922 / 0.944 / 0.953 at 105 / 180 / 240 /
360 / 495 px (its bar periods are fixed in pixels, so a small chart is denser); natural images
0.66-0.885, where the capture's own noisy 2D sensor reads 0.81-0.90 (0.86-0.95 after the best
oracle-tuned TV / non-local-means denoising; camera 0.86-0.88). Non-local means as a
plug-and-play prior in place of the gradient shrinkage reached 0.72-0.75 on the 180-px camera.

Aberrated and mismatched banks (the prior is not convex, so the start matters; see INIT_REG and
MISFIT_REG; a bank whose views are shifted against the data, as a defocus error makes them, is
fixed before this solver by :mod:`metasensor.dao.bank_registration`,
``reconstruct(register=True)``): a ~1.4 λ r.m.s. block (defocus, astigmatism, coma; camera,
30 dB) reaches PSNR 26.2 dB (Richardson–Lucy 24.0 dB); a window whose margins hold a
neighbouring block's aberration 24.8 dB (RL 22.6 dB); multisite 4 x 4 blocks with up to 1.8 λ
24.36 dB, 3.44 dB above one global PSF (RL: 24.11 dB, 3.27 dB). Before both fixes these were
14.6 dB, −5.5 dB and −5.9 dB.

Data weight: ``lam = lam_scale / sigma² · (d / 3)²`` on the image normalised to mean 0.5 (d the
scan step: the samples per pixel, V / d², then weigh the same against the prior at every scan),
with sigma the larger of the views' noise (:func:`estimate_noise` unless given) and the misfit of
a nearly unregularised fit (model error, MISFIT_REG).
Unobserved samples (the padded margins of a window) make the x-step non-circular: it is then solved
by conjugate gradients preconditioned with the circular solve (:func:`_pcg`, ``cg`` iterations from
the previous x; on a padded chart window 0.917 vs 0.920 for the fully observed problem, where
filling the margins with the prediction once per beta reached 0.650). The result is clipped at zero
(flux stays within 1 %: measured 0.996-1.001).
"""

from __future__ import annotations

import math

import torch

from metasensor.phasespace.masked_normal import masked_normal
from metasensor.phasespace.normal import FoldedNormal, difference_weights
from metasensor.phasespace.operator import PhaseSpaceOperator
from metasensor.solvers.krishnan_fergus import beta_schedule, solve_w_table
from metasensor.solvers.richardson_lucy import RLResult

__all__ = ["estimate_noise", "hyper_laplacian_isa", "continuation_steps", "DEFAULT_LAM_SCALE"]

# lam·sigma² on the mean-0.5 image, sigma from estimate_noise. Measured on simulated captures
# (192-px chart, camera, astronaut; 20/30/40 dB), SSIM for lam_scale 0.1 / 0.2 / 0.3 / 0.4 / 1:
# the optimum lies at 0.3-0.4 at every SNR (30 dB chart 0.869 / - / 0.901 / - / 0.888, camera
# 0.754 / - / 0.778 / - / 0.632). Too large a lam collapses (under-regularised: the near-null
# directions fill with noise) while too small degrades gently, so the default keeps a 3x margin.
DEFAULT_LAM_SCALE = 0.3
DEFAULT_BETA_MAX = 4096.0
# x-steps per beta and CG iterations per x-step: (3, 3) measured against (2, 2), (1, 3), (2, 1):
# 30 dB chart SSIM 0.901 vs 0.881 / 0.702 / 0.695 (the cheaper ones leave the borders unsolved)
DEFAULT_INNER = 3
DEFAULT_CG = 3
REG_FLOOR = 1e-4
# The prior is not convex (alpha < 1), so where HQS starts decides where it ends. Starting from
# the least-squares solve of the first beta (weight beta0/lam, ~1e-4 of AᵀA's largest eigenvalue)
# fills the weakly observed border pixels with noise that the w-step then keeps as edges: an
# aberrated block (~1.4 λ, camera, 30 dB) reached 14.6 dB PSNR, its outer 10 pixels at 0.3-0.6
# of the range r.m.s. error (its interior 24.6 dB). Starting from the smoothness-regularised
# solve with weight INIT_REG (relative to that eigenvalue; 1e-3 / 1e-2 / 1e-1: 26.19 / 26.20 /
# 26.20 dB) gives 26.2 dB (Richardson–Lucy 24.0) and chart / camera SSIM 0.907 / 0.779.
INIT_REG = 1e-2
# Model error. Where the PSF bank does not match the data (a calibration error, a neighbouring
# block's aberration reaching into the window), a data weight set by the noise alone makes the
# solution explode: a 168-px corner window of a 4 x 4 field-dependent capture (true aberration in
# its core only) fit to 8.8 % residual where the noise is 2.7 %, and reached PSNR −5.5 dB
# (Richardson–Lucy 22.6 dB). The data weight therefore uses max(noise, misfit), the misfit being
# the r.m.s. residual of the least-squares fit with smoothness weight MISFIT_REG (about the noise
# where the bank matches: 0.8-1.04 x the noise estimate on the chart, camera and an aberrated
# block at 30 dB; 3.2 x on that window, which then reaches 24.8 dB). Noise-free data keep their
# weight (the fit's bias is small: SSIM 0.99 on model-exact data).
MISFIT_REG = 1e-4
# CG iterations of that start where margins are unobserved (0 / 3 / 10: chart 0.898 / 0.902 / 0.907)
INIT_CG = 10
REF_STEP = 3  # scan step (px) of the 5 x 5 scan lam_scale was measured on


def estimate_noise(data: torch.Tensor, mask: torch.Tensor) -> float:
    """Noise r.m.s. of view samples (V, My, Mx), from the median absolute value of their second
    differences (the views are smooth on their sample grid because each sample integrates a whole
    lenslet): sigma = 1.4826·MAD / sqrt(6) per axis, the two axes averaged. Exact on flat views
    (1.002x); edges only add to it: a dense chart reads 1.1x / 1.75x / 4.2x at 20 / 30 / 40 dB
    (white noise). With photon noise (signal-dependent) the median reads the typical sample, not
    the r.m.s.: simulated 30 dB captures read 1.09x (chart) and 0.85x (camera) of the true r.m.s.;
    :func:`hyper_laplacian_isa`'s model-error floor (MISFIT_REG) lifts the low reading."""
    m = mask.to(torch.bool)
    out = []
    for axis in (0, 1):  # axis of the (My, Mx) sample grid
        n = data.shape[axis + 1]
        if n < 3:
            continue
        sec = (data.narrow(axis + 1, 0, n - 2) - 2 * data.narrow(axis + 1, 1, n - 2)
               + data.narrow(axis + 1, 2, n - 2))
        ok = m.narrow(axis, 0, n - 2) & m.narrow(axis, 1, n - 2) & m.narrow(axis, 2, n - 2)
        vals = sec[:, ok]
        if vals.numel():
            out.append(float(vals.abs().median()) * 1.4826 / math.sqrt(6.0))
    return float(sum(out) / len(out)) if out else 0.0


def continuation_steps(beta0: float = 1.0, beta_max: float = DEFAULT_BETA_MAX, **_) -> int:
    """Number of betas (residuals, progress ticks) :func:`hyper_laplacian_isa` runs with these
    keyword arguments (the others are ignored)."""
    return len(beta_schedule(beta0, beta_max))


def _grad(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    return torch.roll(x, -1, 0) - x, torch.roll(x, -1, 1) - x


def _grad_t(wy: torch.Tensor, wx: torch.Tensor) -> torch.Tensor:
    return (torch.roll(wy, 1, 0) - wy) + (torch.roll(wx, 1, 1) - wx)


def _pcg(normal, rhs, x, inv, nm: FoldedNormal, iterations: int) -> torch.Tensor:
    """Conjugate gradients on ``normal(x) = rhs`` from ``x``, preconditioned by the circular,
    fully observed system (``nm.solve`` with ``inv``), which differs from it only by the
    unobserved samples: a few iterations suffice."""
    r = rhs - normal(x)
    z = nm.solve(r, inv)
    p = z
    rz = float(torch.vdot(r.flatten(), z.flatten()))
    for _ in range(iterations):
        q = normal(p)
        pq = float(torch.vdot(p.flatten(), q.flatten()))
        if not pq > 0:
            break
        a = rz / pq
        x = x + a * p
        r = r - a * q
        z = nm.solve(r, inv)
        rz_new = float(torch.vdot(r.flatten(), z.flatten()))
        p = z + (rz_new / rz) * p if rz > 0 else z
        rz = rz_new
    return x


def _smooth_least_squares(nm: FoldedNormal, aty, normal, reg, weight: float,
                          full: bool) -> torch.Tensor:
    """argmin ||A x − y||²_mask + weight·scale·||∇x||² (scale: AᵀA's largest diagonal), circular
    solve then :data:`INIT_CG` preconditioned CG steps where margins are unobserved; ``normal``
    applies that system with the mask, ``reg`` is its circular regulariser."""
    inv = nm.factor(weight, reg)
    x = nm.solve(aty, inv)
    if not full:
        x = _pcg(normal, aty, x, inv, nm, INIT_CG)
    return x


def hyper_laplacian_isa(op: PhaseSpaceOperator, psf, data, mask, lam: float | None = None,
                        alpha: float = 2.0 / 3.0, noise: float | None = None,
                        lam_scale: float = DEFAULT_LAM_SCALE, beta0: float = 1.0,
                        beta_max: float = DEFAULT_BETA_MAX, inner: int = DEFAULT_INNER,
                        cg: int = DEFAULT_CG, init_reg: float = INIT_REG,
                        progress=None) -> RLResult:
    """Sparse-gradient ISA (module docstring) of ``data`` (V, My, Mx) observed where ``mask``.

    psf : the operator's bank (V, K, K) (for the folded normal operator). lam : data weight on the
    mean-0.5 image (default ``lam_scale / sigma² · (d / 3)²``). noise : the views' noise r.m.s.
    in data units (default: :func:`estimate_noise`; the model-error floor applies either way).
    init_reg : smoothness weight of the start (INIT_REG). Returns the estimate (Ny, Nx),
    non-negative, and the relative residual ||y − A x||/||y|| (observed samples) after each beta.
    """
    if alpha != 1.0 and abs(alpha - 2.0 / 3.0) > 1e-9:
        raise ValueError(f"alpha must be 2/3 or 1, got {alpha!r}")
    if inner < 1:
        raise ValueError(f"inner must be >= 1, got {inner}")
    y, m = op.samples_and_mask(data, mask)
    mf = m.to(torch.float32)
    y = torch.nan_to_num(y) * mf
    nm = FoldedNormal(op, psf)
    sens = op.sensitivity(mf)
    level = float(y.sum()) / max(float(sens.sum()), 1e-30)  # mean of the image
    if not level > 0:
        return RLResult(torch.zeros(op.geometry.domain, device=op.device), [])
    unit = 2.0 * level  # image normalised to mean 0.5: x_n = x / unit
    yn = y / unit
    if not init_reg > 0:
        raise ValueError(f"init_reg must be > 0, got {init_reg!r}")
    scale = float(nm.matrix.diagonal(dim1=-2, dim2=-1).real.max())
    reg = difference_weights(nm, floor=REG_FLOOR)
    full = bool(m.all())
    norm_y = max(float(torch.linalg.vector_norm(yn)), 1e-30)
    aty = op.adjoint(yn)

    data_normal = masked_normal(op, nm, psf, m)  # AᵀMA, cheap on padded windows

    def normal_at(mu: float):  # (AᵀMA + mu·L) v, L = ∇ᵀ∇ + floor (what factor() inverts without M)
        return lambda v: data_normal(v) + mu * (_grad_t(*_grad(v)) + REG_FLOOR * v)

    # start from a smooth least-squares estimate (see INIT_REG)
    x = _smooth_least_squares(nm, aty, normal_at(init_reg * scale), reg, init_reg, full)
    if lam is None:
        sigma = estimate_noise(y, m) if noise is None else float(noise)
        # noise and model error (see MISFIT_REG): the misfit of a nearly unregularised fit
        fit = _smooth_least_squares(nm, aty, normal_at(MISFIT_REG * scale), reg, MISFIT_REG,
                                    full)
        n_obs = max(float(mf.sum()) * yn.shape[0], 1.0)
        misfit = float(torch.linalg.vector_norm((op.forward(fit) - yn) * mf)) / math.sqrt(n_obs)
        del fit
        sigma_n = max(sigma / unit, misfit, 1e-6 * float(yn[:, m].abs().mean()))
        # per image pixel the data hold V / d² samples: keep their weight against the prior's
        # that of the 5 x 5 scan (d = 3) the default was measured on
        lam = lam_scale / sigma_n**2 * (op.geometry.d / REF_STEP) ** 2
    if not (lam > 0 and math.isfinite(lam)):
        raise ValueError(f"lam must be positive and finite, got {lam!r}")
    history: list[float] = []
    for beta in beta_schedule(beta0, beta_max):
        mu = beta / lam
        inv = nm.factor(mu / scale, reg)
        normal = normal_at(mu)
        for _ in range(inner):
            gy, gx = _grad(x)
            rhs = aty + mu * _grad_t(solve_w_table(gy, beta, alpha), solve_w_table(gx, beta, alpha))
            x = nm.solve(rhs, inv) if full else _pcg(normal, rhs, x, inv, nm, cg)
        res = (op.forward(x) - yn) * mf
        history.append(float(torch.linalg.vector_norm(res)) / norm_y)
        if progress is not None:
            progress(1)
    return RLResult(torch.clamp(x, min=0.0) * unit, history)
