"""The phase-space forward model of the views as an FFT operator (docs/conventions.md).

``V[u, v] = S_d(H[u, v] ⊛ I)``: every view is the image convolved with that view's PSF and
sampled every ``d = nnum // scan`` pixels. Hand-written (no library does the sampled phase-space
convolution): instead of up-sampling the views to the image grid, the sampling is modelled
exactly in the Fourier domain.

- forward: one real FFT of the estimate, then per view multiply by its OTF and *fold* the spectrum
  (the aliasing sum over the d x d sub-bands: sampling every d-th pixel) to the small spectrum of
  the sampled view, and inverse-transform at the small size;
- adjoint: small FFT of the view-domain array, *tile* its spectrum d x d times (the spectrum of the
  zero-filled up-sampled array), multiply by the conjugate OTF, accumulate over views
  (:meth:`PhaseSpaceOperator.backproject_conj`), and do one inverse real FFT at full size.

Geometry (:mod:`metasensor.phasespace.geometry`): the estimate lives on a padded domain whose
view samples sit exactly at multiples of d, so the folding is phase-free.
"""

from __future__ import annotations

import numpy as np
import torch

from metasensor.backend import resolve_device
from metasensor.phasespace.geometry import Geometry, GridShapes, make_geometry, smooth_size
from metasensor.phasespace.sampling import column_fold, sample_columns

__all__ = ["Geometry", "make_geometry", "PhaseSpaceOperator", "smooth_size"]


