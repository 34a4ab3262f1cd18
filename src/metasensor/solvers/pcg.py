"""Preconditioned conjugate gradients for the HQS x-step (:mod:`metasensor.solvers.hqs`).

Hand-written: SciPy's ``cg`` works on NumPy arrays and cannot carry the product ``AᵀMA x`` from
one call to the next (each call here starts from the previous x-step's result and its product),
and the preconditioner is the folded normal operator's exact circular solve
(:meth:`metasensor.phasespace.normal.FoldedNormal.solve`). The method: Hestenes & Stiefel (1952);
Saad, "Iterative Methods for Sparse Linear Systems", 2nd ed., SIAM 2003, Algorithm 9.1.
"""

from __future__ import annotations

import torch

from metasensor.phasespace.normal import FoldedNormal

__all__ = ["preconditioned_cg"]


def preconditioned_cg(data_normal, reg, mu: float, rhs, x, ax, inv, nm: FoldedNormal,
                      iterations: int, tol: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Conjugate gradients on ``(AᵀMA + μ R) x = rhs`` from ``x``, preconditioned by the
    circular, fully observed system (``nm.solve`` with ``inv``); ``R`` = ``reg``. At most
    ``iterations``; fewer once ``‖r‖ <= tol·‖rhs‖`` after an iteration (r the residual).

    ``ax`` is ``AᵀMA x`` when known (None: computed here); it is carried along the iterations
    (``AᵀMA`` of each step is one product the iteration makes anyway), so the result comes with
    its own ``AᵀMA x`` and the next call starts without a product."""
    if ax is None:
        ax = data_normal(x)
    r = rhs - ax - mu * reg(x)
    z = nm.solve(r, inv)
    p = z
    rz = float(torch.vdot(r.flatten(), z.flatten()))
    stop = tol * float(torch.linalg.vector_norm(rhs))
    for _ in range(iterations):
        qd = data_normal(p)
        q = qd + mu * reg(p)
        pq = float(torch.vdot(p.flatten(), q.flatten()))
        if not pq > 0:
            break
        a = rz / pq
        x = x + a * p
        ax = ax + a * qd
        r = r - a * q
        if stop > 0 and float(torch.linalg.vector_norm(r)) <= stop:
            break
        z = nm.solve(r, inv)
        rz_new = float(torch.vdot(r.flatten(), z.flatten()))
        p = z + (rz_new / rz) * p if rz > 0 else z
        rz = rz_new
    return x, ax
