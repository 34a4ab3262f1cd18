"""One DAO block's data and its two steps: the deconvolved mean image and the view shifts.

Hand-written (the paper's Methods, "ISA with multisite DAO in wave optics"; the loop that drives
it is :func:`metasensor.dao.estimate.run_dao`, whose docstring states the algorithm and the
known-region weights added here).
"""

from __future__ import annotations

import numpy as np
import torch

from metasensor.align.shifts import fourier_shift, measure_shifts_torch, shift_precision
from metasensor.backend import as_tensor
from metasensor.config import SystemConfig
from metasensor.solvers.krishnan_fergus import beta_schedule, kf_deconv, pad_fade, psf2otf

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
        self.betas = beta_schedule()
        self._up = None

    def _up_chunk(self, b: slice) -> torch.Tensor:
        if self._up is not None:
            return self._up[b]
        return _upsample(self.views[b] / self.scale, self.d)

    def _otf_chunk(self, b: slice) -> torch.Tensor:
        return self.otf[b] if self.otf is not None else psf2otf(self.kernels[b], self.shape)

    def set_psfs(self, bank: np.ndarray) -> None:
        n = self.cfg.nnum
        h = bank.reshape(n * n, *bank.shape[-2:])[self.used.ravel()]
        h = as_tensor(h[:, _crop_slice(h)][:, :, _crop_slice(h.transpose(0, 2, 1))],
                      self.views.device)
        self.energy = h.sum(dim=(-2, -1)).clamp(min=1e-12)
        self.kernels = h / self.energy[:, None, None]
        k = h.shape[-1]
        self.pad = k // 2 + 4
        hh, ww = self.hw
        self.shape = (hh + 2 * self.pad, ww + 2 * self.pad)
        nv, grid = self.views.shape[0], self.shape[0] * self.shape[1]
        cached = nv * (hh * ww * 4 + grid * 4) <= self.cache_bytes  # views + half spectra
        self.chunk = max(1, min(self.chunk0, self.cache_bytes // (12 * 4 * grid)))
        if cached and self._up is None:
            self._up = _upsample(self.views / self.scale, self.d)
        elif not cached:
            self._up = None
        self.otf = psf2otf(self.kernels, self.shape) if cached else None
        dom = torch.zeros(self.shape, device=self.views.device, dtype=self.views.dtype)
        dom[self.pad:self.pad + hh, self.pad:self.pad + ww] = 1.0
        self.domain_spec = torch.fft.rfft2(dom)
        d = self.d
        self.sample_weight = torch.cat([  # (B, h, w), fixed while the PSFs are
            self.reliability(self._inside(slice(a, a + self.chunk))[:, d // 2::d, d // 2::d])
            for a in range(0, nv, self.chunk)])

    def _inside(self, b: slice) -> torch.Tensor:
        """Fraction (chunk, H, W) of each view pixel's predicted light that comes from image
        pixels inside the block (1_block ⊛ H; kernels have unit sum)."""
        p = self.pad
        hh, ww = self.hw
        spec = self.domain_spec * self._otf_chunk(b)
        return torch.fft.irfft2(spec, s=self.shape)[:, p:p + hh, p:p + ww].clamp(0.0, 1.0)

    def reliability(self, frac: torch.Tensor) -> torch.Tensor:
        """Weight from an inside fraction: 0 below ``self.known``, rising to 1 at 1 (squared
        ramp)."""
        t = self.known
        return ((frac - t) / (1.0 - t)).clamp(0.0, 1.0) ** 2

    def estimate(self, shifts_px: torch.Tensor) -> torch.Tensor:
        """I = Σ_uv e_uv Deconv(V_uv(p + s_uv), Ĥ_uv) / Σ e_uv on the pixel grid (H, W).

        Not weighted by the known region (unlike :meth:`measure`). Measured, with the plain
        (unweighted) Zernike fit: weighting each view's estimate by the same reliability of its
        field (1_block ⋆ H) brought 3 λ closer (ED Fig. 4, 6 draws: 0.26-0.68 λ, 4 of 6 ≤ 0.3 λ,
        against 0.33-0.93 λ without) but failed at low SNR (1 λ, 10 dB: 0.28 λ against 0.15 λ;
        target 0.2 λ); weighting by the fraction itself kept 0.15 λ at 10 dB but ended 3 λ
        draw 1 at 0.33 / 0.81 λ. With the precision-weighted fit (``run_dao``'s default) the
        reliability weighting gives 0.111 λ at 10 dB, and on the one 3 λ draw this estimator alone
        misses (astronaut, draw 1: 0.306 λ) it ends at 0.255 λ but wanders 0.22-0.34 λ over updates
        4-8; not adopted without the full ED Fig. 4 re-run. The paper's estimator
        (``run_dao(estimator="views")``); the default is :meth:`estimate_isa`."""
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
        # each deconvolved view estimates I (kernels have unit sum, views carry e_uv·I)
        return (acc / self.energy.sum()).clamp(min=0)

    def estimate_isa(self, iterations: int = 5, subsets: int = 16) -> torch.Tensor:
        """I = the block's ISA (phase-space Richardson–Lucy,
        :func:`~metasensor.solvers.richardson_lucy.richardson_lucy`, the authors' spiral view
        order) of all used views with the current PSFs, on the pixel grid (H, W) at the scale of
        :meth:`estimate`.

        Not in the paper, whose intermediate image is :meth:`estimate` (the mean of the views'
        separate deconvolutions). The joint deconvolution resolves what no single view does, so
        the predictions S_d(I ⊛ H_uv) carry the views' detail and the shifts measured against them
        are less biased. Measured (240-px block, 3 λ, 30 dB, starting from the *true*
        aberration): one update moved the estimate 0.035 / 0.059 λ r.m.s. away (astronaut /
        camera, draw 1) against 0.172 / 0.181 λ with :meth:`estimate` (0.035 / 0.051 λ with the
        sparse-gradient solver in place of RL: no better, 8x slower). Shifts are not applied:
        ``run_dao`` measures once per update with it."""
        from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
        from metasensor.solvers.richardson_lucy import richardson_lucy, subset_major, view_order

        raster = [(int(u), int(v)) for u, v in zip(*np.nonzero(self.used), strict=True)]
        pos = {p: i for i, p in enumerate(raster)}
        order = [pos[p] for p in subset_major(view_order(self.used, "spiral"), subsets)]
        idx = torch.as_tensor(order, device=self.views.device)
        psf = (self.kernels * self.energy[:, None, None])[idx]
        ky, kx = psf.shape[-2:]  # both odd (centred crops), may differ: pad to a square
        k = max(ky, kx)
        psf = torch.nn.functional.pad(psf, ((k - kx) // 2, (k - kx) // 2,
                                            (k - ky) // 2, (k - ky) // 2))
        h, w = self.views.shape[-2:]
        geometry = make_geometry((h, w), self.d, psf.shape[-1] // 2, pad=True)
        op = PhaseSpaceOperator(psf, geometry, device=self.views.device)
        data, mask = geometry.embed(self.views[idx] / self.scale)
        result = richardson_lucy(op, data, mask, iterations=iterations, subsets=subsets)
        return geometry.crop(result.estimate).to(self.views.dtype)

    def predict(self, image: torch.Tensor) -> torch.Tensor:
        """S_d(I ⊛ H_uv) for every used view → (B, h, w) (scan-step grid, view scale)."""
        p, d = self.pad, self.d
        hh, ww = image.shape
        spec = torch.fft.rfft2(pad_fade(image[None], p))
        out = []
        for a in range(0, self.views.shape[0], self.chunk):
            b = slice(a, a + self.chunk)
            conv = torch.fft.irfft2(spec * self._otf_chunk(b), s=self.shape)[:, p:p + hh,
                                                                               p:p + ww]
            out.append(conv[:, d // 2::d, d // 2::d] * self.energy[b, None, None])
        return torch.cat(out)

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
