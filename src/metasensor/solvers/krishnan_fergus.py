"""Fast non-blind deconvolution with a hyper-Laplacian gradient prior (Krishnan & Fergus 2009).

Written here by hand (no maintained Python package implements it). Per image,

    min_x  (λ/2) ‖k ⊛ x − y‖²  +  Σ_i |(∇x)_i|^alpha,

by the half-quadratic splitting loop of :mod:`metasensor.solvers.splitting` with the
hyper-Laplacian prior of :mod:`metasensor.solvers.priors` and an exact Fourier x-step
(:class:`FourierXStep`; circular boundary, images padded with a reflection that fades to their
mean so the wrap-around is continuous). β runs the authors' schedule (1 → 256, ×2√2).

Scaling. The prior is not scale-invariant: λ refers to images with values in [0, 1] (the
authors' convention; λ = 5e4 is the value their DAO code uses, 2e3 suits ~1 % noise). Every image
is divided by its own maximum |value| before deconvolution and multiplied back afterwards, so the
result is scale-equivariant. Kernels are normalised to unit sum unless ``normalize_kernel`` is
False. Torch on CPU or CUDA (same code), batched over images (views): NumPy in and out at
:func:`hyper_laplacian_deconv`; :func:`kf_deconv` is the tensor core used by DAO.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from metasensor.backend import as_tensor, resolve_device, to_numpy
from metasensor.solvers.priors import HyperLaplacian, Prior, Transform
from metasensor.solvers.splitting import Continuation, half_quadratic_splitting

__all__ = ["hyper_laplacian_deconv", "KFOptions", "kf_deconv", "FourierXStep", "psf2otf",
           "pad_fade", "DEFAULT_LAMBDA"]

DEFAULT_LAMBDA = 5e4


def psf2otf(kernel: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """rfft2 of kernels ``(..., k1, k2)`` zero-padded to ``shape`` with their centre
    (index k//2) moved to the origin (MATLAB's psf2otf). Returns ``(..., H, W//2+1)`` complex."""
    k1, k2 = kernel.shape[-2:]
    h, w = shape
    if k1 > h or k2 > w:
        raise ValueError(f"kernel {tuple(kernel.shape[-2:])} larger than the image {shape}")
    big = kernel.new_zeros((*kernel.shape[:-2], h, w))
    big[..., :k1, :k2] = kernel
    big = torch.roll(big, shifts=(-(k1 // 2), -(k2 // 2)), dims=(-2, -1))
    return torch.fft.rfft2(big)


def pad_fade(x: torch.Tensor, pad: int) -> torch.Tensor:
    """Pad ``(..., H, W)`` by ``pad`` pixels per side: a reflection that fades (raised cosine)
    to the image mean at the outer border, so that the periodic extension is continuous."""
    if pad <= 0:
        return x
    h, w = x.shape[-2:]
    p = min(pad, h - 1, w - 1)
    mean = x.mean(dim=(-2, -1), keepdim=True)
    lead = x.shape[:-2]
    y = torch.nn.functional.pad(x.reshape(-1, 1, h, w) - mean.reshape(-1, 1, 1, 1),
                                (p, p, p, p), mode="reflect")
    if pad > p:  # images smaller than the pad: zero (= mean) beyond the reflection
        y = torch.nn.functional.pad(y, (pad - p,) * 4)
    ramp = 0.5 - 0.5 * torch.cos(math.pi * (torch.arange(pad, device=x.device, dtype=x.dtype)
                                              + 0.5) / pad)
    wy = torch.cat([ramp, torch.ones(h, device=x.device, dtype=x.dtype), ramp.flip(0)])
    wx = torch.cat([ramp, torch.ones(w, device=x.device, dtype=x.dtype), ramp.flip(0)])
    y = y * (wy[:, None] * wx[None, :])
    return y.reshape(*lead, h + 2 * pad, w + 2 * pad) + mean


class FourierXStep:
    """The x-step ``(KᵀK + μ (LᵀL + ε I)) x = rhs`` of a circular convolution with kernels of
    spectra ``otf`` ``(B or 1, H, W//2+1)``, by one Fourier division per image."""

    def __init__(self, otf: torch.Tensor, shape: tuple[int, int], transform: Transform,
                 floor: float = 0.0) -> None:
        self.shape = (int(shape[0]), int(shape[1]))
        self.den_data = otf.abs() ** 2
        sym = transform.symbol(self.shape, otf.device)[..., : self.shape[1] // 2 + 1]
        self.den_reg = (sym + float(floor)).to(self.den_data.dtype)

    def at(self, mu: float):
        denom = self.den_data + mu * self.den_reg

        def solve(rhs: torch.Tensor, x: torch.Tensor | None) -> torch.Tensor:
            return torch.fft.irfft2(torch.fft.rfft2(rhs) / denom, s=self.shape)

        return solve


def kf_deconv(y: torch.Tensor, otf: torch.Tensor, lam: float = DEFAULT_LAMBDA,
              prior: Prior = HyperLaplacian(isotropic=True), betas: list[float] | None = None,
              inner: int = 1) -> torch.Tensor:
    """Tensor core of :func:`hyper_laplacian_deconv` (used by DAO).

    Parameters
    ----------
    y : torch.Tensor
        ``(B, H, W)`` images, already scaled to ~[0, 1] and padded (circular boundary).
    otf : torch.Tensor
        ``(B or 1, H, W//2+1)`` kernel spectra (:func:`psf2otf`, unit DC gain).
    lam : float
        λ, the data weight (:mod:`metasensor.solvers.splitting`).
    prior : Prior
        Default the hyper-Laplacian, alpha 2/3.
    betas : list of float, optional
        The continuation; default Krishnan & Fergus's (:class:`Continuation`).
    inner : int
        Rounds per β.

    Returns
    -------
    torch.Tensor
        ``(B, H, W)`` deconvolved images, starting from ``y``.
    """
    h, w = y.shape[-2:]
    xstep = FourierXStep(otf, (h, w), prior.transform)
    aty = torch.fft.irfft2(otf.conj() * torch.fft.rfft2(y), s=(h, w))
    return half_quadratic_splitting(y, aty, xstep, prior, lam,
                                    Continuation().betas() if betas is None else betas, inner)


@dataclass(frozen=True)
class KFOptions:
    """Settings of :func:`hyper_laplacian_deconv` (frozen, validated).

    Attributes
    ----------
    lam : float
        λ on images scaled to [0, 1] (default 5e4).
    alpha : float
        Prior exponent, 2/3 or 1.
    continuation : Continuation
        The β schedule (default 1 → 256 in steps of 2√2).
    inner : int
        Rounds per β (default 1).
    pad : int or None
        Border added before the FFTs (default: the kernel's half size + 4).
    normalize_kernel : bool
        Scale kernels to unit sum (default True).
    isotropic : bool
        Penalise the gradient's magnitude (default True, as the phase-space HQS) rather than
        each component (:class:`~metasensor.solvers.priors.HyperLaplacian`).
    """

    lam: float = DEFAULT_LAMBDA
    alpha: float = 2.0 / 3.0
    continuation: Continuation = Continuation()
    inner: int = 1
    pad: int | None = None
    normalize_kernel: bool = True
    isotropic: bool = True

    def __post_init__(self) -> None:
        if not (isinstance(self.lam, int | float) and self.lam > 0 and math.isfinite(self.lam)):
            raise ValueError(f"lam must be positive and finite, got {self.lam!r}")
        HyperLaplacian(self.alpha, isotropic=self.isotropic)  # validates alpha, isotropic
        if self.inner < 1:
            raise ValueError(f"inner must be >= 1, got {self.inner}")


def hyper_laplacian_deconv(images, kernels, options: KFOptions | None = None, *, device=None,
                           **settings) -> np.ndarray:
    """Krishnan–Fergus deconvolution (module docstring).

    Parameters
    ----------
    images : array_like
        ``(H, W)`` or ``(B, H, W)``, not modified.
    kernels : array_like
        ``(k, k)`` (shared) or ``(B, k, k)`` (one per image, e.g. per view), centred at index
        ``k//2`` (``(k ⊛ x)(p) = Σ_q k(p − q) x(q)``).
    options : KFOptions, optional
        ``settings`` (keywords named as its fields, e.g. ``lam=2e3``) override it.
    device : str, optional

    Returns
    -------
    numpy.ndarray
        float32 of the images' shape.
    """
    from dataclasses import replace

    opts = replace(options or KFOptions(), **settings)
    lam, pad = opts.lam, opts.pad
    img = np.asarray(images)
    ker = np.asarray(kernels)
    if img.ndim not in (2, 3):
        raise ValueError(f"images must be (H, W) or (B, H, W), got shape {img.shape}")
    batched_ok = ker.ndim == 2 or (img.ndim == 3 and ker.shape[0] == img.shape[0])
    if ker.ndim not in (2, 3) or not batched_ok:
        raise ValueError(f"kernels must be (k, k) or (B, k, k) matching images, got {ker.shape}")
    if not (np.isfinite(img).all() and np.isfinite(ker).all()):
        raise ValueError("images or kernels contain NaN or infinite values")
    dev = resolve_device(device)
    y = as_tensor(img, dev)
    squeeze = y.ndim == 2
    if squeeze:
        y = y[None]
    k = as_tensor(ker, dev)
    if k.ndim == 2:
        k = k[None]
    if opts.normalize_kernel:
        ksum = k.sum(dim=(-2, -1), keepdim=True)
        if (ksum.abs() < 1e-12).any():
            raise ValueError("a kernel sums to zero; cannot normalise it")
        k = k / ksum
    if pad is None:
        pad = max(k.shape[-2:]) // 2 + 4
    # the maximum-normalised images in float64, rounded once: images that differ by a scale
    # factor normalise to the same float32 values (scale-equivariant results)
    y64 = torch.as_tensor(img, dtype=torch.float64, device=dev)
    if squeeze:
        y64 = y64[None]
    scale64 = y64.abs().amax(dim=(-2, -1), keepdim=True).clamp(min=1e-12)
    scale = scale64.to(y.dtype)
    yp = pad_fade((y64 / scale64).to(y.dtype), pad)
    otf = psf2otf(k, yp.shape[-2:])
    x = kf_deconv(yp, otf, lam=lam, prior=HyperLaplacian(opts.alpha, isotropic=opts.isotropic),
                  betas=opts.continuation.betas(), inner=opts.inner)
    h, w = y.shape[-2:]
    x = x[..., pad:pad + h, pad:pad + w] * scale
    out = to_numpy(x).astype(np.float32)
    return out[0] if squeeze else out
