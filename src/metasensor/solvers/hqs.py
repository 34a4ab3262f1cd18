"""Phase-space ISA with an image prior: half-quadratic splitting on the phase-space operator.

Hand-written (no library solves a multi-view, sampled deconvolution with a prior). It extends
Krishnan & Fergus (NeurIPS 2009) from one convolution to the whole scanning light-field
measurement ``A`` of :class:`metasensor.phasespace.operator.PhaseSpaceOperator`:

    min_x  (λ/2)·‖A x − y‖²_M  +  R(L x)

with the loop of :func:`metasensor.solvers.splitting.half_quadratic_splitting` and a pluggable prior
(:mod:`metasensor.solvers.priors`; default the isotropic hyper-Laplacian ``Σ_p |∇x(p)|^(2/3)``). The
x-step (:class:`FoldedXStep`) is exact on a fully observed (circular) domain: AᵀA is block-diagonal
in the Fourier domain (:class:`metasensor.phasespace.normal.FoldedNormal`), and so is LᵀL, so it
costs two FFTs and a batched d² x d² product with the system's inverse (factored once per β).
Unobserved samples (the padded margins of a window) make it non-circular: it is then solved by
conjugate gradients preconditioned with the circular solve, warm-started from the previous x, with
the masked normal product of :mod:`metasensor.phasespace.masked_normal`.

Units and λ: the image is normalised to mean 0.5 (``x_n = x / (2·mean)``, the mean from the
data and the operator's sensitivity) and the prior sees it so. Unless given, λ =
``lam_scale / σ² · (d / 3)^e``, σ the larger of the views' noise (``noise`` where given, else
measured as ``noise_estimate`` says: :func:`estimate_noise` or the r.m.s. of the views' fitted
Poisson–Gaussian model, :mod:`metasensor.solvers.noise_fit`) and the r.m.s.
misfit of a nearly unregularised fit (the model error: PSF banks that do not match the data
must not get the weight of the noise); ``e`` (``scan_exponent``) scales the data's weight with
the scan step ``d`` (px) from that of the 5 x 5 scan (e = 2 keeps the data's weight per image
pixel, V / d² samples, constant). By default e and the misfit gate below follow the noise
measurement (``ESTIMATE_SETTINGS`` of :mod:`metasensor.solvers.hqs_options`): 2 and 1.1 with
the second differences, which texture and coarse samples raise and which these were chosen
with; 0.5 and 0.95 with a Poisson–Gaussian σ, which reads the noise alone. The start is
the smoothness-regularised least-squares fit (weight ``init_reg``; the prior is not convex, so
the start decides where it ends). The result is clipped at zero. Why each default is what it
is: ``docs/decisions.md``.

With a Poisson–Gaussian ``noise_model`` (:mod:`metasensor.solvers.noise_model`) the data term
is weighted least squares, ``‖A x − y‖²_{MW}`` with ``W = σ²/var`` (mean 1; var from the smooth
start's prediction, so the noise of the data does not bias the weights), and σ² the weights'
reference variance; the x-step is then never circular: PCG on ``AᵀMWA + μ(LᵀL + εI)``, still
preconditioned by the circular unweighted solve.

Model error (a bank that is an estimate, a wavefront or scene that moves during the scan) sits
where the scene has structure, not everywhere as noise does: where the nearly unregularised
fit's r.m.s. misfit exceeds ``misfit_weights`` (the gate) times the noise, the data term is
weighted by each sample position's own misfit in that fit, averaged over ``misfit_pool`` ×
``misfit_pool`` positions and floored at the fit's r.m.s. misfit
(:func:`metasensor.solvers.noise_model.misfit_weights`), as above: positions the model misses
get less than the global weight, none more (that fit absorbs part of the model error, so a
position's own misfit under-states it).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import torch

from metasensor.phasespace.masked_normal import BandNormal
from metasensor.phasespace.normal import FoldedNormal
from metasensor.phasespace.operator import PhaseSpaceOperator
from metasensor.solvers.hqs_options import HQSOptions
from metasensor.solvers.noise_fit import fitted_noise_rms, quiet_fit
from metasensor.solvers.noise_model import PoissonGaussian, misfit_weights, sample_weights
from metasensor.solvers.pcg import preconditioned_cg
from metasensor.solvers.priors import GRADIENT, Transform
from metasensor.solvers.result import SolveResult
from metasensor.solvers.splitting import half_quadratic_splitting

__all__ = ["HQSOptions", "hqs", "estimate_noise", "FoldedXStep"]

REG_FLOOR = 1e-4  # ε of the x-step, relative to LᵀL
MISFIT_REG = 1e-4  # smoothness weight of the fit whose misfit bounds the data weight
INIT_CG = 10  # CG iterations of the start where margins are unobserved
REF_STEP = 3  # scan step (px) of the 5 x 5 scan lam_scale was chosen on


def estimate_noise(data: torch.Tensor, mask: torch.Tensor) -> float:
    """Noise r.m.s. of view samples from their second differences.

    Parameters
    ----------
    data : torch.Tensor
        ``(V, My, Mx)`` view samples.
    mask : torch.Tensor
        ``(My, Mx)`` bool, True where observed (a difference needs its three samples observed).

    Returns
    -------
    float
        ``1.4826·MAD / sqrt(6)`` of the second differences along each sample axis, the two axes
        averaged (data units; 0 for views under 3 samples). Exact for white noise on smooth
        views (each sample integrates a whole lenslet); edges only add to it.
    """
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


def _noise(y: torch.Tensor, m: torch.Tensor, options: HQSOptions) -> tuple[float, str]:
    """The views' noise r.m.s. (data units) and how it was measured (``"differences"`` or
    ``"poisson-gaussian"``, the keys of ``ESTIMATE_SETTINGS``): ``noise`` where given (counted
    as the differences), else as ``noise_estimate`` says; a Poisson–Gaussian fit the views do
    not support falls back to :func:`estimate_noise`, with a warning for
    ``"poisson-gaussian"``, quietly for ``"auto"`` (also where the fit's lack of fit is too
    large: ``NoiseFit.holds``)."""
    if options.noise is not None:
        return float(options.noise), "differences"
    if isinstance(options.noise_estimate, PoissonGaussian):
        return options.noise_estimate.rms(y, m), "poisson-gaussian"
    if options.noise_estimate == "poisson-gaussian":
        try:
            return fitted_noise_rms(y, m), "poisson-gaussian"
        except ValueError as exc:
            warnings.warn(f"HQS noise: {exc}; using the second-difference estimate instead",
                          UserWarning, stacklevel=3)
    elif options.noise_estimate == "auto":
        fit = quiet_fit(y)
        if fit is not None and fit.holds():
            return fit.model.rms(y, m), "poisson-gaussian"
    return estimate_noise(y, m), "differences"



class FoldedXStep:
    """The x-step ``(AᵀMA + μ (LᵀL + ε I)) x = rhs`` of the phase-space operator.

    Circular and fully observed: exact, through the folded normal operator's inverse, factored
    once per μ. Masked, or ``exact`` False (``normal`` only approximates the operator's AᵀA, as
    for :class:`metasensor.phasespace.space_variant.SpaceVariantOperator`): at most ``cg``
    preconditioned conjugate-gradient iterations from the previous x (from the circular solve
    at the start), fewer once the residual is below ``tol`` times the right-hand side. ``mu``
    is absolute (the scale of AᵀA).
    """

    def __init__(self, normal: FoldedNormal, data_normal, mask: torch.Tensor,
                 transform: Transform, floor: float, cg: int, exact: bool = True,
                 tol: float = 0.0) -> None:
        self.nm, self.data_normal, self.transform = normal, data_normal, transform
        self.floor, self.cg, self.tol = float(floor), int(cg), float(tol)
        self.full = bool(mask.all()) and exact
        self.scale = normal.scale
        sym = transform.symbol(normal.geometry.domain, normal.device) + self.floor
        self.reg_fold = normal.fold(sym.to(torch.complex64)).real
        self._last: tuple[torch.Tensor, torch.Tensor] | None = None

    def reg(self, v: torch.Tensor) -> torch.Tensor:
        """v -> (LᵀL + ε I) v."""
        return self.transform.gram(v) + self.floor * v

    def system(self, mu: float) -> Callable[[torch.Tensor], torch.Tensor]:
        """v -> (AᵀMA + μ (LᵀL + ε I)) v."""
        return lambda v: self.data_normal(v) + mu * self.reg(v)

    def data_product(self, x: torch.Tensor) -> torch.Tensor | None:
        """``AᵀMA x`` for the tensor ``x`` this x-step returned last (masked solves), else
        None."""
        last = self._last
        return last[1] if last is not None and last[0] is x else None

    def carry(self, other: FoldedXStep) -> None:
        """Take ``other``'s last iterate and its ``AᵀMA x`` (same data term) as this one's."""
        self._last = other._last

    def at(self, mu: float):
        inv = self.nm.factor(mu / self.scale, self.reg_fold)

        def solve(rhs: torch.Tensor, x: torch.Tensor | None) -> torch.Tensor:
            if self.full:
                return self.nm.solve(rhs, inv)
            ax = None if x is None else self.data_product(x)
            x0 = self.nm.solve(rhs, inv) if x is None else x
            out, ax = preconditioned_cg(self.data_normal, self.reg, mu, rhs, x0, ax, inv,
                                        self.nm, self.cg, self.tol)
            self._last = (out, ax)
            return out

        return solve


def _residual_norm(op, x: torch.Tensor, ax: torch.Tensor | None, aty: torch.Tensor,
                   yn: torch.Tensor, mf: torch.Tensor, yy: float | None = None) -> float:
    """``‖M (A x − yn)‖`` (``yn`` zero where unobserved, ``aty`` = ``Aᵀ yn``): from ``ax`` =
    ``AᵀMA x`` when known, as ``sqrt(x·AᵀMAx − 2 x·Aᵀyn + ‖yn‖²)`` in double precision (no
    product; ``yy``: ``‖yn‖²`` when known), else directly."""
    if ax is None:
        return float(torch.linalg.vector_norm((op.forward(x) - yn) * mf))
    if yy is None:
        yy = float(torch.sum(yn.double() ** 2))
    xd = x.flatten().double()
    sq = (float(torch.dot(xd, ax.flatten().double())) - 2.0 * float(
        torch.dot(xd, aty.flatten().double())) + yy)
    return math.sqrt(max(sq, 0.0))


def _noise_weights(op, x, unit: float, m, options: HQSOptions):
    """The data term's per-sample weights (mean 1, zero where unobserved; None: all equal) and
    the noise σ they are relative to (data units; None: from ``noise`` or the data), from
    ``noise_model`` and the prediction of the start ``x`` (:func:`sample_weights`)."""
    if options.noise_model is None:
        return None, None
    weights, sigma2 = sample_weights(options.noise_model, op.forward(x) * unit, m)
    return weights, math.sqrt(sigma2)


def _misfit_weights(op, smooth: FoldedXStep, x, aty, y, m, unit: float, options: HQSOptions,
                    yy: float, noise_kind: tuple[float, str]):
    """Weights of the model's local misfit (module docstring) and their reference σ (data
    units), or (None, the noise σ (data units)) where the nearly unregularised fit (smoothness
    ``MISFIT_REG``) is within ``misfit_weights`` times the noise (that fit is not made where the
    smooth start ``x`` already is: it fits at least as closely, or where the weights are off:
    ``misfit_weights`` None); third, that fit where made. ``weights`` is ``(My, Mx)``: one per
    sample position, for every view. ``noise_kind``: the noise (data units) and its kind
    (:func:`_noise`)."""
    sigma, kind = noise_kind
    gate = options.data_weight_settings(kind)[1]
    if gate is None:
        return None, sigma, None
    mf = m.to(torch.float32)
    yn = y / unit
    noise = sigma / unit
    root_n = math.sqrt(max(float(mf.sum()) * yn.shape[0], 1.0))
    bound = gate * noise * root_n
    if not (noise > 0 and _residual_norm(op, x, smooth.data_product(x), aty, yn, mf, yy)
            > bound):
        return None, sigma, None
    fit = smooth.at(MISFIT_REG * smooth.scale)(aty, None)
    resid = op.forward(fit) - yn
    norm = float(torch.linalg.vector_norm(resid * mf))
    if not norm > bound:
        return None, sigma, fit
    # floored at the fit's r.m.s. misfit: the weights only ever lower the global one
    weights, sigma2 = misfit_weights(resid, m, max(noise, norm / root_n), options.misfit_pool)
    return weights, math.sqrt(sigma2) * unit, fit


def _weighted_normal(op, weights: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
    """v -> AᵀWA v, ``weights`` (V, My, Mx) or (My, Mx), zero where unobserved."""
    return lambda v: op.adjoint(op.forward(v) * weights)


def _data_weight(op: PhaseSpaceOperator, smooth: FoldedXStep, aty, y, m, unit: float,
                 options: HQSOptions, weights=None, sigma=None, start=None, yy=None,
                 fit=None, kind: str | None = None) -> float:
    """λ (module docstring): lam_scale / σ² · (d / 3)^e, σ = max(noise, model misfit); with
    ``weights``, the misfit is weighted and σ is the weights' reference σ.

    The misfit is that of the fit with smoothness weight ``MISFIT_REG``; a weaker smoothness
    weight fits the data at least as closely (the residual of a Tikhonov fit grows with its
    weight), so where the smooth ``start`` (weight ``init_reg``, its ``AᵀMA x`` carried by
    ``smooth``) already fits within the noise, that fit cannot raise σ and is not made.
    ``yy``: ``‖y / unit‖²`` when known; ``fit``: that fit when made already; ``kind``: how
    ``sigma`` was measured (:func:`_noise`; it sets e), measured here with it where either is
    None."""
    if options.lam is not None:
        return float(options.lam)
    mf = m.to(torch.float32)
    yn = y / unit
    if sigma is None or kind is None:
        measured, kind = _noise(y, m, options)
        sigma = measured if sigma is None else sigma
    n_obs = max(float(mf.sum()) * yn.shape[0], 1.0)
    misfit = 0.0
    if (fit is not None or weights is not None or start is None or _residual_norm(
            op, start, smooth.data_product(start), aty, yn, mf, yy) / math.sqrt(n_obs)
            > sigma / unit):
        if fit is None:
            fit = smooth.at(MISFIT_REG * smooth.scale)(aty, None)
        if weights is None:
            resid = _residual_norm(op, fit, smooth.data_product(fit), aty, yn, mf, yy)
        else:
            resid = float(torch.linalg.vector_norm((op.forward(fit) - yn) * weights.sqrt()))
        misfit = resid / math.sqrt(n_obs)
    sigma_n = max(sigma / unit, misfit, 1e-6 * float(yn[:, m].abs().mean()))
    e = options.data_weight_settings(kind)[0]
    lam = options.lam_scale / sigma_n**2 * (op.geometry.d / REF_STEP) ** e
    if not (lam > 0 and math.isfinite(lam)):
        raise ValueError(f"lam must be positive and finite, got {lam!r}")
    return lam


def hqs(op: PhaseSpaceOperator, y, mask, options: HQSOptions = HQSOptions(), *,
        progress: Callable[[int], None] | None = None) -> SolveResult:
    """Phase-space ISA with a prior (module docstring) of the view samples ``y``.

    Parameters
    ----------
    op : PhaseSpaceOperator or SpaceVariantOperator
        The forward model; its folded normal operator is built here.
    y : array_like
        ``(V, My, Mx)`` view samples on the operator's sample grid (zero where unobserved), in
        the operator's view order; not modified.
    mask : array_like
        ``(My, Mx)`` bool, True on observed samples.
    options : HQSOptions
        Prior, λ and the loop's settings.
    progress : callable, optional
        Called with 0 once the set-up is done (before the first β), then with 1 after each β.

    Returns
    -------
    SolveResult
        ``estimate`` ``(Ny, Nx)`` on the operator's domain, non-negative, in data units, and
        ``history``: the relative residual ``‖y − A x‖/‖y‖`` over observed samples after each β.
    """
    y, m = op.samples_and_mask(y, mask)
    mf = m.to(torch.float32)
    y = torch.nan_to_num(y) * mf
    level = float(y.sum()) / max(float(op.sensitivity(mf).sum()), 1e-30)  # mean of the image
    if not level > 0:
        return SolveResult(torch.zeros(op.geometry.domain, device=op.device), [])
    unit = 2.0 * level  # image normalised to mean 0.5
    yn = y / unit
    nm = op.normal()
    data_normal = op.masked_normal(m, nm)
    exact = bool(getattr(op, "normal_is_exact", True))
    smooth = FoldedXStep(nm, data_normal, m, GRADIENT, REG_FLOOR, INIT_CG, exact,
                         options.cg_tol)
    aty = op.adjoint(yn)
    if options.noise_model is None and isinstance(data_normal, BandNormal):
        op.drop_spectra()  # from here on only the folded AᵀA and the bands' operators apply
    x = smooth.at(options.init_reg * smooth.scale)(aty, None)  # the smooth start
    yy = float(torch.sum(yn.double() ** 2))
    weights, sigma = _noise_weights(op, x, unit, m, options)
    fit, kind = None, "differences"
    if weights is None and sigma is None:
        noise_kind = _noise(y, m, options)
        kind = noise_kind[1]
        weights, sigma, fit = _misfit_weights(op, smooth, x, aty, y, m, unit, options, yy,
                                              noise_kind)
    loop_aty = aty
    if weights is None:
        xstep = FoldedXStep(nm, data_normal, m, options.prior.transform, REG_FLOOR, options.cg,
                            exact, options.cg_tol)
        xstep.carry(smooth)  # the start's AᵀMA x: the first x-step needs no product for it
    else:  # weighted least squares: PCG on AᵀMWA, the folded AᵀA its preconditioner
        xstep = FoldedXStep(nm, _weighted_normal(op, weights), m, options.prior.transform,
                            REG_FLOOR, options.cg, exact=False, tol=options.cg_tol)
        loop_aty = op.adjoint(yn * weights)
    lam = _data_weight(op, smooth, aty, y, m, unit, options, weights, sigma, start=x, yy=yy,
                       fit=fit, kind=kind)
    norm_y = max(float(torch.linalg.vector_norm(yn)), 1e-30)
    history: list[float] = []

    def on_beta(xb: torch.Tensor) -> None:
        ax = xstep.data_product(xb) if weights is None else None  # unweighted residual
        history.append(_residual_norm(op, xb, ax, aty, yn, mf, yy) / norm_y)
        if progress is not None:
            progress(1)

    if progress is not None:
        progress(0)  # the set-up is done: what a caller gates on the set-up may go on
    x = half_quadratic_splitting(x, loop_aty, xstep, options.prior, lam,
                                 options.continuation.betas(), options.inner, on_beta)
    return SolveResult(torch.clamp(x, min=0.0) * unit, history)