class PhaseSpaceOperator(GridShapes):
    """The linear map A: domain image (Ny, Nx) -> view samples (V, My, Mx), and its adjoint.

    The one owner of the phase-space model: every solver (:mod:`metasensor.solvers`), the
    registration of a bank and DAO's shift measurement apply this operator.

    Parameters
    ----------
    psf : array_like or torch.Tensor
        ``(V, K, K)`` float PSFs, K odd, centre ``K//2`` = zero displacement (one per used view,
        in the order of the data; docs/conventions.md), in photons per unit image intensity.
    geometry : Geometry
        Where the window of view samples sits in the estimate domain (:func:`make_geometry`).
    device : str or torch.device, optional
        Where the spectra live (default :func:`metasensor.backend.resolve_device`).
    chunk : int
        Views transformed together (speed against memory).

    Notes
    -----
    Holds the bank (``psf``, on the device) and its OTFs (complex64 half spectra
    ``(V, Ny, Nx//2+1)``), computed once (:meth:`drop_spectra` frees them until the next use).
    Calls never change what the operator computes.
    """

    def __init__(self, psf, geometry: Geometry, device=None, chunk: int = 8):
        self.device = resolve_device(device)
        psf_t = torch.as_tensor(psf if isinstance(psf, torch.Tensor) else np.asarray(psf),
                                dtype=torch.float32, device=self.device)
        if psf_t.ndim != 3 or psf_t.shape[-1] != psf_t.shape[-2] or psf_t.shape[-1] % 2 == 0:
            raise ValueError(
                f"psf must have shape (views, K, K) with K odd, got {tuple(psf_t.shape)}")
        if not torch.isfinite(psf_t).all():
            raise ValueError("psf contains NaN or infinite values")
        self.geometry = geometry
        self.n_views = psf_t.shape[0]
        self.k = psf_t.shape[-1]
        self.radius = self.k // 2
        ny, nx = geometry.domain
        if self.k > min(ny, nx):
            raise ValueError(f"PSF size {self.k} exceeds the estimate domain {ny}x{nx}")
        self.chunk = max(int(chunk), 1)
        self.psf = psf_t
        self._otf = self._otfs(psf_t)
        my, mx = geometry.grid
        self._cols = torch.arange(nx // 2 + 1, device=self.device) % mx
        self._xfold = column_fold(geometry, self.device)
        self.psf_sums = psf_t.sum(dim=(-2, -1))

    # ------------------------------------------------------------------ setup
    @property
    def otf(self) -> torch.Tensor:
        """The OTFs, complex64 half spectra ``(V, Ny, Nx//2+1)``: made at construction, freed
        by :meth:`drop_spectra`, remade (the same values) on the next use."""
        if self._otf is None:
            self._otf = self._otfs(self.psf)
        return self._otf

    def drop_spectra(self) -> None:
        """Free the OTFs (the operator's largest part, V·Ny·(Nx/2+1)·8 bytes) until the next
        use remakes them: for a solver that, once set up, applies derived operators only (the
        HQS loop: the folded AᵀA and the bands' own operators)."""
        self._otf = None

    def _otfs(self, psf: torch.Tensor) -> torch.Tensor:
        """rfft2 of each PSF zero-padded to the domain, centre moved to (0, 0); a pruned
        transform: along x only the K rows that hold the PSF, then along y."""
        ny, nx = self.geometry.domain
        r, k = self.radius, self.k
        out = torch.zeros((self.n_views, ny, nx // 2 + 1), dtype=torch.complex64,
                          device=self.device)
        for i in range(0, self.n_views, self.chunk):
            block = psf[i:i + self.chunk]
            rows = torch.zeros((block.shape[0], k, nx), device=self.device)
            rows[..., :k] = block
            rows = torch.fft.rfft(torch.roll(rows, shifts=-r, dims=-1), dim=-1)
            out[i:i + block.shape[0], :k] = rows
            out[i:i + block.shape[0]] = torch.fft.fft(
                torch.roll(out[i:i + block.shape[0]], shifts=-r, dims=-2), dim=-2)
        return out

    # ------------------------------------------------------------------ building blocks
    def spectrum(self, image: torch.Tensor) -> torch.Tensor:
        """Half spectrum (Ny, Nx//2+1) of a domain image."""
        return torch.fft.rfft2(image)

    def predict(self, spec: torch.Tensor, views: slice | torch.Tensor) -> torch.Tensor:
        """View samples (c, My, Mx) of the views ``views`` from an image's half spectrum."""
        d = self.geometry.d
        my, _ = self.geometry.grid
        _, nx = self.geometry.domain
        nh = nx // 2 + 1
        otf = self.otf[views].view(-1, d, my, nh)
        spec = spec.view(d, my, nh)
        # fold the rows (sampling every d-th row): Σ_k OTF·G over the d row sub-bands, fused
        folded = torch.mul(otf[:, 0], spec[0])
        for k in range(1, d):
            folded.addcmul_(otf[:, k], spec[k])
        return self.samples_from_folded(folded)

    def samples_from_folded(self, folded: torch.Tensor) -> torch.Tensor:
        """View samples (c, My, Mx) from their row-folded half spectra (c, My, Nx//2+1): the
        columns sampled in the Fourier domain (:mod:`metasensor.phasespace.sampling`)."""
        return sample_columns(folded, self._xfold, self.geometry)

    def new_conj_accumulator(self) -> torch.Tensor:
        """Zeroed (d, My, Nx//2+1) accumulator for :meth:`backproject_conj`."""
        d = self.geometry.d
        my, _ = self.geometry.grid
        nh = self.geometry.domain[1] // 2 + 1
        return torch.zeros((d, my, nh), dtype=torch.complex64, device=self.device)

    def conj_tiles(self, samples: torch.Tensor) -> torch.Tensor:
        """conj(fft2) of view samples ``(c, My, Mx)``, tiled along the columns to the half
        spectrum's ``(c, My, Nx//2+1)``: the part of :meth:`backproject_conj` that does not
        depend on the bank (operators on one geometry can share it)."""
        _, mx = self.geometry.grid
        nh = self.geometry.domain[1] // 2 + 1
        small_conj = torch.fft.ifft2(samples, norm="forward")  # = conj(fft2(samples)), real input
        reps = -(-nh // mx)
        return small_conj.repeat(1, 1, reps)[..., :nh] if reps > 1 else small_conj[..., :nh]

    def backproject_conj(self, samples: torch.Tensor, views: slice | torch.Tensor,
                         acc: torch.Tensor | None = None,
                         tiles: torch.Tensor | None = None) -> torch.Tensor:
        """Accumulate the *conjugate* of the back-projected half spectrum, Σ OTF·conj(U), into
        ``acc`` (d, My, Nh) in place; :meth:`image_from_conj` turns it into Aᵀ·samples.
        Conjugating once per sum instead of once per view chunk saves a full-size copy per chunk;
        conj(fft2(x)) of the real samples is their unnormalised inverse FFT (no copy either).
        ``tiles``: :meth:`conj_tiles` of ``samples`` when already computed (``samples`` is then
        not read)."""
        d = self.geometry.d
        my, _ = self.geometry.grid
        nh = self.geometry.domain[1] // 2 + 1
        if acc is None:
            acc = self.new_conj_accumulator()
        tiled = self.conj_tiles(samples) if tiles is None else tiles
        otf = self.otf[views]
        for i in range(otf.shape[0]):
            acc.addcmul_(otf[i].view(d, my, nh), tiled[i][None])
        return acc

    def image_from_spectrum(self, spec: torch.Tensor) -> torch.Tensor:
        ny, nx = self.geometry.domain
        return torch.fft.irfft2(spec, s=(ny, nx))

    def image_from_conj(self, acc: torch.Tensor) -> torch.Tensor:
        """The (Ny, Nx) image of a :meth:`backproject_conj` accumulator."""
        return self.image_from_spectrum(acc.conj().reshape(self.geometry.domain[0], -1))

    def _chunks(self, views=None):
        if views is None:
            for i in range(0, self.n_views, self.chunk):
                yield slice(i, min(i + self.chunk, self.n_views))
            return
        for i in range(0, len(views), self.chunk):
            yield views[i:i + self.chunk]

    def samples_and_mask(self, data, mask) -> tuple[torch.Tensor, torch.Tensor]:
        """``data`` (V, My, Mx) as float32 and ``mask`` (My, Mx) as bool on the device, checked
        against the operator's views and sample grid (one-line errors)."""
        y = torch.as_tensor(data, dtype=torch.float32, device=self.device)
        m = torch.as_tensor(mask, dtype=torch.bool, device=self.device)
        if tuple(y.shape) != (self.n_views, *self.geometry.grid):
            raise ValueError(f"data must have shape {(self.n_views, *self.geometry.grid)}, "
                             f"got {tuple(y.shape)}")
        if tuple(m.shape) != self.geometry.grid:
            raise ValueError(f"mask must have shape {self.geometry.grid}, got {tuple(m.shape)}")
        return y, m

    # ------------------------------------------------------------------ the operator
    def forward(self, image, views=None) -> torch.Tensor:
        """``A·image``, the model's view samples.

        Parameters
        ----------
        image : array_like
            ``(Ny, Nx)`` image on the domain, in photons per pixel.
        views : torch.Tensor, optional
            Indices of the views to predict (default all, in the bank's order).

        Returns
        -------
        torch.Tensor
            ``(V, My, Mx)`` float32 view samples on the domain's sample grid, in photons.
        """
        image = torch.as_tensor(image, dtype=torch.float32, device=self.device)
        if tuple(image.shape) != self.geometry.domain:
            raise ValueError(f"image must have the domain shape {self.geometry.domain}, "
                             f"got {tuple(image.shape)}")
        spec = self.spectrum(image)
        return torch.cat([self.predict(spec, c) for c in self._chunks(views)])

    def adjoint(self, samples, views=None) -> torch.Tensor:
        """``Aᵀ·samples``, the back-projection.

        Parameters
        ----------
        samples : array_like
            ``(V, My, Mx)`` view samples (``V`` = ``len(views)`` when given).
        views : torch.Tensor, optional
            Indices of the views the samples belong to (default all).

        Returns
        -------
        torch.Tensor
            ``(Ny, Nx)`` float32 domain image.
        """
        samples = torch.as_tensor(samples, dtype=torch.float32, device=self.device)
        n = self.n_views if views is None else len(views)
        if tuple(samples.shape) != (n, *self.geometry.grid):
            raise ValueError(f"samples must have shape {(n, *self.geometry.grid)}, "
                             f"got {tuple(samples.shape)}")
        acc = self.new_conj_accumulator()
        start = 0
        for c in self._chunks(views):
            count = len(range(self.n_views)[c]) if isinstance(c, slice) else len(c)
            self.backproject_conj(samples[start:start + count], c, acc)
            start += count
        return self.image_from_conj(acc)

    def sensitivity(self, mask: torch.Tensor, views=None) -> torch.Tensor:
        """Aᵀ applied to ``mask`` (My, Mx) on every view in ``views``: (Ny, Nx), >= 0 up to fp."""
        idx = slice(None) if views is None else views
        ny, nx = self.geometry.domain
        d = self.geometry.d
        my, _ = self.geometry.grid
        otf_sum = self.otf[idx].sum(dim=0)
        small = torch.fft.fft2(mask.to(torch.float32))[..., self._cols]
        spec = (otf_sum.view(d, my, -1).conj() * small[None]).reshape(ny, -1)
        return self.image_from_spectrum(spec)

    # ------------------------------------------------------------------ derived operators
    def normal(self):
        """The folded normal operator AᵀA (:class:`metasensor.phasespace.normal.FoldedNormal`),
        built from this operator's bank (My·Mx·d⁴·8 bytes)."""
        from metasensor.phasespace.normal import FoldedNormal

        return FoldedNormal(self)

    def masked_normal(self, mask, normal=None):
        """A callable ``v -> AᵀMA v`` for the observed samples ``mask`` (My, Mx)
        (:func:`metasensor.phasespace.masked_normal.masked_normal`); ``normal``: this
        operator's :meth:`normal`, when already built."""
        from metasensor.phasespace.masked_normal import masked_normal

        m = torch.as_tensor(mask, dtype=torch.bool, device=self.device)
        return masked_normal(self, self.normal() if normal is None else normal, m)

    def norm(self, iterations: int = 30, seed: int = 0) -> float:
        """The operator norm ‖A‖₂ (largest singular value), by power iteration on AᵀA from a
        seeded random image; ``iterations`` products (relative error ~ (λ₂/λ₁)^iterations)."""
        from metasensor.phasespace.dottest import power_norm

        return power_norm(self, iterations, seed)
