"""The normal operator AᵀA of the phase-space model, block-diagonal in the Fourier domain.

Hand-written (no library folds a multi-view sampled convolution). For the operator
``A = [S_d(H_v ⊛ ·)]_v`` of :class:`metasensor.phasespace.operator.PhaseSpaceOperator` on a
domain of
``(My·d, Mx·d)`` pixels, sampling every d-th pixel aliases the d² frequencies
``(p + a·My, q + b·Mx)``, a, b = 0..d−1, onto the view frequency (p, q). Hence (unnormalised DFTs)

    fft2(A_v x)(p, q) = Σ_i h_v,i(p, q) X_i(p, q),   h_v,i = H_v(p + a·My, q + b·Mx) / d²
    fft2(AᵀA x)_i(p, q) = Σ_j G_ij(p, q) X_j(p, q),  G(p, q) = d² Σ_v h_vᴴ h_v   (d² x d²),

so the normal equations split into My·Mx independent d² x d² Hermitian systems: the exact
regularised least-squares solution costs FFTs plus a batched d² x d² product (the inverse,
from a Cholesky factorisation once per weight). The eigenvalues of
G(p, q) are the squared singular values of the whole scanning light-field measurement; they show
what a capture can and cannot resolve (d² aliases against the number of views: a 1 x 1 scan,
d = 15, has 225 unknowns per frequency for 113 views and a null space; 5 x 5 has 9).

The regularised solves built on it are in :mod:`metasensor.solvers` (:mod:`~metasensor.solvers.
tikhonov`, the x-step of :mod:`~metasensor.solvers.hqs`).
"""

from __future__ import annotations

import torch

from metasensor.phasespace.operator import PhaseSpaceOperator

__all__ = ["FoldedNormal"]


class FoldedNormal:
    """G(p, q) = fft-domain AᵀA of ``op`` as a (My, Mx, d², d²) complex64 tensor (built once).

    Memory: My·Mx·d⁴·8 bytes (2,100² px domain, d = 3: 290 MB). Calls never change the object.
    """

    def __init__(self, op: PhaseSpaceOperator) -> None:
        g = op.geometry
        self.op, self.geometry, self.device = op, g, op.device
        d = g.d
        my, mx = g.grid
        ny, nx = g.domain
        nh = nx // 2 + 1
        # the full spectra from the operator's half spectra (a real PSF's spectrum is Hermitian:
        # H(ky, kx) = conj H(−ky, Nx − kx) for kx >= Nx//2 + 1), not from new FFTs
        rows = torch.remainder(-torch.arange(ny, device=self.device), ny)
        cols = nx - torch.arange(nh, nx, device=self.device)
        mat = torch.zeros((my, mx, d * d, d * d), dtype=torch.complex64, device=self.device)
        for i in range(0, op.n_views, op.chunk):
            half = op.otf[i:i + op.chunk]
            full = torch.empty((half.shape[0], ny, nx), dtype=torch.complex64,
                               device=self.device)
            full[..., :nh] = half
            full[..., nh:] = half[:, rows][..., cols].conj()
            h = self.fold(full)
            mat += torch.einsum("vpqi,vpqj->pqij", h.conj(), h)
        self.matrix = mat / (d * d)

    # ------------------------------------------------------------------ layout
    def fold(self, spec: torch.Tensor) -> torch.Tensor:
        """(..., Ny, Nx) full spectrum -> (..., My, Mx, d²): the aliases of each view frequency."""
        d = self.geometry.d
        my, mx = self.geometry.grid
        lead = spec.shape[:-2]
        s = spec.reshape(*lead, d, my, d, mx)
        n = len(lead)
        s = s.permute(*range(n), n + 1, n + 3, n, n + 2)
        return s.reshape(*lead, my, mx, d * d)

    def unfold(self, folded: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`fold` for a single (My, Mx, d²) array -> (Ny, Nx)."""
        d = self.geometry.d
        my, mx = self.geometry.grid
        return folded.reshape(my, mx, d, d).permute(2, 0, 3, 1).reshape(my * d, mx * d)

    # ------------------------------------------------------------------ operators
    def apply(self, image) -> torch.Tensor:
        """AᵀA·image on the circular domain, through G (equals op.adjoint(op.forward(image)))."""
        x = torch.as_tensor(image, dtype=torch.float32, device=self.device)
        xf = self.fold(torch.fft.fft2(x))
        y = torch.einsum("pqij,pqj->pqi", self.matrix, xf)
        return torch.fft.ifft2(self.unfold(y)).real

    def eigenvalues(self) -> torch.Tensor:
        """(My, Mx, d²) eigenvalues of G per view frequency, ascending (squared singular values
        of the measurement, in the units of op: divide by their maximum for a relative scale)."""
        return torch.linalg.eigvalsh(self.matrix)

    def factor(self, lam: float, weights: torch.Tensor | None = None) -> torch.Tensor:
        """The regularised system (G + lam·R)⁻¹ per view frequency, (My, Mx, d², d²) complex128,
        R = diag(``weights``) (My, Mx, d²) in the folded layout (default: the identity); ``lam``
        is relative to G's largest diagonal. For :meth:`solve`.

        Cholesky factorisation, then the explicit inverse (applying it is one batched d² x d²
        product per solve), in double precision: G's eigenvalues span ~1e-6..1 (float32 would
        lose the small ones). Timings: ``docs/decisions.md``."""
        if not lam > 0:
            raise ValueError(f"lam must be > 0, got {lam}")
        scale = float(self.matrix.diagonal(dim1=-2, dim2=-1).real.max())
        a = self.matrix.to(torch.complex128)
        diag = a.diagonal(dim1=-2, dim2=-1)
        if weights is None:
            diag += lam * scale
        else:
            diag += (lam * scale) * weights.to(torch.float64)
        chol, info = torch.linalg.cholesky_ex(a)
        del a
        if bool((info != 0).any()):
            raise ValueError(f"lam = {lam} is too small to make AᵀA + lam·R positive definite")
        return torch.cholesky_inverse(chol)

    def solve(self, rhs_image, inverse: torch.Tensor) -> torch.Tensor:
        """(AᵀA + lam·R)⁻¹ rhs on the circular domain, with ``inverse`` from :meth:`factor`."""
        b = self.fold(torch.fft.fft2(torch.as_tensor(rhs_image, dtype=torch.float32,
                                                     device=self.device)))
        x = torch.matmul(inverse, b.to(torch.complex128).unsqueeze(-1)).squeeze(-1)
        return torch.fft.ifft2(self.unfold(x.to(torch.complex64))).real
