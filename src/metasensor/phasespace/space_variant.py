"""A space-variant phase-space operator: PSF banks at several field points, blended smoothly.

Where the aberration changes inside a block, one bank per block is wrong towards the block's
borders (the deconvolution with a wrong PSF leaves comb-like fringes along edges there). This
operator interpolates the PSF across the field instead (Nagy & O'Leary, "Restoring images
degraded by spatially variant blur", SIAM J. Sci. Comput. 19, 1998): with banks ``H_f`` at
``F`` field points and smooth weights ``w_f(y, x) >= 0``, ``Σ_f w_f = 1`` (a partition of unity
over the estimate's domain),

    A x  = Σ_f A_f (w_f · x),        Aᵀ y = Σ_f w_f · (A_fᵀ y),

each ``A_f`` the phase-space operator of bank ``f``
(:class:`metasensor.phasespace.operator.PhaseSpaceOperator`, applied by FFT). A point at
``(y, x)`` is blurred by ``Σ_f w_f(y, x) H_f``, so PSFs vary continuously and blocks whose
field points and weights agree on their shared borders see the same PSFs there. The simulator
renders field-dependent blur the same way (:mod:`metasensor.simulation.layers`).

:func:`corner_weights` gives the bilinear weights of the four corners of a block's core (field
points on the block grid's corners: neighbouring blocks share them), or of a finer grid of
points spanning the core, held constant beyond the core.

The forward sums the banks' folded spectra before one inverse transform per view; the adjoint
shares the views' small FFTs between banks. Cost: ``F`` times one bank's (minus the shared
transforms). The normal operator is not block-diagonal in the Fourier domain, so
:meth:`SpaceVariantOperator.normal` returns the folded normal operator of the weighted mean bank
(a preconditioner, ``normal_is_exact = False``) and :meth:`SpaceVariantOperator.masked_normal`
the exact product ``Aᵀ M A``; the HQS x-step then runs preconditioned conjugate gradients.

Hand-written: no library has the sampled phase-space operator.
"""

from __future__ import annotations

import numpy as np
import torch

from metasensor.phasespace.geometry import Geometry, GridShapes
from metasensor.phasespace.operator import PhaseSpaceOperator

__all__ = ["SpaceVariantOperator", "corner_weights", "pad_banks"]


def pad_banks(banks) -> list[np.ndarray]:
    """Banks ``(V, K_f, K_f)`` (odd K_f) zero-padded about their centre to the largest K."""
    arrs = [np.asarray(b, dtype=np.float32) for b in banks]
    k = max(a.shape[-1] for a in arrs)
    out = []
    for a in arrs:
        p = (k - a.shape[-1]) // 2
        out.append(np.pad(a, [(0, 0)] * (a.ndim - 2) + [(p, p), (p, p)]) if p else a)
    return out


