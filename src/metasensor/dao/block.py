"""One DAO block's data and its two steps: the block's image estimate and the view shifts.

Hand-written (the paper's Methods, "ISA with multisite DAO in wave optics"; the loop that drives
it is :func:`metasensor.dao.estimate.run_dao`). Predictions, the known-region fractions and the
ISA estimate all use one :class:`~metasensor.phasespace.operator.PhaseSpaceOperator` of the
block's bank (:attr:`DaoBlock.op`), the operator the reconstruction fits: the shifts are
measured against the model the block is then solved with. An image on the window's pixel grid
is placed in the operator's padded domain with a reflection that fades to its mean
(:func:`metasensor.solvers.krishnan_fergus.pad_fade`).
"""

from __future__ import annotations

import numpy as np
import torch

from metasensor.align.shifts import fourier_shift, measure_shifts_torch, shift_precision
from metasensor.backend import as_tensor
from metasensor.config import SystemConfig
from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
from metasensor.phasespace.views import subset_major, view_order
from metasensor.solvers.krishnan_fergus import kf_deconv, pad_fade, psf2otf
from metasensor.solvers.richardson_lucy import RLOptions, richardson_lucy
from metasensor.solvers.splitting import Continuation

__all__ = ["DaoBlock"]


def _crop_slice(h: np.ndarray, keep: float = 0.998) -> slice:
    """Centred rows of a bank ``(B, K, K)`` holding ``keep`` of the used views' light (the bank's
    window is sized for all views, the dark outer ones included)."""
    k = h.shape[-2]
    prof = np.abs(h).sum(axis=(0, 2))
    total = prof.sum()
    c = k // 2
    for r in range(c + 1):
        if prof[c - r:c + r + 1].sum() >= keep * total:
            return slice(c - r, c + r + 1)
    return slice(0, k)


def _upsample(views: torch.Tensor, d: int) -> torch.Tensor:
    """Views (B, h, w) on the scan-step grid → (B, h·d, w·d) pixel grid (bicubic; sample Y sits
    at pixel Y·d + d//2, the align_corners=False convention for odd d)."""
    if d == 1:
        return views
    return torch.nn.functional.interpolate(views[:, None], scale_factor=d, mode="bicubic",
                                           align_corners=False)[:, 0]


