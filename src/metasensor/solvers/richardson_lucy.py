"""Incoherent synthetic aperture (ISA): phase-space Richardson–Lucy deconvolution of the views.

Hand-written (the authors' algorithm, Lu et al. Opt. Express 2019, on the sampled forward model
of :class:`metasensor.phasespace.operator.PhaseSpaceOperator`). Ordered-subset
Richardson–Lucy (OS-EM):

    I <- I · A_Sᵀ(y_S / A_S I) / A_Sᵀ(M)

for each subset S of views in turn (consecutive runs of the operator's views:
:func:`metasensor.phasespace.views.subset_major`). ``subsets = V`` is the authors' sequential
per-view update; ``subsets = 1`` the simultaneous (plain Richardson–Lucy) one. The normaliser
``A_Sᵀ(M)`` counts the observed samples only (the mask ``M``), so the unobserved margins of the
padded domain are estimated without ringing (Bertero & Boccacci's boundary treatment).

Non-negative by construction; every division is guarded (no NaN, no Inf): a predicted sample below
``eps`` (relative to the data's mean) counts as ``eps``; where the normaliser is below
:data:`SENS_FLOOR` of its maximum (pixels hardly any observed sample sees) the estimate is left
unchanged. The defaults' measurements: ``docs/decisions.md``.

With a Poisson–Gaussian ``noise_model`` (:mod:`metasensor.solvers.noise_model`, ``a > 0``) the
update is the shifted-Poisson form of Snyder, Hammoud & White (JOSA A 10, 1014–1023, 1993) for
read noise: ``y + c`` is treated as Poisson with mean ``A I + c``, ``c = b / a`` (data units),
i.e. the ratio is ``(y + c) / (A I + c)`` (samples below ``−c`` count as ``−c``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from metasensor.phasespace.operator import PhaseSpaceOperator
from metasensor.phasespace.views import subset_runs
from metasensor.solvers.noise_model import PoissonGaussian
from metasensor.solvers.result import SolveResult

__all__ = ["RLOptions", "richardson_lucy", "default_subsets", "DEFAULT_ITERATIONS",
           "DEFAULT_SUBSETS", "COARSE_STEP"]

DEFAULT_ITERATIONS = 5
DEFAULT_SUBSETS = 16
COARSE_STEP = 5  # scan steps (px) above this use the simultaneous update (default_subsets)
SENS_FLOOR = 1e-3  # normaliser floor, relative to its maximum (float32 FFT round-off below)


def default_subsets(step: int) -> int:
    """Subsets per iteration when none is asked for: :data:`DEFAULT_SUBSETS` for scan steps
    (pixels between a view's samples) up to :data:`COARSE_STEP`, else 1 (simultaneous)."""
    return DEFAULT_SUBSETS if int(step) <= COARSE_STEP else 1


@dataclass(frozen=True)
class RLOptions:
    """Settings of :func:`richardson_lucy` (frozen, validated).

    Attributes
    ----------
    iterations : int
        Passes over all views (>= 0; default 5).
    subsets : int
        View subsets per pass (1 = simultaneous, V = sequential; default 16); subset k is the
        k-th consecutive run of the operator's views.
    eps : float
        Smallest predicted sample, relative to the data's mean (default 1e-6).
    noise_model : PoissonGaussian or None
        The views' Poisson–Gaussian noise, ``a > 0``: the shifted-Poisson update (module
        docstring); None: plain Poisson.
    """

    iterations: int = DEFAULT_ITERATIONS
    subsets: int = DEFAULT_SUBSETS
    eps: float = 1e-6
    noise_model: PoissonGaussian | None = None

    def __post_init__(self) -> None:
        for name, low in (("iterations", 0), ("subsets", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        if not (isinstance(self.eps, int | float) and self.eps > 0 and math.isfinite(self.eps)):
            raise ValueError(f"eps must be a positive number, got {self.eps!r}")
        if self.noise_model is not None:
            if not isinstance(self.noise_model, PoissonGaussian):
                raise TypeError(f"noise_model must be a PoissonGaussian, got "
                                f"{type(self.noise_model).__name__}")
            if not self.noise_model.a > 0:
                raise ValueError("noise_model: Richardson-Lucy's shifted-Poisson form needs "
                                 "a > 0 (signal-dependent noise)")

    @property
    def shift(self) -> float:
        """The shifted-Poisson offset ``b / a`` (data units; 0 without a noise model)."""
        return 0.0 if self.noise_model is None else self.noise_model.shift

    @property
    def steps(self) -> int:
        """Progress ticks (one per iteration) a solve makes."""
        return self.iterations


def _sensitivities(op: PhaseSpaceOperator, maskf: torch.Tensor, runs: list[slice]):
    """Per subset: the normaliser A_Sᵀ(M) (ones where below the floor) and where it is valid."""
    sens = [op.sensitivity(maskf, g) for g in runs]
    valid = [s > SENS_FLOOR * float(s.max()) for s in sens]
    sens = [torch.where(v, s, torch.ones_like(s)) for s, v in zip(sens, valid, strict=True)]
    return sens, valid


def _subset_update(op: PhaseSpaceOperator, estimate, data, maskf, run: slice, floor: float,
                   shift: float = 0.0):
    """Back-projected ratio Aᵀ_S((y_S + c) / (A_S I + c)) of one subset (``data`` is y + c,
    c = ``shift``) and its squared residual."""
    spec = op.spectrum(estimate)
    acc = op.new_conj_accumulator()
    sq = 0.0
    for start in range(run.start, run.stop, op.chunk):
        c = slice(start, min(start + op.chunk, run.stop))
        pred = op.predict(spec, c)
        y = data[c]
        if shift:
            pred.add_(shift)
        resid = torch.sub(y, pred).mul_(maskf)
        sq += float(torch.vdot(resid.flatten(), resid.flatten()))
        ratio = torch.div(y, pred.clamp_(min=floor), out=pred).mul_(maskf)
        op.backproject_conj(ratio, c, acc)
    return op.image_from_conj(acc), sq


def richardson_lucy(op: PhaseSpaceOperator, y, mask, options: RLOptions = RLOptions(), *,
                    init=None, progress=None) -> SolveResult:
    """Ordered-subset Richardson–Lucy (module docstring) of the view samples ``y``.

    Parameters
    ----------
    op : PhaseSpaceOperator
        The forward model.
    y : array_like
        ``(V, My, Mx)`` view samples on the domain's sample grid (zero where unobserved), in the
        operator's view order; not modified (negative and NaN samples count as 0; with a
        noise model, samples below ``−b/a`` count as ``−b/a`` and NaN as 0).
    mask : array_like
        ``(My, Mx)`` bool, True on observed samples.
    options : RLOptions
        Iterations, subsets, eps.
    init : array_like, optional
        ``(Ny, Nx)`` start (clipped at 0); default: the flat image of the data's light.
    progress : callable, optional
        Called with 1 after each iteration.

    Returns
    -------
    SolveResult
        ``estimate`` ``(Ny, Nx)`` >= 0; ``history``: ``‖y − A I‖/‖y‖`` per iteration (for
        subsets > 1 each subset's residual is taken before its own update).
    """
    data, mask_t = op.samples_and_mask(y, mask)
    maskf = mask_t.to(torch.float32)
    shift = options.shift
    data = torch.clamp(torch.nan_to_num(data, nan=0.0), min=-shift) * maskf
    n_obs = max(float(maskf.sum()) * op.n_views, 1.0)
    floor = options.eps * max(float(data.sum()) / n_obs, 1e-30)
    data_norm = max(float(torch.linalg.vector_norm(data)), 1e-30)
    runs = subset_runs(op.n_views, options.subsets)
    sens, valid = _sensitivities(op, maskf, runs)
    if init is None:
        total = sum(float((s * v).sum()) for s, v in zip(sens, valid, strict=True))
        level = float(data.sum()) / max(total, 1e-30)
        estimate = torch.full(op.geometry.domain, max(level, floor), device=op.device)
    else:
        estimate = torch.clamp(torch.as_tensor(init, dtype=torch.float32, device=op.device),
                               min=0).clone()
    if shift:
        data = data + shift * maskf  # y + c
    history: list[float] = []
    for _ in range(options.iterations):
        sq = 0.0
        for run, s, v in zip(runs, sens, valid, strict=True):
            back, sq_run = _subset_update(op, estimate, data, maskf, run, floor, shift)
            sq += sq_run
            estimate = estimate * torch.where(v, torch.clamp(back, min=0.0) / s,
                                              torch.ones_like(s))
        history.append(math.sqrt(sq) / data_norm)
        if progress is not None:
            progress(1)
    return SolveResult(estimate, history)
