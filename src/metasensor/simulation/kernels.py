"""Fine-grid PSFs collapsed exactly onto the pixel grid (the simulator's anti-inverse-crime step).

The simulator's scene model is continuous: the pixel scene ``I`` is up-sampled 3× per axis by
cubic-spline interpolation (``scipy.ndimage.zoom(order=3, grid_mode=True)``, flux preserving:
each fine cell carries 1/9 of the interpolated radiance), convolved with PSFs sampled on the 3×
finer grid (``view_psfs(..., subsample=3)``), and sampled at the lenslet centres (views) or
integrated over the sensor pixels (2D sensor). Both steps are linear and commute with whole-pixel
shifts, so the fine-grid computation equals a pixel-grid convolution with the effective kernel

    H_eff(k) = (H_fine ⊛ u)(3k)              (views: value at the lenslet-centre fine cell)
    H_eff(k) = (H_fine ⊛ u ⊛ box3)(3k)       (2D sensor: integrated over the 3×3 fine cells)

where ``u`` is the spline up-sampler's response to one unit pixel (sums to 1). This identity is
exact (tested against a brute-force fine-grid simulation); it cuts the work 9×. The data are
still made by the finer continuous model, never by the pixel-pitch PSFs reconstructions use.
"""

from __future__ import annotations

import functools

import numpy as np
import torch
from scipy import ndimage

__all__ = ["SUBSAMPLE", "upsampler_response", "collapse", "crop_energy", "fine_view_bank",
           "fine_widefield"]

SUBSAMPLE = 3


UPSAMPLERS = ("spline", "box", "point")


