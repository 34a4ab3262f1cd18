"""The dot-product (adjoint) test of a linear operator, in the manner of PyLops's ``dottest``, and
its norm by power iteration.

For random ``x`` in the domain and ``y`` in the range, an operator ``A`` and its adjoint satisfy
``⟨A x, y⟩ = ⟨x, Aᵀ y⟩``. The mismatch is measured against the Cauchy–Schwarz scale
``‖A x‖·‖y‖`` (and ``‖x‖·‖Aᵀ y‖``), the size of the error that a relative error of ``A x`` or
``Aᵀ y`` can make, not against the inner product itself: two random vectors of ``n`` entries are
nearly orthogonal (``⟨A x, y⟩ ~ ‖A x‖·‖y‖ / √n``, and much less for an unlucky draw), so a
mismatch relative to the inner product magnifies float32 round-off without bound on such a draw.
Against the scale, round-off stays near float32's precision over ``√n`` and a wrong adjoint
reads about ``1/√n``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

__all__ = ["dot_test", "power_norm"]


def dot_test(forward: Callable[[torch.Tensor], torch.Tensor],
             adjoint: Callable[[torch.Tensor], torch.Tensor], domain_shape: tuple[int, ...],
             range_shape: tuple[int, ...], seed: int = 0, device="cpu") -> float:
    """Relative mismatch ``|⟨A x, y⟩ − ⟨x, Aᵀ y⟩| / max(‖A x‖·‖y‖, ‖x‖·‖Aᵀ y‖)``.

    Parameters
    ----------
    forward, adjoint : callable
        ``A`` and its claimed adjoint ``Aᵀ`` on float32 tensors.
    domain_shape, range_shape : tuple of int
        Shapes of ``x`` and of ``A x``.
    seed : int
        Seed of the standard normal ``x`` and ``y``.
    device : str or torch.device
        Where ``x`` and ``y`` are made.

    Returns
    -------
    float
        The relative mismatch: 0 for an exact adjoint pair (round-off only, in float32);
        ``O(1/√n)`` for a wrong adjoint (``n`` the number of range entries).
    """
    gen = torch.Generator(device="cpu").manual_seed(int(seed))
    x = torch.randn(tuple(domain_shape), generator=gen).to(device)
    y = torch.randn(tuple(range_shape), generator=gen).to(device)
    ax = forward(x)
    if tuple(ax.shape) != tuple(range_shape):
        raise ValueError(f"forward returned shape {tuple(ax.shape)}, expected {range_shape}")
    aty = adjoint(y)
    x64, y64, ax64, aty64 = x.double(), y.double(), ax.double(), aty.double()
    lhs = float(torch.sum(ax64 * y64))
    rhs = float(torch.sum(x64 * aty64))
    scale = max(float(torch.linalg.vector_norm(ax64) * torch.linalg.vector_norm(y64)),
                float(torch.linalg.vector_norm(x64) * torch.linalg.vector_norm(aty64)), 1e-300)
    return abs(lhs - rhs) / scale


def power_norm(op, iterations: int = 30, seed: int = 0) -> float:
    """The operator norm ‖A‖₂ (largest singular value) of ``op`` (``forward``, ``adjoint``,
    ``domain_shape``, ``device``), by power iteration on AᵀA from a seeded random image;
    ``iterations`` products (relative error ~ (λ₂/λ₁)^iterations)."""
    gen = torch.Generator(device="cpu").manual_seed(int(seed))
    x = torch.rand(op.domain_shape, generator=gen).to(op.device)
    value = 0.0
    for _ in range(max(int(iterations), 1)):
        x = op.adjoint(op.forward(x))
        value = float(torch.linalg.vector_norm(x))
        if value == 0.0:
            return 0.0
        x = x / value
    return math.sqrt(value)
