"""Regularised linear least squares on the phase-space operator (the best *linear* estimate).

``argmin_x ‖A x − y‖²_M + lam·scale·xᵀ R x`` with ``R`` the gradient's ``LᵀL``
(:class:`metasensor.solvers.priors.Gradient`, plus a floor that keeps the mean determined) or the
identity, solved exactly per view frequency by the folded normal operator
(:class:`metasensor.phasespace.normal.FoldedNormal`; ``scale`` its largest diagonal).
Hand-written. Unobserved samples (the padded margins of a window) are completed with the current
prediction and the circular problem re-solved (an EM fixed point, a few outer steps).
"""

from __future__ import annotations

import torch

from metasensor.phasespace.normal import FoldedNormal
from metasensor.solvers.priors import GRADIENT

__all__ = ["difference_weights", "tikhonov"]


def difference_weights(normal: FoldedNormal, floor: float = 1e-3) -> torch.Tensor:
    """The folded symbol ``(My, Mx, d²)`` of the gradient's ``LᵀL`` (``|D_y|² + |D_x|²``,
    :class:`~metasensor.solvers.priors.Gradient`) plus ``floor``: a smoothness regulariser R for
    :meth:`FoldedNormal.factor <metasensor.phasespace.normal.FoldedNormal.factor>`."""
    sym = GRADIENT.symbol(normal.geometry.domain, normal.device) + floor
    return normal.fold(sym.to(torch.complex64)).real


def tikhonov(normal: FoldedNormal, data, mask, lam: float, smooth: bool = True,
             outer: int = 10) -> torch.Tensor:
    """Regularised least squares on the operator of ``normal``.

    Parameters
    ----------
    normal : FoldedNormal
        The folded normal operator of the phase-space operator ``A`` (``op.normal()``).
    data : array_like
        ``(V, My, Mx)`` view samples on the domain's sample grid.
    mask : array_like
        ``(My, Mx)`` bool, True where observed.
    lam : float
        Regularisation weight relative to AᵀA's largest diagonal, > 0.
    smooth : bool
        R: the gradient's ``LᵀL`` (True) or the identity.
    outer : int
        Completion steps where samples are unobserved (one step when all are observed).

    Returns
    -------
    torch.Tensor
        The ``(Ny, Nx)`` domain estimate, not clipped.
    """
    op = normal.op
    y, m = op.samples_and_mask(data, mask)
    inv = normal.factor(lam, difference_weights(normal) if smooth else None)  # once
    mf = m.to(torch.float32)
    y = torch.nan_to_num(y) * mf
    steps = 1 if bool(m.all()) else max(int(outer), 1)
    x = None
    for _ in range(steps):
        full = y if x is None else y + op.forward(x) * (1 - mf)
        x = normal.solve(op.adjoint(full), inv)
    return x
