"""The dot-product (adjoint) test of a linear operator, in the manner of PyLops's ``dottest``, and
its norm by power iteration.

For random ``x`` in the domain and ``y`` in the range, an operator ``A`` and its adjoint satisfy
``⟨A x, y⟩ = ⟨x, Aᵀ y⟩``; float32 round-off leaves a relative difference of ~1e-6.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

__all__ = ["dot_test", "power_norm"]


def dot_test(forward: Callable[[torch.Tensor], torch.Tensor],
             adjoint: Callable[[torch.Tensor], torch.Tensor], domain_shape: tuple[int, ...],
             range_shape: tuple[int, ...], seed: int = 0, device="cpu") -> float:
    """Relative mismatch ``|⟨A x, y⟩ − ⟨x, Aᵀ y⟩| / max(|⟨A x, y⟩|, |⟨x, Aᵀ y⟩|)``.

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
        The relative mismatch (0 for an exact adjoint pair, ~1e-6 in float32).
    """
    gen = torch.Generator(device="cpu").manual_seed(int(seed))
    x = torch.randn(tuple(domain_shape), generator=gen).to(device)
    y = torch.randn(tuple(range_shape), generator=gen).to(device)
    ax = forward(x)
    if tuple(ax.shape) != tuple(range_shape):
        raise ValueError(f"forward returned shape {tuple(ax.shape)}, expected {range_shape}")
    lhs = float(torch.sum(ax.double() * y.double()))
    rhs = float(torch.sum(x.double() * adjoint(y).double()))
    scale = max(abs(lhs), abs(rhs), 1e-300)
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