def corner_weights(geometry: Geometry, window_origin: tuple[int, int],
                   core: tuple[int, int, int, int], points: int = 2) -> np.ndarray:
    """Bilinear weights ``(points², Ny, Nx)`` of a block core's field points on an estimate
    domain.

    Parameters
    ----------
    geometry : Geometry
        The estimate's domain (:func:`metasensor.phasespace.operator.make_geometry`).
    window_origin : (int, int)
        Output pixel (field coordinates) of the window's pixel (0, 0).
    core : (y0, y1, x0, x1)
        The block's core in output pixels (continuous coordinates: pixel i covers [i, i + 1)).
    points : int
        Field points per side, evenly spaced from the core's first edge to its last (2: the
        corners), ordered row-major: (y0, x0), (y0, x1), (y1, x0), (y1, x1) for 2.

    Returns
    -------
    numpy.ndarray
        float32 ``(points², Ny, Nx)``, non-negative, summing to 1 at every pixel; piecewise
        bilinear (hat functions of the points) inside the core, constant beyond it along each
        axis (the nearest core edge's value).
    """
    ny, nx = geometry.domain
    oy, ox = geometry.offset
    y0, y1, x0, x1 = core
    if y1 <= y0 or x1 <= x0:
        raise ValueError(f"core must be a non-empty box (y0, y1, x0, x1), got {core}")
    if isinstance(points, bool) or int(points) != points or points < 2:
        raise ValueError(f"points must be an integer >= 2, got {points!r}")
    n = int(points)
    gy = window_origin[0] + np.arange(ny) - oy + 0.5  # field coordinate of each pixel centre
    gx = window_origin[1] + np.arange(nx) - ox + 0.5
    ty = np.clip((gy - y0) / (y1 - y0), 0.0, 1.0) * (n - 1)
    tx = np.clip((gx - x0) / (x1 - x0), 0.0, 1.0) * (n - 1)
    knots = np.arange(n, dtype=np.float64)
    wy = [np.clip(1.0 - np.abs(ty - k), 0.0, 1.0) for k in knots]
    wx = [np.clip(1.0 - np.abs(tx - k), 0.0, 1.0) for k in knots]
    return np.stack([np.outer(wy[a], wx[b]) for a in range(n) for b in range(n)]
                    ).astype(np.float32)


