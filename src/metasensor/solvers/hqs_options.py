"""Settings of the half-quadratic-splitting solver (:func:`metasensor.solvers.hqs.hqs`): a frozen,
validated option object; the model each setting enters is described in
:mod:`metasensor.solvers.hqs`."""

from __future__ import annotations

import math
from dataclasses import dataclass

from metasensor.solvers.noise_model import PoissonGaussian
from metasensor.solvers.priors import HyperLaplacian, Prior
from metasensor.solvers.splitting import Continuation

__all__ = ["HQSOptions", "NOISE_ESTIMATES", "ESTIMATE_SETTINGS", "NOISELESS_CG_TOL"]

NOISE_ESTIMATES = ("differences", "poisson-gaussian", "auto")
#: per kind of noise measurement, the data weight's (scan exponent e, misfit gate) where
#: ``scan_exponent`` / ``misfit_weights`` are ``"auto"``: the second differences read texture
#: and coarse samples as noise, and e = 2 and the gate 1.1 were chosen with that bias; a
#: Poisson–Gaussian σ (fitted, or a model given) reads the noise alone (docs/decisions.md). A
#: given ``noise`` keeps the first pair.
ESTIMATE_SETTINGS = {"differences": (2.0, 1.1), "poisson-gaussian": (0.5, 0.95)}
#: ``cg_tol`` of a capture without measurable noise (at most; where the noise is measured from
#: the views, :func:`metasensor.recon.noise.capture_noise`):
#: the default tolerance sits at float32's floor of the x-step's products, which noise hides
#: and noise-free views do not (docs/decisions.md)
NOISELESS_CG_TOL = 1e-5


