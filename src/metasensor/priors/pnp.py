"""The learned denoiser as a plug-and-play prior of the half-quadratic splitting solvers.

Plug-and-play (Venkatakrishnan, Bouman & Wohlberg, GlobalSIP 2013; with a CNN denoiser and
HQS, Zhang et al., "Plug-and-play image restoration with deep denoiser prior", IEEE TPAMI 2022):
the proximal operator of the prior, ``argmin_w weight·R(w) + ½‖w − z‖²``, is the MAP denoiser of
``z`` under white Gaussian noise of variance ``weight``, so it is replaced by a denoiser at
``sigma = strength · sqrt(weight)``, clamped to the noise levels the network was trained on.
The prior acts on the image itself (``transform``: the identity), in the solver's units: the
phase-space HQS normalises the image to mean 0.5, the range the denoiser was trained on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from metasensor.priors.denoiser import CNNDenoiser
from metasensor.priors.training import SIGMA_MAX
from metasensor.solvers.priors import IDENTITY, Identity

__all__ = ["DenoiserPrior", "pnp_options", "check_noise_levels", "noise_level"]


def check_noise_levels(strength: float, sigma_min: float, sigma_max: float) -> None:
    """Refuse a plug-and-play prior's settings: ``strength`` and ``sigma_max`` positive numbers,
    ``0 <= sigma_min <= sigma_max`` (ValueError naming the setting)."""
    for name, v in (("strength", strength), ("sigma_max", sigma_max)):
        if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a positive number, got {v!r}")
    if not (isinstance(sigma_min, int | float) and 0 <= sigma_min <= sigma_max):
        raise ValueError(f"sigma_min must lie in [0, sigma_max], got {sigma_min!r}")


def noise_level(weight: float, strength: float, sigma_min: float, sigma_max: float) -> float:
    """The denoiser's noise level for the prox weight ``weight`` (> 0): ``strength ·
    sqrt(weight)`` clamped to ``[sigma_min, sigma_max]`` (the image's units)."""
    if not (math.isfinite(weight) and weight > 0):
        raise ValueError(f"weight must be a positive number, got {weight!r}")
    return min(max(strength * math.sqrt(weight), sigma_min), sigma_max)


@dataclass(frozen=True)
class DenoiserPrior:
    """``prox(z, weight) = D(z, clip(strength·sqrt(weight), sigma_min, sigma_max))``.

    Parameters
    ----------
    strength : float
        Scale from ``sqrt(weight)`` to the denoiser's noise level (> 0); larger smooths more.
    sigma_min, sigma_max : float
        Noise levels the denoiser is asked for are clamped to this range (image units of the
        mean-0.5 normalised image; the shipped network was trained on 0 to ``SIGMA_MAX``).
    denoiser : CNNDenoiser
        The network (default: the shipped weights, loaded once per prior).
    """

    strength: float = 1.0
    sigma_min: float = 0.0
    sigma_max: float = SIGMA_MAX
    denoiser: CNNDenoiser = field(default_factory=CNNDenoiser, repr=False, compare=False)
    transform: Identity = IDENTITY

    def __post_init__(self) -> None:
        check_noise_levels(self.strength, self.sigma_min, self.sigma_max)

    def prox(self, z: torch.Tensor, weight: float) -> torch.Tensor:
        """Denoise ``z`` (..., H, W) at the noise level of ``weight`` (class docstring)."""
        sigma = noise_level(weight, self.strength, self.sigma_min, self.sigma_max)
        flat = z.reshape(-1, *z.shape[-2:])
        out = torch.stack([self.denoiser.denoise(img, sigma) for img in flat])
        return out.reshape(z.shape)


def pnp_options(strength: float = 1.0, lam_scale: float = 3.0):
    """HQS options (:class:`metasensor.solvers.hqs.HQSOptions`) that run the phase-space solver
    with :class:`DenoiserPrior`: data weight ``lam_scale`` and a continuation of β from 25 (the
    denoiser at its largest trained sigma, 0.2) to 4096 (sigma 0.016), doubling. The defaults
    are those chosen on a simulated dead-leaves capture (docs/decisions.md); pass the result as
    ``reconstruct(..., solver_options=pnp_options())``."""
    from metasensor.solvers.hqs import HQSOptions
    from metasensor.solvers.splitting import Continuation

    return HQSOptions(prior=DenoiserPrior(strength=strength), lam_scale=lam_scale,
                      continuation=Continuation(beta0=25.0, beta_max=4096.0, beta_rate=2.0),
                      noise_estimate="differences")  # the noise lam_scale was chosen with
