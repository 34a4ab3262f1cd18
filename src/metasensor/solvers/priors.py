"""Image priors for half-quadratic splitting (:mod:`metasensor.solvers.splitting`).

A prior is a penalty ``R(L x)`` on a linear transform ``L`` of the image (the *analysis* form):
``L`` is the gradient stencil :class:`Gradient` for sparse-gradient priors, or :class:`Identity`
for priors on the image itself (Tikhonov, a plug-and-play denoiser). Half-quadratic splitting
introduces ``w ≈ L x`` and alternates

    w-step:  w = prior.prox(L x, 1 / beta)         x-step:  (λAᵀA + β LᵀL) x = λAᵀy + β Lᵀw,

so a prior is two things, and a new one is one class with them:

- ``transform``: the linear map ``L`` (``forward``, ``adjoint``, ``gram`` = ``adjoint∘forward``
  and ``symbol(shape, device)``: the eigenvalues of the circulant ``LᵀL`` on the unshifted FFT
  grid, which the Fourier x-steps need);
- ``prox(z, weight)``: the proximal operator ``argmin_w weight·R(w) + ½‖w − z‖²``, element-wise
  or not, on ``z`` of the transform's output shape (``(2, ..., H, W)`` for the gradient,
  ``(..., H, W)`` for the identity). ``weight`` > 0 is a float; ``z`` is a float32 tensor on the
  solver's device, and the result must have its shape, dtype and device and must not modify it.

A plug-and-play denoiser ``D_σ`` (Venkatakrishnan et al. 2013) is a prior on the image:
``transform = IDENTITY`` and ``prox(z, weight) = D_σ(z)`` with ``σ² = weight`` (the MAP denoiser
of Gaussian noise of variance ``weight`` is exactly this proximal operator); pass it as
``HQSOptions(prior=...)``.

The image the prior sees is in the solver's units (the phase-space HQS normalises the image to
mean 0.5; Krishnan–Fergus to maximum 1); λ, the data weight, is defined once, in
:mod:`metasensor.solvers.splitting`.

:class:`HyperLaplacian` is Krishnan & Fergus's ``R(w) = Σ |w|^alpha`` (NeurIPS 2009) on the
gradient, with the closed-form proximal operators of :mod:`metasensor.solvers.hyper_laplacian`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import torch

from metasensor.solvers.hyper_laplacian import solve_w_table

__all__ = ["Transform", "Prior", "Gradient", "Identity", "HyperLaplacian", "GRADIENT",
           "IDENTITY"]


@runtime_checkable
class Transform(Protocol):
    """A linear map ``L`` of images ``(..., H, W)`` with its adjoint (see the module docstring)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor: ...

    def adjoint(self, w: torch.Tensor) -> torch.Tensor: ...

    def gram(self, x: torch.Tensor) -> torch.Tensor: ...

    def symbol(self, shape: tuple[int, int], device) -> torch.Tensor: ...


@runtime_checkable
class Prior(Protocol):
    """An HQS prior: a transform ``L`` and
    ``prox(z, weight) = argmin_w weight·R(w) + ½‖w − z‖²``."""

    transform: Transform

    def prox(self, z: torch.Tensor, weight: float) -> torch.Tensor: ...


@dataclass(frozen=True)
class Gradient:
    """The gradient stencil ∇ of every solver here: circular *forward* first differences,
    ``(∇x)_y(p) = x(p + e_y) − x(p)`` and likewise along x, stacked as ``(2, ..., H, W)``
    (component 0 along rows, 1 along columns)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.stack([torch.roll(x, -1, -2) - x, torch.roll(x, -1, -1) - x])

    def adjoint(self, w: torch.Tensor) -> torch.Tensor:
        wy, wx = w[0], w[1]
        return (torch.roll(wy, 1, -2) - wy) + (torch.roll(wx, 1, -1) - wx)

    def gram(self, x: torch.Tensor) -> torch.Tensor:
        return self.adjoint(self.forward(x))

    def symbol(self, shape: tuple[int, int], device) -> torch.Tensor:
        """``|D_y|² + |D_x|² = 4 sin²(π k_y) + 4 sin²(π k_x)`` on the FFT grid ``shape``."""
        ky = torch.fft.fftfreq(int(shape[0]), device=device)[:, None]
        kx = torch.fft.fftfreq(int(shape[1]), device=device)[None, :]
        return 4 * torch.sin(math.pi * ky) ** 2 + 4 * torch.sin(math.pi * kx) ** 2


@dataclass(frozen=True)
class Identity:
    """``L = I``: a prior on the image itself."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x

    def adjoint(self, w: torch.Tensor) -> torch.Tensor:
        return w

    def gram(self, x: torch.Tensor) -> torch.Tensor:
        return x

    def symbol(self, shape: tuple[int, int], device) -> torch.Tensor:
        return torch.ones((int(shape[0]), int(shape[1])), device=device)


GRADIENT = Gradient()
IDENTITY = Identity()


@dataclass(frozen=True)
class HyperLaplacian:
    """The sparse-gradient prior of natural images (Krishnan & Fergus 2009), alpha 2/3
    (default) or 1 (total variation): anisotropic ``R(∇x) = Σ_p Σ_i |(∇x)_i(p)|^alpha`` (each
    gradient component on its own), or with ``isotropic`` ``R(∇x) = Σ_p |∇x(p)|^alpha`` (the
    gradient's magnitude; no preferred axis, so edges are not drawn as steps along the pixel
    axes).

    ``prox`` is exact for alpha = 1 (soft threshold) and tabulated for 2/3 (the lookup table of
    :func:`metasensor.solvers.hyper_laplacian.solve_w_table`, element-wise, so each image of a
    batch ``(2, ..., H, W)`` gets its own result).
    The isotropic prox is the scalar one applied to the magnitude ``|z(p)|`` with ``z(p)``'s
    direction kept (the minimiser of a radial penalty plus ``½‖w − z‖²`` lies along ``z``).
    """

    alpha: float = 2.0 / 3.0
    transform: Gradient = GRADIENT
    isotropic: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.alpha, int | float) or (
                self.alpha != 1.0 and abs(self.alpha - 2.0 / 3.0) > 1e-9):
            raise ValueError(f"alpha must be 2/3 or 1, got {self.alpha!r}")
        if not isinstance(self.isotropic, bool):
            raise TypeError(f"isotropic must be True or False, got {self.isotropic!r}")

    def prox(self, z: torch.Tensor, weight: float) -> torch.Tensor:
        beta = 1.0 / float(weight)
        if not self.isotropic:
            return solve_w_table(z, beta, self.alpha)
        if z.shape[0] != 2:
            raise ValueError(f"the isotropic prox needs gradients (2, ..., H, W), got {z.shape}")
        rho = torch.sqrt(z[0] ** 2 + z[1] ** 2)
        scale = solve_w_table(rho, beta, self.alpha).div_(rho.clamp_min(1e-30))
        return z * scale