class SpaceVariantOperator(GridShapes):
    """``A x = Σ_f A_f (w_f · x)``: PSF banks blended by a partition of unity (module docstring).

    Parameters
    ----------
    psfs : sequence of array_like
        ``F`` banks ``(V, K, K)`` (one K, odd; :func:`pad_banks`), the same views in the same
        order, in photons per unit image intensity.
    weights : array_like
        ``(F, Ny, Nx)`` non-negative weights on the estimate domain, summing to 1 per pixel.
    geometry : Geometry
    device : str or torch.device, optional
    chunk : int
        Views transformed together.

    Notes
    -----
    Has the methods the HQS solver uses (``forward``, ``adjoint``, ``sensitivity``, ``normal``,
    ``masked_normal``, ``samples_and_mask``, ``norm``); Richardson–Lucy's per-view-subset
    building blocks are not provided. Memory: ``F + 1`` banks' OTFs. Calls never change it.
    """

    normal_is_exact = False

    def __init__(self, psfs, weights, geometry: Geometry, device=None, chunk: int = 8):
        banks = [np.asarray(p.cpu() if isinstance(p, torch.Tensor) else p, np.float32)
                 for p in psfs]
        if not banks:
            raise ValueError("psfs must hold at least one bank")
        if len({b.shape for b in banks}) != 1:
            raise ValueError(f"banks must share one shape (V, K, K), got "
                             f"{sorted({b.shape for b in banks})}")
        self.ops = [PhaseSpaceOperator(b, geometry, device, chunk) for b in banks]
        ref = self.ops[0]
        self.device, self.geometry, self.chunk = ref.device, geometry, ref.chunk
        self.n_views, self.k, self.radius = ref.n_views, ref.k, ref.radius
        w = torch.as_tensor(np.asarray(weights, np.float32), device=self.device)
        if tuple(w.shape) != (len(banks), *geometry.domain):
            raise ValueError(f"weights must have shape {(len(banks), *geometry.domain)}, "
                             f"got {tuple(w.shape)}")
        if not torch.isfinite(w).all() or float(w.min()) < 0:
            raise ValueError("weights must be finite and non-negative")
        if float((w.sum(0) - 1.0).abs().max()) > 1e-4:
            raise ValueError("weights must sum to 1 at every pixel (a partition of unity)")
        self.weights = w
        share = w.mean(dim=(-2, -1)).cpu().numpy()
        mean_bank = sum(float(s) * b for s, b in zip(share, banks, strict=True))
        self.psf = torch.as_tensor(mean_bank, device=self.device)
        self._mean_op: PhaseSpaceOperator | None = None
        self.psf_sums = self.psf.sum(dim=(-2, -1))

    def samples_and_mask(self, data, mask):
        """As :meth:`PhaseSpaceOperator.samples_and_mask`."""
        return self.ops[0].samples_and_mask(data, mask)

    def _views(self, views):
        return list(self.ops[0]._chunks(views))

    def forward(self, image, views=None) -> torch.Tensor:
        """``A·image``: ``(V, My, Mx)`` view samples of the ``(Ny, Nx)`` domain image."""
        image = torch.as_tensor(image, dtype=torch.float32, device=self.device)
        if tuple(image.shape) != self.geometry.domain:
            raise ValueError(f"image must have the domain shape {self.geometry.domain}, "
                             f"got {tuple(image.shape)}")
        d = self.geometry.d
        my, _ = self.geometry.grid
        nx = self.geometry.domain[1]
        nh = nx // 2 + 1
        specs = [torch.fft.rfft2(wf * image).view(d, my, nh) for wf in self.weights]
        out = []
        for c in self._views(views):
            folded = None
            for op, spec in zip(self.ops, specs, strict=True):
                otf = op.otf[c].view(-1, d, my, nh)
                for k in range(d):
                    folded = (torch.mul(otf[:, k], spec[k]) if folded is None
                              else folded.addcmul_(otf[:, k], spec[k]))
            out.append(self.ops[0].samples_from_folded(folded))
        return torch.cat(out)

    def adjoint(self, samples, views=None) -> torch.Tensor:
        """``Aᵀ·samples``: the ``(Ny, Nx)`` domain image of ``(V, My, Mx)`` view samples."""
        samples = torch.as_tensor(samples, dtype=torch.float32, device=self.device)
        n = self.n_views if views is None else len(views)
        if tuple(samples.shape) != (n, *self.geometry.grid):
            raise ValueError(f"samples must have shape {(n, *self.geometry.grid)}, "
                             f"got {tuple(samples.shape)}")
        accs = [op.new_conj_accumulator() for op in self.ops]
        start = 0
        for c in self._views(views):
            count = len(range(self.n_views)[c]) if isinstance(c, slice) else len(c)
            tiles = self.ops[0].conj_tiles(samples[start:start + count])  # shared by the banks
            for op, acc in zip(self.ops, accs, strict=True):
                op.backproject_conj(None, c, acc, tiles)
            start += count
        out = torch.zeros(self.geometry.domain, device=self.device)
        for op, acc, wf in zip(self.ops, accs, self.weights, strict=True):
            out.add_(wf * op.image_from_conj(acc))
        return out

    def sensitivity(self, mask: torch.Tensor, views=None) -> torch.Tensor:
        """``Aᵀ`` of ``mask`` (My, Mx) on every view in ``views``: (Ny, Nx)."""
        out = torch.zeros(self.geometry.domain, device=self.device)
        for op, wf in zip(self.ops, self.weights, strict=True):
            out.add_(wf * op.sensitivity(mask, views))
        return out

    def mean_operator(self) -> PhaseSpaceOperator:
        """The phase-space operator of the weighted mean bank (built once)."""
        if self._mean_op is None:
            self._mean_op = PhaseSpaceOperator(self.psf, self.geometry, self.device, self.chunk)
        return self._mean_op

    def normal(self):
        """The folded normal operator of the mean bank: an approximation of AᵀA (a
        preconditioner; ``normal_is_exact`` is False)."""
        from metasensor.phasespace.normal import FoldedNormal

        return FoldedNormal(self.mean_operator())

    def masked_normal(self, mask, normal=None):
        """``v -> Aᵀ M A v`` for the observed samples ``mask`` (My, Mx), exact (direct)."""
        mf = torch.as_tensor(mask, dtype=torch.bool, device=self.device).to(torch.float32)
        return lambda v: self.adjoint(self.forward(v) * mf)

    def norm(self, iterations: int = 30, seed: int = 0) -> float:
        """‖A‖₂ by power iteration on AᵀA from a seeded random image."""
        from metasensor.phasespace.dottest import power_norm

        return power_norm(self, iterations, seed)
