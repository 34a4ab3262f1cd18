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

# bytes of OTF values gathered at once while G is built (its transient memory)
SLAB_BYTES = 16 * 2**20


def _partner(g, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Where the folded columns ``q`` of a real image's spectrum have their conjugates: the
    spectrum at −f is the conjugate of that at f, so alias (a, b) of the view frequency (p, q)
    is the conjugate of alias (a', b') of (−p, −q). Returns the rows ``(−p) mod My``, the
    columns ``(−q) mod Mx`` and the alias index a'·d + b' (My, len(q), d²) (a' = d−1−a, or
    −a mod d on row 0; b' likewise)."""
    d = g.d
    my, mx = g.grid
    dev = q.device
    p = torch.arange(my, device=dev)
    k = torch.arange(d, device=dev)
    a = torch.where(p[:, None] > 0, d - 1 - k[None], torch.remainder(-k, d)[None])  # (My, d)
    b = torch.where(q[:, None] > 0, d - 1 - k[None], torch.remainder(-k, d)[None])  # (nq, d)
    alias = (a[:, None, :, None] * d + b[None, :, None, :]).reshape(my, len(q), d * d)
    return torch.remainder(-p, my), torch.remainder(-q, mx), alias


def _alias_index(g, device) -> tuple[torch.Tensor, torch.Tensor]:
    """Where alias (a, b) of view frequency (p, q < Mx//2+1) lies in a real image's half
    spectrum (Ny, Nx//2+1), flattened: frequency (p + a·My, q + b·Mx) itself, or, beyond the
    half, the conjugate of (−(p + a·My), Nx − q − b·Mx). Returns the flat indices
    (My·(Mx//2+1)·d²,) in the folded layout (p, q, a·d + b) and whether each is conjugated."""
    d = g.d
    my, mx = g.grid
    ny, nx = g.domain
    nh = nx // 2 + 1
    k = torch.arange(d, device=device)
    ky = torch.arange(my, device=device)[:, None, None, None] + my * k[None, None, :, None]
    kx = (torch.arange(mx // 2 + 1, device=device)[None, :, None, None]
          + mx * k[None, None, None, :])
    ky, kx = torch.broadcast_tensors(ky, kx)
    inside = kx < nh
    rows = torch.where(inside, ky, torch.remainder(-ky, ny))
    cols = torch.where(inside, kx, nx - kx)
    return (rows * nh + cols).flatten(), ~inside.flatten()


def _conjugates(values: torch.Tensor, partner) -> torch.Tensor:
    """The conjugate partners (:func:`_partner`) of folded values (My, Mx', k[, k])."""
    rows, cols, alias = partner
    out = values.index_select(0, rows).index_select(1, cols).conj()
    if values.ndim == 3:
        return torch.gather(out, 2, alias)
    k = alias.shape[-1]
    out = torch.gather(out, 2, alias[..., None].expand(-1, -1, -1, k))
    return torch.gather(out, 3, alias[:, :, None, :].expand(-1, -1, k, -1))


class FoldedNormal:
    """G(p, q) = fft-domain AᵀA of ``op``, built once for the view frequencies q < Mx//2+1
    (:attr:`half`, (My, Mx//2+1, d², d²) complex64): the others are their conjugates with the
    aliases permuted (a real PSF's spectrum is Hermitian), and so are the right-hand sides and
    solutions of real images, so products, factorisations and solves run on that half.

    Memory: about My·Mx·d⁴·4 bytes (2,100² px domain, d = 3: 145 MB), and while it is built a
    few times :data:`SLAB_BYTES` more (the OTF values of a slab of frequency rows, every view at
    once). Calls never change the object.
    """

    def __init__(self, op: PhaseSpaceOperator) -> None:
        g = op.geometry
        self.op, self.geometry, self.device = op, g, op.device
        d = g.d
        my, mx = g.grid
        ny, nx = g.domain
        nh = nx // 2 + 1
        mh = mx // 2 + 1
        cols = torch.arange(mx, device=self.device)
        self._rest = _partner(g, cols[mh:])  # the columns made from the half
        self._own = _partner(g, cols[:mh])  # the half's own conjugates (symmetrised input)
        # the aliases of the half's view frequencies read out of the operator's half spectra
        # (a real PSF's spectrum is Hermitian: H(ky, kx) = conj H(−ky, Nx − kx) for
        # kx >= Nx//2 + 1), not from new FFTs nor full spectra
        index, conj = _alias_index(g, self.device)
        otf = op.otf.reshape(op.n_views, ny * nh)
        mat = torch.empty((my * mh, d * d, d * d), dtype=torch.complex64, device=self.device)
        # a few frequency rows at a time, every view at once: the gathered values stay near
        # SLAB_BYTES whatever the number of views
        per_row = mh * d * d
        rows = max(1, SLAB_BYTES // (op.n_views * per_row * 8))
        for p0 in range(0, my, rows):
            part = slice(p0 * per_row, min(p0 + rows, my) * per_row)
            h = otf.index_select(1, index[part])
            h = torch.where(conj[part], h.conj(), h).T.reshape(-1, d * d, op.n_views)
            out = mat[p0 * mh:min(p0 + rows, my) * mh]
            out.zero_()
            for i in range(0, op.n_views, op.chunk):  # the views' sum in the operator's chunks
                c = h[..., i:i + op.chunk]
                out += torch.matmul(c.conj(), c.transpose(-1, -2))
        self.half = (mat / (d * d)).reshape(my, mh, d * d, d * d)
        self.scale = float(self.half.diagonal(dim1=-2, dim2=-1).real.max())

    @property
    def matrix(self) -> torch.Tensor:
        """G for every view frequency, (My, Mx, d², d²) complex64 (made from :attr:`half`)."""
        return self.expand(self.half)

    def expand(self, half: torch.Tensor) -> torch.Tensor:
        """(My, Mx//2+1, k[, k]) folded values of a real image's spectrum (or of a matrix per
        frequency acting on them) → (My, Mx, k[, k]): the other columns by conjugate symmetry
        with the aliases permuted."""
        mh = half.shape[1]
        rest = _conjugates(half, self._rest)
        out = torch.empty((half.shape[0], mh + rest.shape[1], *half.shape[2:]),
                          dtype=half.dtype, device=half.device)
        out[:, :mh] = half
        out[:, mh:] = rest
        return out

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
    def _folded_half(self, image) -> torch.Tensor:
        """(My, Mx//2+1, d²) folded spectrum of a real domain image."""
        x = torch.as_tensor(image, dtype=torch.float32, device=self.device)
        full = self.fold(torch.fft.fft2(x))
        # the mean with the conjugates: exactly Hermitian, as the real image's spectrum is
        return (full[:, :self.half.shape[1]] + _conjugates(full, self._own)) / 2

    def _image(self, folded_half: torch.Tensor) -> torch.Tensor:
        """The real domain image of a folded half spectrum (:meth:`expand`, then inverse)."""
        return torch.fft.ifft2(self.unfold(self.expand(folded_half))).real

    def apply(self, image) -> torch.Tensor:
        """AᵀA·image on the circular domain, through G (equals op.adjoint(op.forward(image)))."""
        y = torch.einsum("pqij,pqj->pqi", self.half, self._folded_half(image))
        return self._image(y)

    def eigenvalues(self) -> torch.Tensor:
        """(My, Mx, d²) eigenvalues of G per view frequency, ascending (squared singular values
        of the measurement, in the units of op: divide by their maximum for a relative scale)."""
        ev = torch.linalg.eigvalsh(self.half)  # a conjugate's eigenvalues are the same
        rows, cols, _ = self._rest
        return torch.cat([ev, ev.index_select(0, rows).index_select(1, cols)], dim=1)

    def factor(self, lam: float, weights: torch.Tensor | None = None) -> torch.Tensor:
        """The regularised system (G + lam·R)⁻¹ per view frequency q < Mx//2+1 (the others are
        its conjugates, :meth:`expand`), (My, Mx//2+1, d², d²) complex128, R = diag(``weights``)
        (My, Mx, d²) in the folded layout (default: the identity; real and even, as every
        regulariser of a real image); ``lam`` is relative to G's largest diagonal (:attr:`scale`).
        For :meth:`solve`.

        Cholesky factorisation, then the explicit inverse (applying it is one batched d² x d²
        product per solve), in double precision: G's eigenvalues span ~1e-6..1 (float32 would
        lose the small ones). Timings: ``docs/decisions.md``."""
        if not lam > 0:
            raise ValueError(f"lam must be > 0, got {lam}")
        scale = self.scale
        a = self.half.to(torch.complex128)
        diag = a.diagonal(dim1=-2, dim2=-1)
        if weights is None:
            diag += lam * scale
        else:
            diag += (lam * scale) * weights[:, :a.shape[1]].to(torch.float64)
        chol, info = torch.linalg.cholesky_ex(a)
        del a
        if bool((info != 0).any()):
            raise ValueError(f"lam = {lam} is too small to make AᵀA + lam·R positive definite")
        return torch.cholesky_inverse(chol)

    def solve(self, rhs_image, inverse: torch.Tensor) -> torch.Tensor:
        """(AᵀA + lam·R)⁻¹ rhs on the circular domain, with ``inverse`` from :meth:`factor`."""
        b = self._folded_half(rhs_image)
        x = torch.matmul(inverse, b.to(torch.complex128).unsqueeze(-1)).squeeze(-1)
        return self._image(x.to(torch.complex64))