@dataclass(frozen=True)
class HQSOptions:
    """Settings of :func:`~metasensor.solvers.hqs.hqs` (frozen, validated).

    Attributes
    ----------
    prior : Prior
        The image prior (:mod:`metasensor.solvers.priors`); default the isotropic
        hyper-Laplacian (gradient magnitude), alpha 2/3.
    lam : float or None
        λ, the data weight on the mean-0.5 image; None: from the noise and the model error
        (module docstring).
    lam_scale : float
        λ·σ² when λ is derived (default 0.3).
    noise : float or None
        The views' noise r.m.s. in data units; None: measured as ``noise_estimate`` says.
    noise_estimate : {"differences", "poisson-gaussian", "auto"} or PoissonGaussian
        How the noise is measured where ``noise`` is None: ``"differences"`` (default), the
        second differences' median absolute deviation
        (:func:`~metasensor.solvers.hqs.estimate_noise`), which texture and coarse samples
        raise; ``"poisson-gaussian"``, the r.m.s. of the Poisson–Gaussian model fitted to the
        solved samples' smooth parts (:func:`~metasensor.solvers.noise_fit.fitted_noise_rms`;
        where they do not support the fit, the differences, with a warning); ``"auto"``, that
        fit where the views follow it (``NoiseFit.holds``: not refused, lack of fit at most
        ``MAX_LACK_OF_FIT``), else quietly the differences (views without measurable noise;
        ``reconstruct`` then also solves the x-steps to ``NOISELESS_CG_TOL``);
        a ``PoissonGaussian``: that model's r.m.s. over the solved samples
        (``PoissonGaussian.rms``; ``reconstruct`` fits it once on the whole capture, as small
        blocks hold too few smooth samples for a fit of their own, and resolves ``"auto"``
        there).
    scan_exponent : float or "auto"
        ``e`` of λ's scan factor ``(d / 3)^e`` (module docstring), >= 0; ``"auto"`` (default):
        that of the noise measurement used (``ESTIMATE_SETTINGS``: 2 with the differences or a
        given ``noise``, 0.5 with a Poisson–Gaussian σ).
    noise_model : PoissonGaussian or None
        The views' Poisson–Gaussian noise (:mod:`metasensor.solvers.noise_model`): the data
        term becomes weighted least squares, each sample weighed by ``1 / var`` of the smooth
        start's prediction, and σ the harmonic mean of those variances (``noise`` is then
        unused); None: one weight for every sample.
    continuation : Continuation
        The β schedule (default 1 → 4096 in steps of 2√2).
    inner : int
        w-step / x-step rounds per β (default 3).
    cg : int
        Conjugate-gradient iterations per x-step where margins are unobserved, at most
        (default 3).
    cg_tol : float
        A masked x-step's conjugate gradients stop once the residual of its system is below
        ``cg_tol`` times its right-hand side (2-norms; default 1e-4, just above the float32
        floor of these products: ``docs/decisions.md``; ``NOISELESS_CG_TOL`` at most where
        ``reconstruct`` finds no measurable noise in the views); 0: always ``cg`` iterations.
    init_reg : float
        Smoothness weight of the start, relative to AᵀA's largest diagonal (default 1e-2).
    misfit_weights : float, "auto" or None
        Without a ``noise_model``: where the nearly unregularised fit's r.m.s. misfit exceeds
        this many times the noise (the model does not fit the data), weigh each view-sample
        position by its local misfit (module docstring; ``docs/decisions.md``); ``"auto"``
        (default): the gate of the noise measurement used (``ESTIMATE_SETTINGS``: 1.1 with the
        differences or a given ``noise``, 0.95 with a Poisson–Gaussian σ); None: one global
        weight always.
    misfit_pool : int
        Odd side (view-sample positions) of the box over which that local misfit is averaged
        (default 3), so that the weights do not vary from one view sample to the next.
    """

    prior: Prior = HyperLaplacian(isotropic=True)
    lam: float | None = None
    lam_scale: float = 0.3
    noise: float | None = None
    noise_estimate: str | PoissonGaussian = "differences"
    scan_exponent: float | str = "auto"
    noise_model: PoissonGaussian | None = None
    continuation: Continuation = Continuation(beta_max=4096.0)
    inner: int = 3
    cg: int = 3
    cg_tol: float = 1e-4
    init_reg: float = 1e-2
    misfit_weights: float | str | None = "auto"
    misfit_pool: int = 3

    def __post_init__(self) -> None:
        if not isinstance(self.prior, Prior):
            raise TypeError(f"prior must have a transform and prox(z, weight), got "
                            f"{type(self.prior).__name__}")
        if self.lam is not None and not (self.lam > 0 and math.isfinite(self.lam)):
            raise ValueError(f"lam must be positive and finite, got {self.lam!r}")
        for name in ("lam_scale", "init_reg"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be > 0, got {value!r}")
        mw = self.misfit_weights
        if mw is not None and mw != "auto" and (isinstance(mw, bool) or not (
                isinstance(mw, int | float) and math.isfinite(mw) and mw > 0)):
            raise ValueError(f"misfit_weights must be a positive number, 'auto' or None, got "
                             f"{mw!r}")
        mp = self.misfit_pool
        if isinstance(mp, bool) or not (isinstance(mp, int) and mp >= 1 and mp % 2 == 1):
            raise ValueError(f"misfit_pool must be an odd positive integer, got {mp!r}")
        if not (isinstance(self.cg_tol, int | float) and 0 <= self.cg_tol < 1):
            raise ValueError(f"cg_tol must be in [0, 1), got {self.cg_tol!r}")
        if self.noise is not None and not (self.noise >= 0 and math.isfinite(self.noise)):
            raise ValueError(f"noise must be a non-negative number, got {self.noise!r}")
        if not isinstance(self.noise_estimate, PoissonGaussian) and (
                self.noise_estimate not in NOISE_ESTIMATES):
            raise ValueError(f"noise_estimate must be one of {NOISE_ESTIMATES}, got "
                             f"{self.noise_estimate!r}")
        e = self.scan_exponent
        if e != "auto" and (isinstance(e, bool) or not (
                isinstance(e, int | float) and math.isfinite(e) and e >= 0)):
            raise ValueError(f"scan_exponent must be a finite number >= 0 or 'auto', got {e!r}")
        if self.noise_model is not None and not isinstance(self.noise_model, PoissonGaussian):
            raise TypeError(f"noise_model must be a PoissonGaussian, got "
                            f"{type(self.noise_model).__name__}")
        if not isinstance(self.continuation, Continuation):
            raise TypeError("continuation must be a Continuation")
        for name in ("inner", "cg"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < (
                    1 if name == "inner" else 0):
                raise ValueError(f"{name} must be an integer >= {1 if name == 'inner' else 0}, "
                                 f"got {value!r}")

    def data_weight_settings(self, kind: str) -> tuple[float, float | None]:
        """(scan exponent e, misfit gate or None) for a noise measured as ``kind``
        (``"differences"`` or ``"poisson-gaussian"``; a given ``noise`` is ``"differences"``):
        the explicit settings, ``"auto"`` ones from ``ESTIMATE_SETTINGS``."""
        e, gate = ESTIMATE_SETTINGS[kind]
        return (e if self.scan_exponent == "auto" else float(self.scan_exponent),
                gate if self.misfit_weights == "auto" else self.misfit_weights)

    @property
    def steps(self) -> int:
        """Progress ticks (one per β) a solve makes."""
        return len(self.continuation.betas())
