"""The Poisson–Gaussian noise model of the view samples and the data-term weights it gives.

Every view sample is one sensor pixel, read as ``y = g·(Poisson(s/g) + N(0, r²))`` DN (photon
shot noise, read noise, then quantisation; :mod:`metasensor.simulation.noise`), so

    var(y) = a·s + b,    a = g [DN per electron],   b = (g·r)² + 1/12 [DN²]

(Foi et al., IEEE TIP 17, 1737–1754, 2008: the Poissonian–Gaussian model of raw data). The
model comes from the capture's metadata (:meth:`PoissonGaussian.from_metadata`: gain, read
noise, bit depth as the simulator writes them) or is fitted to the views
(:func:`metasensor.solvers.noise_fit.fit_poisson_gaussian`).

Weighted least squares (the HQS data term, :mod:`metasensor.solvers.hqs`) weighs a sample by
``1 / var``; :func:`sample_weights` returns those weights normalised to mean 1 over the observed
samples, and the reference variance ``σ²`` they are relative to (the harmonic mean of the
variances), so that ``σ²·W = 1 / var``; a variance counts as at least :data:`VARIANCE_FLOOR`
times the mean variance (the residual of dark samples is not their noise alone but also the
model's error, which the model above does not hold). With ``a = 0`` every weight is exactly 1
and ``σ² = b``: the unweighted data term. Richardson–Lucy takes the model as the shifted-Poisson
form of Snyder, Hammoud & White (JOSA A 10, 1014–1023, 1993): ``y + b/a`` is nearly Poisson
(in units of ``a``) with mean ``A x + b/a``.

Model error is not in that model: a bank that is an estimate, or a wavefront or scene that moves
during the scan, leaves residuals where the scene has structure, and one global weight lets the
fit explain them there with spurious detail. :func:`misfit_weights` weighs each sample position
by its own misfit instead, ``var = max(σ², mean over the views of r²)`` of a first fit's
residual ``r``: one step of iteratively reweighted least squares (Holland & Welsch,
Commun. Stat. 6, 813–827, 1977) with a floor ``σ`` (the noise, or a caller's larger level), so
the samples the model explains keep the floor's weight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

__all__ = ["misfit_weights", "PoissonGaussian", "sample_weights", "VARIANCE_FLOOR"]

#: smallest variance a weight uses, relative to the mean variance of the observed samples: the
#: residual of dark samples is not their noise alone (the model's own error), so a weight is at
#: most 10x the mean-variance sample's (docs/decisions.md, 2026-11-26, bench_noise)
VARIANCE_FLOOR = 0.1


def _finite(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class PoissonGaussian:
    """``var(y) = a·max(y, 0) + b`` of a view sample ``y`` (data units, e.g. DN) (frozen,
    validated).

    Attributes
    ----------
    a : float
        Slope, data units per photo-electron (the gain), >= 0; 0: signal-independent noise.
    b : float
        Intercept, data units² (read-noise variance plus quantisation), >= 0; ``a + b > 0``.
    source : str
        Where the values come from: ``"given"``, ``"metadata"`` or ``"fit"``.
    """

    a: float
    b: float
    source: str = "given"

    def __post_init__(self) -> None:
        a, b = _finite("a", self.a), _finite("b", self.b)
        if a < 0:
            raise ValueError(f"a (the gain, data units per electron) must be >= 0, got {a!r}")
        if b < 0:
            raise ValueError(f"b (the read-noise variance) must be >= 0, got {b!r}")
        if a + b <= 0:
            raise ValueError("a and b are both 0: a noise model needs some noise")
        if self.source not in ("given", "metadata", "fit"):
            raise ValueError(f"source must be 'given', 'metadata' or 'fit', got {self.source!r}")

    @classmethod
    def from_gain(cls, gain: float, read_noise: float, quantised: bool = True,
                  source: str = "given") -> PoissonGaussian:
        """The model of a sensor of ``gain`` DN per electron and ``read_noise`` electrons
        r.m.s.; ``quantised`` adds the 1/12 DN² of rounding to integer DN."""
        g, r = _finite("gain", gain), _finite("read_noise", read_noise)
        if g <= 0 or r < 0:
            raise ValueError(f"gain must be > 0 and read_noise >= 0, got {gain!r}, {read_noise!r}")
        return cls(a=g, b=(g * r) ** 2 + (1.0 / 12.0 if quantised else 0.0), source=source)

    @classmethod
    def from_metadata(cls, meta) -> PoissonGaussian | None:
        """The model from a capture's metadata: a :class:`~metasensor.simulation.noise.NoiseModel`
        (``Capture.noise``) or the ``"metasensor"`` extras of a written capture (keys ``gain``,
        ``read_noise``; views in DN). None where they hold no gain (a noise-free simulation, or
        data that do not say)."""
        gain = getattr(meta, "gain", None) if not isinstance(meta, dict) else meta.get("gain")
        read = (getattr(meta, "read_noise", None) if not isinstance(meta, dict)
                else meta.get("read_noise"))
        if gain is None or read is None:
            return None
        return cls.from_gain(float(gain), float(read), source="metadata")

    @property
    def shift(self) -> float:
        """``b / a``: the shifted-Poisson offset (data units) of Richardson–Lucy."""
        if self.a <= 0:
            raise ValueError("the shifted-Poisson form needs a > 0 (signal-dependent noise)")
        return self.b / self.a

    def variance(self, y: torch.Tensor) -> torch.Tensor:
        """``a·max(y, 0) + b`` (data units²) of samples ``y``."""
        return torch.clamp(y, min=0.0) * self.a + self.b

    def rms(self, y: torch.Tensor, mask: torch.Tensor | None = None) -> float:
        """The noise r.m.s. (data units) of view samples under this model: the square root of
        :meth:`variance`'s mean over the observed samples.

        Parameters
        ----------
        y : torch.Tensor
            ``(V, My, Mx)`` view samples (data units); not modified.
        mask : torch.Tensor, optional
            ``(My, Mx)`` bool, True on observed samples; default all.
        """
        if y.ndim != 3:
            raise ValueError(f"y must be (V, My, Mx) view samples, got shape {tuple(y.shape)}")
        m = (torch.ones(y.shape[1:], dtype=torch.bool, device=y.device) if mask is None
             else mask.to(device=y.device, dtype=torch.bool))
        n = int(m.sum()) * y.shape[0]
        if not n:
            raise ValueError("no observed samples to measure the noise on")
        total = float((self.variance(y) * m).sum(dtype=torch.float64))
        return math.sqrt(max(total / n, 0.0))


def sample_weights(model: PoissonGaussian, level: torch.Tensor, mask: torch.Tensor
                   ) -> tuple[torch.Tensor | None, float]:
    """Per-sample weights of weighted least squares (module docstring).

    Parameters
    ----------
    model : PoissonGaussian
        The noise model, data units.
    level : torch.Tensor
        ``(V, My, Mx)`` the samples' expected values (data units): the data, or better a
        prediction of them (weights of the noisy data bias the fit towards dark samples).
    mask : torch.Tensor
        ``(My, Mx)`` bool, True on observed samples.

    Returns
    -------
    weights : torch.Tensor or None
        ``(V, My, Mx)`` float32, ``σ² / var``, mean 1 over observed samples and 0 elsewhere;
        None where ``a = 0`` (every weight 1).
    sigma2 : float
        ``σ²`` (data units²), the harmonic mean of the observed samples' variances (floored).
    """
    if model.a == 0:
        return None, float(model.b)
    mf = mask.to(level.dtype)
    var = model.variance(level)
    mean_var = float((var * mf).sum()) / max(float(mf.sum()) * var.shape[0], 1.0)
    var = torch.clamp(var, min=VARIANCE_FLOOR * mean_var)
    inv = mf / var
    n_obs = max(float(mf.sum()) * var.shape[0], 1.0)
    sigma2 = n_obs / max(float(inv.sum()), 1e-30)
    return (inv * sigma2).to(torch.float32), sigma2


def misfit_weights(residual: torch.Tensor, mask: torch.Tensor, noise: float, pool: int = 1
                   ) -> tuple[torch.Tensor, float]:
    """Per-position weights of a data term from a fit's local misfit (module docstring).

    Parameters
    ----------
    residual : torch.Tensor
        ``(V, My, Mx)`` residual ``A x − y`` of a first fit (any units; zero or anything where
        unobserved).
    mask : torch.Tensor
        ``(My, Mx)`` bool, True on observed samples.
    noise : float
        The floor of the r.m.s. misfit in the residual's units (the samples' noise or more),
        > 0.
    pool : int
        Odd side (sample positions) of the box over which the mean squared residual is
        averaged (observed positions only), so that the weights vary smoothly over the field
        rather than from one view sample to the next; 1: each position alone.

    Returns
    -------
    weights : torch.Tensor
        ``(My, Mx)`` float32, ``σ² / var`` with ``var = max(noise², mean residual²)`` at each
        observed position, the mean taken over the views and the ``pool`` × ``pool`` observed
        positions around it (the same for every view): mean 1 over the observed positions, 0
        where unobserved.
    sigma2 : float
        ``σ²``, the harmonic mean of the observed positions' variances (residual units²).
    """
    if not (noise > 0 and math.isfinite(noise)):
        raise ValueError(f"noise must be positive and finite, got {noise!r}")
    if not (isinstance(pool, int) and pool >= 1 and pool % 2 == 1):
        raise ValueError(f"pool must be an odd positive integer, got {pool!r}")
    m = mask.to(torch.bool)
    local = (residual.to(torch.float32) ** 2).mean(0)
    if pool > 1:
        mf = m.to(torch.float32)
        box = [torch.nn.functional.avg_pool2d(a[None, None], pool, stride=1,
                                              padding=pool // 2)[0, 0] for a in (local * mf, mf)]
        local = box[0] / torch.clamp(box[1], min=1e-12)
    var = torch.where(m, torch.clamp(local, min=noise**2), torch.ones_like(local))
    inv = m.to(torch.float32) / var
    sigma2 = float(m.sum()) / max(float(inv.sum()), 1e-30)
    return (inv * sigma2).to(torch.float32), sigma2