class DaoBlock:
    """Geometry and data of one block: up-sampled views, their FFT padding, the PSF spectra and
    the weights of the view samples in the shift measurement (per PSF bank, :meth:`set_psfs`).

    Memory: the up-sampled views and the PSF spectra of all views are kept when they fit in
    ``cache_bytes`` (default 1 GiB); otherwise (large blocks, e.g. 2,000² px × 113 views) they
    are recomputed per chunk of views (one bicubic up-sampling and one FFT per view more per
    pass), and the chunk is reduced so that the deconvolution's ~12 grid-sized work arrays per
    view stay within the same budget."""

    known = 0.95  # inside fraction below which a predicted view sample gets no weight

    def __init__(self, views: torch.Tensor, cfg: SystemConfig, used: np.ndarray, lam: float,
                 chunk: int, cache_bytes: int = 1 << 30):
        self.cfg = cfg
        self.d = cfg.scan_step_px
        self.used = used
        self.views = views  # (B, h, w) scan-step grid, used views only
        self.scale = float(views.abs().max().clamp(min=1e-30))
        self.hw = (views.shape[-2] * self.d, views.shape[-1] * self.d)
        self.lam = lam
        self.chunk0 = max(int(chunk), 1)
        self.cache_bytes = int(cache_bytes)
        self.betas = Continuation().betas()
        self._up = None
        self._otf = None
        self._cached = False

    @property
    def otf(self) -> torch.Tensor | None:
        """The Krishnan–Fergus half spectra of the current bank's kernels, all views (made on
        first use: the ISA estimator never needs them); None where they exceed the cache."""
        if self._otf is None and self._cached:
            self._otf = psf2otf(self.kernels, self.shape)
        return self._otf

    def _up_chunk(self, b: slice) -> torch.Tensor:
        if self._up is None and self._cached:  # made on first use, kept while it fits
            self._up = _upsample(self.views / self.scale, self.d)
        if self._up is not None:
            return self._up[b]
        return _upsample(self.views[b] / self.scale, self.d)

    def _otf_chunk(self, b: slice) -> torch.Tensor:
        otf = self.otf
        return otf[b] if otf is not None else psf2otf(self.kernels[b], self.shape)

    def set_psfs(self, bank: np.ndarray) -> None:
        n = self.cfg.nnum
        h = bank.reshape(n * n, *bank.shape[-2:])[self.used.ravel()]
        h = as_tensor(h[:, _crop_slice(h)][:, :, _crop_slice(h.transpose(0, 2, 1))],
                      self.views.device)
        self.energy = h.sum(dim=(-2, -1)).clamp(min=1e-12)
        self.kernels = h / self.energy[:, None, None]
        k = max(h.shape[-2:])  # the crops are centred but may differ (a tall or wide PSF)
        self.pad = k // 2 + 4
        hh, ww = self.hw
        self.shape = (hh + 2 * self.pad, ww + 2 * self.pad)
        nv, grid = self.views.shape[0], self.shape[0] * self.shape[1]  # the KF deconvolutions
        cached = nv * (hh * ww * 4 + grid * 4) <= self.cache_bytes  # views + half spectra
        self.chunk = max(1, min(self.chunk0, self.cache_bytes // (12 * 4 * grid)))
        self._cached = cached
        if not cached:
            self._up = None
        self._otf = None  # this bank's spectra: on first use (:attr:`otf`)
        self._build_operator(h)
        self.sample_weight = self.reliability(self.inside_fraction())  # fixed with the PSFs

    def _build_operator(self, h: torch.Tensor, subsets: int = 16) -> None:
        """The phase-space operator of the bank ``h`` (B, ky, kx), padded to a square, its views
        in the authors' spiral order, subset-major (``self.order``; ``self.inverse`` maps back
        to this block's raster order of the used views)."""
        raster = [(int(u), int(v)) for u, v in zip(*np.nonzero(self.used), strict=True)]
        pos = {p: i for i, p in enumerate(raster)}
        order = [pos[p] for p in subset_major(view_order(self.used, "spiral"), subsets)]
        dev = self.views.device
        self.order = torch.as_tensor(order, device=dev)
        self.inverse = torch.argsort(self.order)
        ky, kx = h.shape[-2:]  # both odd (centred crops), may differ: pad to a square
        k = max(ky, kx)
        psf = torch.nn.functional.pad(h, ((k - kx) // 2, (k - kx) // 2, (k - ky) // 2,
                                          (k - ky) // 2))[self.order]
        geometry = make_geometry(tuple(self.views.shape[-2:]), self.d, k // 2, pad=True)
        self.op = PhaseSpaceOperator(psf, geometry, device=dev)

    def embed(self, image: torch.Tensor) -> torch.Tensor:
        """A window image ``(H, W)`` in the operator's padded domain ``(Ny, Nx)``: the image at
        its place, continued by a reflection that fades to its mean (circularly)."""
        g = self.op.geometry
        (ny, nx), (oy, ox) = g.domain, g.offset
        hh, ww = image.shape[-2:]
        pad = max(ny - hh, nx - ww) // 2 + 1
        ext = pad_fade(image[None].to(torch.float32), pad)[0]
        dev = ext.device
        iy = torch.remainder(torch.arange(ny, device=dev) - oy + pad, ext.shape[0])
        ix = torch.remainder(torch.arange(nx, device=dev) - ox + pad, ext.shape[1])
        return ext[iy][:, ix]

    def _window_samples(self, samples: torch.Tensor) -> torch.Tensor:
        """(B, My, Mx) operator samples → (B, h, w) of the window, in raster view order."""
        sy, sx = self.op.geometry.sample_slices()
        return samples[self.inverse][:, sy, sx]

    def inside_fraction(self) -> torch.Tensor:
        """Fraction ``(B, h, w)`` of each view sample's predicted light that comes from image
        pixels inside the block (``A·1_block`` over the view's light)."""
        g = self.op.geometry
        (oy, ox), (hh, ww) = g.offset, g.pixels
        inside = torch.zeros(g.domain, device=self.views.device)
        inside[oy:oy + hh, ox:ox + ww] = 1.0
        frac = self._window_samples(self.op.forward(inside)) / self.energy[:, None, None]
        return frac.clamp(0.0, 1.0)

    def reliability(self, frac: torch.Tensor) -> torch.Tensor:
        """Weight from an inside fraction: 0 below ``self.known``, rising to 1 at 1 (squared
        ramp)."""
        t = self.known
        return ((frac - t) / (1.0 - t)).clamp(0.0, 1.0) ** 2

    def estimate(self, shifts_px: torch.Tensor, tick=None) -> torch.Tensor:
        """I = Σ_uv e_uv Deconv(V_uv(p + s_uv), Ĥ_uv) / Σ e_uv on the pixel grid (H, W): the
        paper's estimate (``run_dao(estimator="views")``), each view up-sampled and deconvolved
        by Krishnan–Fergus (:func:`~metasensor.solvers.krishnan_fergus.kf_deconv`, λ = ``lam``,
        the authors' β schedule) after translating it by ``-shifts_px`` (B, 2) pixels; not
        weighted by the known region (``docs/decisions.md``). ``tick(done, total)``: called
        after every chunk of views."""
        p = self.pad
        hh, ww = self.hw
        acc = torch.zeros((hh, ww), device=self.views.device, dtype=self.views.dtype)
        for a in range(0, self.views.shape[0], self.chunk):
            b = slice(a, a + self.chunk)
            y = pad_fade(self._up_chunk(b), p)
            if shifts_px is not None:
                y = fourier_shift(y, -shifts_px[b])
            x = kf_deconv(y, self._otf_chunk(b), lam=self.lam,
                          betas=self.betas)[:, p:p + hh, p:p + ww]
            acc += (x * self.energy[b, None, None]).sum(0)
            if tick is not None:
                tick(min(a + self.chunk, self.views.shape[0]), self.views.shape[0])
        # each deconvolved view estimates I (kernels have unit sum, views carry e_uv·I)
        return (acc / self.energy.sum()).clamp(min=0)

    def estimate_isa(self, iterations: int = 5, subsets: int = 16, tick=None) -> torch.Tensor:
        """I = the block's ISA: phase-space Richardson–Lucy
        (:func:`~metasensor.solvers.richardson_lucy.richardson_lucy`, the authors' spiral view
        order) of all used views on :attr:`op`, on the window's pixel grid (H, W) at the scale
        of :meth:`estimate`. Not in the paper (its intermediate image is :meth:`estimate`); no
        shifts are applied (``run_dao`` measures once per update with it). ``tick(done,
        total)``: called after every iteration."""
        g = self.op.geometry
        data, mask = g.embed(self.views[self.order] / self.scale)
        options = RLOptions(iterations=iterations, subsets=subsets)
        done = []

        def step(n: int) -> None:
            done.append(n)
            if tick is not None:
                tick(len(done), iterations)

        result = richardson_lucy(self.op, data, mask, options, progress=step)
        return g.crop(result.estimate).to(self.views.dtype)

    def predict(self, image: torch.Tensor) -> torch.Tensor:
        """The operator's prediction of every used view → (B, h, w) (scan-step grid, view scale)
        of a window image ``(H, W)`` (:meth:`embed`)."""
        return self._window_samples(self.op.forward(self.embed(image))).to(self.views.dtype)

    def measure(self, image: torch.Tensor, max_shift_px: float,
                precision: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Shifts (B, 2) in pixels of the measured views against the prediction; with
        ``precision``, also each shift's precision (B,) in 1/pixels² (:func:`shift_precision`)."""
        pred = self.predict(image)
        mov = self.views / self.scale
        s = measure_shifts_torch(pred, mov, max_shift=max_shift_px / self.d,
                                 weight=self.sample_weight)
        if not precision:
            return s * self.d
        return s * self.d, shift_precision(pred, mov, s, weight=self.sample_weight) / self.d**2
