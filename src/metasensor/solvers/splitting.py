"""Half-quadratic splitting (HQS): the one loop behind every prior-regularised solver here.

Hand-written (Geman & Yang 1995; the continuation scheme of Krishnan & Fergus, NeurIPS 2009;
in the manner of deepinv's ``optim_iterators/hqs.py``, not copied). It minimises

    (λ/2) ‖A x − y‖²_M  +  R(L x)

over images x, where ``A`` is a linear forward model (one convolution, or the phase-space
operator of all views), ``M`` the mask of observed samples, and ``R(L x)`` the prior
(:mod:`metasensor.solvers.priors`). **λ**, the data weight, is defined here and only here: the
weight of the data term against a prior of unit weight, on the image in the units the caller
normalised it to. An auxiliary ``w ≈ L x`` with the penalty ``(β/2)‖L x − w‖²`` and ``β`` raised
along a :class:`Continuation` gives, for every β, ``inner`` rounds of

    w-step:  w = prior.prox(L x, 1/β)
    x-step:  (AᵀMA + μ (LᵀL + ε I)) x = AᵀM y + μ Lᵀ w,      μ = β/λ,

``ε`` a small floor (it keeps the mean determined where ``L`` is the gradient). The x-step is the
pluggable :class:`XStep`: a single-kernel Fourier division
(:class:`metasensor.solvers.krishnan_fergus.FourierXStep`) or the folded multi-view solve of the
phase-space operator (:class:`metasensor.solvers.hqs.FoldedXStep`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import torch

from metasensor.solvers.priors import Prior

__all__ = ["Continuation", "XStep", "half_quadratic_splitting", "beta_schedule"]


@dataclass(frozen=True)
class Continuation:
    """The penalty weights β of HQS: ``beta0, beta0·rate, ...`` while below ``beta_max``
    (at least ``beta0``). Defaults: Krishnan & Fergus's 1 → 256 in steps of 2√2."""

    beta0: float = 1.0
    beta_max: float = 256.0
    beta_rate: float = 2.0 * math.sqrt(2.0)

    def __post_init__(self) -> None:
        ok = all(isinstance(v, int | float) and math.isfinite(v)
                 for v in (self.beta0, self.beta_max, self.beta_rate))
        if not (ok and self.beta0 > 0 and self.beta_max >= self.beta0 and self.beta_rate > 1):
            raise ValueError(f"bad beta schedule: beta0={self.beta0}, beta_max={self.beta_max}, "
                             f"beta_rate={self.beta_rate}")

    def betas(self) -> list[float]:
        out, beta = [], float(self.beta0)
        while beta < self.beta_max:
            out.append(beta)
            beta *= self.beta_rate
        return out or [float(self.beta0)]


def beta_schedule(beta0: float = 1.0, beta_max: float = 256.0,
                  beta_rate: float = 2.0 * math.sqrt(2.0)) -> list[float]:
    """``Continuation(beta0, beta_max, beta_rate).betas()``."""
    return Continuation(beta0, beta_max, beta_rate).betas()


class XStep(Protocol):
    """The x-step of :func:`half_quadratic_splitting` for one μ.

    ``at(mu)`` prepares the system ``AᵀMA + μ (LᵀL + ε I)`` (a factorisation, a denominator) and
    returns ``solve(rhs, x)``: its solution for the right-hand side ``rhs`` (image shape), where
    ``x`` is the previous iterate (a warm start for iterative x-steps; None at the start).
    """

    def at(self, mu: float) -> Callable[[torch.Tensor, torch.Tensor | None], torch.Tensor]: ...


def half_quadratic_splitting(x: torch.Tensor, aty: torch.Tensor, xstep: XStep, prior: Prior,
                             lam: float, betas: Sequence[float], inner: int = 1,
                             on_beta: Callable[[torch.Tensor], None] | None = None
                             ) -> torch.Tensor:
    """Run HQS (module docstring) from the image ``x``.

    Parameters
    ----------
    x : torch.Tensor
        Start image ``(..., H, W)`` in the solver's units.
    aty : torch.Tensor
        ``AᵀM y``, the back-projected data (image shape).
    xstep : XStep
        The x-step (module docstring); its system must use the same ``L`` as ``prior``.
    prior : Prior
        ``prior.transform`` is ``L``; ``prior.prox(z, 1/β)`` the w-step.
    lam : float
        λ, the data weight (module docstring), > 0.
    betas : sequence of float
        The continuation (:meth:`Continuation.betas`).
    inner : int
        w-step / x-step rounds per β, >= 1.
    on_beta : callable, optional
        Called with the iterate after each β (a residual, a progress tick).

    Returns
    -------
    torch.Tensor
        The last iterate, not clipped.
    """
    if not (lam > 0 and math.isfinite(lam)):
        raise ValueError(f"lam must be positive and finite, got {lam!r}")
    if inner < 1:
        raise ValueError(f"inner must be >= 1, got {inner}")
    transform = prior.transform
    for beta in betas:
        mu = beta / lam
        solve = None  # the previous β's factorisation goes before the next one is made
        solve = xstep.at(mu)
        for _ in range(inner):
            w = prior.prox(transform.forward(x), 1.0 / beta)
            x = solve(aty + mu * transform.adjoint(w), x)
        if on_beta is not None:
            on_beta(x)
    return x
