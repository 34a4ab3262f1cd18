"""What every solver returns."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

__all__ = ["SolveResult"]


@dataclass
class SolveResult:
    """A solver's estimate and its convergence record.

    Attributes
    ----------
    estimate : torch.Tensor
        ``(Ny, Nx)`` float32 image on the operator's domain, in data units.
    history : list of float
        The relative residual ``‖y − A x‖ / ‖y‖`` over the observed samples after each
        iteration (Richardson–Lucy) or each β (half-quadratic splitting).
    """

    estimate: torch.Tensor
    history: list[float] = field(default_factory=list)
