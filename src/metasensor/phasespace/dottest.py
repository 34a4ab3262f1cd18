"""The dot-product (adjoint) test of a linear operator, in the manner of PyLops's ``dottest``.

For random ``x`` in the domain and ``y`` in the range, an operator ``A`` and its adjoint satisfy
``⟨A x, y⟩ = ⟨x, Aᵀ y⟩``; float32 round-off leaves a relative difference of ~1e-6.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

__all__ = ["dot_test"]


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