@functools.lru_cache(maxsize=8)
def upsampler_response(factor: int = SUBSAMPLE, kind: str = "spline") -> np.ndarray:
    """1-D response ``u1`` of the up-sampler to a unit pixel, indexed by the fine offset from that
    pixel's central fine cell (odd length, centre = offset 0), normalised to sum 1.

    ``"spline"`` (default): cubic-spline interpolation of the radiance (a continuous scene);
    ``"box"``: each pixel a uniform square; ``"point"``: each pixel a point source at its centre
    (star fields, beads; with this model a one-pixel scene reproduces ``view_psfs`` exactly).
    """
    if kind == "point":
        return np.ones(1)
    if kind == "box":
        return np.ones(factor) / factor
    if kind != "spline":
        raise ValueError(f"upsample must be one of {UPSAMPLERS}, got {kind!r}")
    n = 41
    delta = np.zeros(n)
    delta[n // 2] = 1.0
    fine = ndimage.zoom(delta, factor, order=3, grid_mode=True, mode="grid-constant")
    centre = factor * (n // 2) + factor // 2
    keep = np.abs(fine) > 1e-6 * np.abs(fine).max()
    half = int(np.max(np.abs(np.nonzero(keep)[0] - centre)))
    u1 = fine[centre - half:centre + half + 1]
    return u1 / u1.sum()


def collapse(fine: np.ndarray, factor: int = SUBSAMPLE, integrate: bool = False,
             upsample: str = "spline") -> np.ndarray:
    """Effective pixel-grid kernels from fine kernels ``(..., Kf, Kf)`` (Kf odd, centre = zero
    displacement, sampled at pitch/factor, value = response of one point per unit flux).

    ``integrate=False``: sampled at the central fine cell of each pixel (view samples);
    ``integrate=True``: summed over the factor×factor fine cells of each pixel (2D sensor).
    ``upsample``: the scene model, see :func:`upsampler_response`.
    Returns ``(..., K, K)`` float32 with K odd, centre = zero displacement.
    """
    fine = np.asarray(fine, dtype=np.float32)
    u1 = upsampler_response(factor, upsample)
    if integrate:
        u1 = np.convolve(u1, np.ones(factor))
    lead = fine.shape[:-2]
    kf = fine.shape[-1]
    c = kf // 2
    pad = len(u1) // 2
    half = (c + pad) // factor
    # A[k, f] = u(factor*k - (f - c)): (H ⊛ u)(factor*k) = Σ_f A[k, f] H(f), per axis
    g = factor * np.arange(-half, half + 1)[:, None] - (np.arange(kf)[None, :] - c)
    amat = np.where(np.abs(g) <= pad, u1[np.clip(g + pad, 0, len(u1) - 1)], 0.0)
    at = torch.from_numpy(amat.astype(np.float32))
    out = (at @ torch.from_numpy(fine.reshape(-1, kf, kf)) @ at.T).numpy()
    return out.reshape(*lead, 2 * half + 1, 2 * half + 1).astype(np.float32)


def crop_energy(kernels: np.ndarray, keep: float = 1.0 - 1e-6) -> np.ndarray:
    """Crop ``(..., K, K)`` kernels to the smallest centred odd square holding ``keep`` of the
    total |energy| of all kernels together (the discarded rim is below ``1 - keep``)."""
    k = kernels.shape[-1]
    c = k // 2
    absk = np.abs(kernels).reshape(-1, k, k).sum(0)
    total = absk.sum()
    if total == 0:
        return kernels[..., c:c + 1, c:c + 1]
    for r in range(c + 1):
        if absk[c - r:c + r + 1, c - r:c + r + 1].sum() >= keep * total:
            return np.ascontiguousarray(kernels[..., c - r:c + r + 1, c - r:c + r + 1])
    return kernels


def _psf_module():
    try:
        from metasensor.optics import psf
    except ImportError as exc:  # pragma: no cover - optics stage not installed
        raise ImportError("metasensor.optics.psf (view_psfs/widefield_psf) is required") from exc
    return psf


def fine_view_bank(cfg, zernike=None, depth: float = 0.0, phase=None, amplitude=None,
                   device=None, subsample: int = SUBSAMPLE) -> np.ndarray:
    """``view_psfs(..., subsample=3, band_limited=True)`` (:mod:`metasensor.optics.bank`)
    rescaled to photons per unit point flux:
    (nnum, nnum, Kf, Kf) float32. (``view_psfs`` returns ``H_sub = per-point / subsample²``,
    each fine point carrying 1/subsample² of a pixel's flux; :func:`collapse` distributes the
    pixel's flux itself through the up-sampler ``u``, so the factor is put back here.)
    ``subsample``: another odd sub-pixel factor (1: the pixel-grid bank, for which
    :func:`collapse` with ``factor=1`` is the identity)."""
    psf = _psf_module()
    kwargs = {"subsample": int(subsample), "device": device, "band_limited": True}
    if phase is not None:
        kwargs["phase"] = phase
        kwargs["cache"] = False
    if amplitude is not None:
        kwargs["amplitude"] = amplitude
    bank = psf.view_psfs(cfg, zernike, float(depth), **kwargs)
    return np.asarray(bank, dtype=np.float32) * np.float32(int(subsample) ** 2)


def _widefield_size(cfg, zernike, depth: float, phase, sampling: float,
                    margin: float = 16.0) -> int:
    """Odd window [samples] holding the geometric ray bundle ((λ/NA) max|∇W|) plus ``margin``
    λ/NA of diffraction tails (the Airy pattern keeps ≈ 99.4 % of its energy within 16 λ/NA)."""
    t = np.linspace(-1.0, 1.0, 129)
    x, y = np.meshgrid(t, t)
    inside = x * x + y * y <= 1.0
    w = np.zeros_like(x)
    if zernike is not None:
        from metasensor.optics.zernike import wavefront

        w = w + np.asarray(wavefront(np.asarray(zernike, float), x, y))
    if phase is not None:
        w = w + np.where(inside, np.asarray(phase(x, y), dtype=np.float64), 0.0)
    if depth:
        w = w + depth / cfg.wavelength * (np.sqrt(1 - cfg.na**2 * np.minimum(x * x + y * y, 1))
                                          - 1)
    gy, gx = np.gradient(w, t[1] - t[0])
    inner = inside & (np.hypot(x, y) <= 1.0 - 2 * (t[1] - t[0]))
    gmax = float(np.hypot(gx, gy)[inner].max()) if inner.any() else 0.0
    lam_na = cfg.wavelength / cfg.na
    return 2 * int(np.ceil((lam_na * (gmax + margin)) / sampling)) + 1


def fine_widefield(cfg, zernike=None, depth: float = 0.0, phase=None, device=None) -> np.ndarray:
    """``widefield_psf`` sampled at pixel_pitch/3 (fine-cell integrated, sums to ≈ 1), on a window
    sized by :func:`_widefield_size` (the ray bundle plus 16 λ/NA)."""
    psf = _psf_module()
    sampling = cfg.pixel_pitch / SUBSAMPLE
    kwargs = {"device": device, "size": _widefield_size(cfg, zernike, depth, phase, sampling)}
    if phase is not None:
        kwargs["phase"] = phase
    out = psf.widefield_psf(cfg, zernike, float(depth), sampling, **kwargs)
    return np.asarray(out, dtype=np.float32)


def as_kernels(bank: np.ndarray, device) -> torch.Tensor:
    """(nnum, nnum, K, K) or (K, K) → (B, K, K) float32 tensor on ``device``."""
    bank = np.asarray(bank, dtype=np.float32)
    if bank.ndim == 2:
        bank = bank[None]
    return torch.from_numpy(np.ascontiguousarray(bank.reshape(-1, *bank.shape[-2:]))).to(device)
