"""Fast non-blind deconvolution with a hyper-Laplacian gradient prior (Krishnan & Fergus 2009).

Written here by hand (no maintained Python package implements it). It solves, per image,

    min_x  (lam / 2) || k ⊛ x − y ||²  +  Σ_i |(∇_i x)|^alpha ,   ∇ = first differences in x, y,

by half-quadratic splitting: auxiliary gradients w with a penalty (beta / 2) ||∇x − w||², beta
raised from ``beta0`` to ``beta_max`` by a factor ``beta_rate`` (defaults: 1 → 256, ×2√2, the
authors' schedule). Each beta alternates

- the w-subproblem, element-wise  min_w |w|^alpha + (beta/2)(w − v)²: solved in closed form for
  alpha = 2/3 (the roots of a quartic, :func:`solve_w`) and alpha = 1 (soft thresholding);
- the x-subproblem, a quadratic solved exactly with FFTs (circular boundary; images are padded
  with a reflection that fades to the mean, so the wrap-around is continuous).

Scaling. The prior is not scale-invariant: ``lam`` refers to images with values in [0, 1] (the
authors' convention; ``lam = 5e4`` is the value their DAO code uses, ``2e3`` suits ~1 % noise).
Every image is therefore divided by its own maximum |value| before deconvolution and multiplied
back afterwards, so the result is scale-equivariant. Kernels are normalised to unit sum; pass
``normalize_kernel=False`` to keep their gain.

Torch on CPU or CUDA (same code), batched over images (views). NumPy in, NumPy out at the public
function :func:`hyper_laplacian_deconv`; :func:`kf_deconv` is the tensor core used by DAO.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

from metasensor.backend import as_tensor, resolve_device, to_numpy

__all__ = ["solve_w", "solve_w_table", "hyper_laplacian_deconv", "kf_deconv", "beta_schedule",
           "psf2otf", "pad_fade", "DEFAULT_LAMBDA"]

DEFAULT_LAMBDA = 5e4


def beta_schedule(beta0: float = 1.0, beta_max: float = 256.0,
                  beta_rate: float = 2.0 * math.sqrt(2.0)) -> list[float]:
    """The continuation values of beta: beta0, beta0·rate, ... while < beta_max (KF's loop)."""
    if not (beta0 > 0 and beta_max >= beta0 and beta_rate > 1):
        raise ValueError(f"bad beta schedule: beta0={beta0}, beta_max={beta_max}, "
                         f"beta_rate={beta_rate}")
    out, beta = [], float(beta0)
    while beta < beta_max:
        out.append(beta)
        beta *= beta_rate
    return out or [float(beta0)]


def _cbrt(x: torch.Tensor) -> torch.Tensor:
    return torch.sign(x) * torch.abs(x).pow(1.0 / 3.0)


def _stationary_two_thirds(a: torch.Tensor, beta: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Largest stationary point w = t³ > 0 of |w|^(2/3) + (beta/2)(w − a)² for a ≥ 0 (float64),
    and the mask of the elements where it exists.

    Stationarity with w = t³ gives the depressed quartic t⁴ − a t + c = 0, c = 2 / (3 beta).
    Ferrari: with m the real positive root of the resolvent cubic m³ − c m − a²/8 = 0 and
    s = sqrt(2 m), the largest root is t = (s + sqrt(s a / m − 2 m)) / 2 (real iff s a/m ≥ 2m).
    """
    c = 2.0 / (3.0 * beta)
    # resolvent cubic m^3 + P m + Q = 0 with P = -c, Q = -a^2/8 (Cardano / trigonometric)
    P = -c
    Q = -(a * a) / 8.0
    disc = (Q / 2.0) ** 2 + (P / 3.0) ** 3
    sq = torch.sqrt(torch.clamp(disc, min=0.0))
    m_cardano = _cbrt(-Q / 2.0 + sq) + _cbrt(-Q / 2.0 - sq)
    # three real roots (disc < 0): the largest is 2 sqrt(-P/3) cos(acos(...)/3)
    arg = (3.0 * Q / (2.0 * P)) * math.sqrt(-3.0 / P)
    m_trig = 2.0 * math.sqrt(-P / 3.0) * torch.cos(torch.arccos(torch.clamp(arg, -1.0, 1.0)) / 3.0)
    m = torch.where(disc >= 0, m_cardano, m_trig)
    m = torch.clamp(m, min=1e-300)
    s = torch.sqrt(2.0 * m)
    inner = s * a / m - 2.0 * m
    t = 0.5 * (s + torch.sqrt(torch.clamp(inner, min=0.0)))
    return t**3, inner >= 0


def _solve_w_two_thirds(v: torch.Tensor, beta: float) -> torch.Tensor:
    """Closed-form minimiser of |w|^(2/3) + (beta/2)(w − v)² for every element of v: the largest
    stationary point (:func:`_stationary_two_thirds`) where it exists and lowers the objective
    below its value at w = 0, else 0. v < 0 by symmetry."""
    dtype = v.dtype
    a = v.abs().double()
    w, exists = _stationary_two_thirds(a, beta)
    f_w = w.pow(2.0 / 3.0) + 0.5 * beta * (w - a) ** 2
    f_0 = 0.5 * beta * a * a
    w = torch.where(exists & (f_w < f_0), w, torch.zeros_like(w))
    return (torch.sign(v.double()) * w).to(dtype)


@functools.lru_cache(maxsize=64)
def _threshold_two_thirds(beta: float) -> float:
    """|v| above which the minimiser is non-zero: v_t(beta) = beta^(-3/4) v_t(1) (the objective
    is invariant under w → beta^(-3/4) w, v → beta^(-3/4) v); v_t(1) by bisection."""
    lo, hi = 0.0, 10.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        w = _solve_w_two_thirds(torch.tensor([mid], dtype=torch.float64, device="cpu"), 1.0)
        lo, hi = (mid, hi) if float(w[0]) == 0.0 else (lo, mid)
    return hi * beta ** -0.75


def solve_w(v, beta: float, alpha: float = 2.0 / 3.0):
    """Element-wise minimiser of ``|w|**alpha + beta/2 * (w - v)**2`` (the KF w-subproblem).

    ``v``: tensor or array (any shape); ``alpha``: 2/3 (quartic roots, closed form) or 1
    (soft threshold). Returns the same type and shape as ``v``.
    """
    if not (isinstance(beta, (int, float)) and beta > 0 and math.isfinite(beta)):
        raise ValueError(f"beta must be positive and finite, got {beta!r}")
    is_np = not isinstance(v, torch.Tensor)
    t = torch.from_numpy(np.array(v, dtype=np.float64)) if is_np else v
    if abs(alpha - 2.0 / 3.0) < 1e-9:
        out = _solve_w_two_thirds(t, float(beta))
    elif abs(alpha - 1.0) < 1e-12:
        out = torch.sign(t) * torch.clamp(t.abs() - 1.0 / beta, min=0.0)
    else:
        raise ValueError(f"alpha must be 2/3 or 1 (closed forms), got {alpha!r}")
    return out.numpy() if is_np else out


def solve_w_table(v: torch.Tensor, beta: float, alpha: float = 2.0 / 3.0,
                  n: int = 1 << 14) -> torch.Tensor:
    """Fast :func:`solve_w` for tensors (KF's lookup-table variant): the closed form tabulated
    on ``n`` points of [0, max |v|] (exactly 0 below the threshold v_t(beta) of
    :func:`_threshold_two_thirds`) and read at the nearest point (5 passes over the data).
    Error: at most (max|v|/n)·max|dw/dv| (~1e-4·max|v|), except for elements within one table
    step of the threshold, which may fall on either side. alpha = 1 is computed directly."""
    if abs(alpha - 2.0 / 3.0) > 1e-9:
        return solve_w(v, beta, alpha)
    vt = _threshold_two_thirds(float(beta))
    vmax = float(v.abs().max()) if v.numel() else 0.0
    if vmax <= vt:
        return torch.zeros_like(v)
    grid = torch.linspace(0.0, vmax, n, dtype=torch.float64, device=v.device)
    w, _ = _stationary_two_thirds(grid, float(beta))
    table = torch.where(grid > vt, w, torch.zeros_like(w)).to(dtype=v.dtype)
    a = v.abs()
    a.mul_((n - 1) / vmax).add_(0.5)
    out = table[a.long()]
    return out.copysign_(v)


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


def kf_deconv(y: torch.Tensor, otf: torch.Tensor, lam: float = DEFAULT_LAMBDA,
              alpha: float = 2.0 / 3.0, betas: list[float] | None = None,
              inner: int = 1) -> torch.Tensor:
    """Tensor core: deconvolve ``y (B, H, W)`` (already scaled to ~[0, 1], already padded) with
    ``otf (B or 1, H, W//2+1)`` (from :func:`psf2otf`, unit DC gain). Circular boundary."""
    h, w = y.shape[-2:]
    dev, rdt = y.device, y.dtype
    dx = torch.zeros((h, w), device=dev, dtype=rdt)
    dx[0, 0], dx[0, -1] = -1.0, 1.0  # (∇x x)(p) = x(p) − x(p − e_x) as a circular filter
    dy = torch.zeros((h, w), device=dev, dtype=rdt)
    dy[0, 0], dy[-1, 0] = -1.0, 1.0
    fdx, fdy = torch.fft.rfft2(dx), torch.fft.rfft2(dy)
    den_grad = fdx.abs() ** 2 + fdy.abs() ** 2
    fy = torch.fft.rfft2(y)
    num_data = otf.conj() * fy
    den_data = otf.abs() ** 2
    x = y
    for beta in betas if betas is not None else beta_schedule():
        gamma = beta / lam
        denom = den_data + gamma * den_grad
        for _ in range(inner):
            gx = x - torch.roll(x, 1, dims=-1)
            gy = x - torch.roll(x, 1, dims=-2)
            wx = solve_w_table(gx, beta, alpha)
            wy = solve_w_table(gy, beta, alpha)
            num = num_data + gamma * (fdx.conj() * torch.fft.rfft2(wx)
                                      + fdy.conj() * torch.fft.rfft2(wy))
            x = torch.fft.irfft2(num / denom, s=(h, w))
    return x


def hyper_laplacian_deconv(images, kernels, lam: float = DEFAULT_LAMBDA, alpha: float = 2.0 / 3.0,
                           beta0: float = 1.0, beta_max: float = 256.0,
                           beta_rate: float = 2.0 * math.sqrt(2.0), inner: int = 1,
                           pad: int | None = None, normalize_kernel: bool = True,
                           device=None) -> np.ndarray:
    """Krishnan–Fergus deconvolution of images ``(H, W)`` or ``(B, H, W)`` by kernels ``(k, k)``
    (shared) or ``(B, k, k)`` (one per image, e.g. per view). Kernels are centred at index k//2
    (``(k ⊛ x)(p) = Σ_q k(p − q) x(q)``). ``pad``: border added before the FFTs (default: the
    kernel's half size + 4). Returns float32 of the images' shape. See the module docstring
    for ``lam``'s scale."""
    img = np.asarray(images)
    ker = np.asarray(kernels)
    if img.ndim not in (2, 3):
        raise ValueError(f"images must be (H, W) or (B, H, W), got shape {img.shape}")
    batched_ok = ker.ndim == 2 or (img.ndim == 3 and ker.shape[0] == img.shape[0])
    if ker.ndim not in (2, 3) or not batched_ok:
        raise ValueError(f"kernels must be (k, k) or (B, k, k) matching images, got {ker.shape}")
    if not (np.isfinite(img).all() and np.isfinite(ker).all()):
        raise ValueError("images or kernels contain NaN or infinite values")
    if not (lam > 0 and math.isfinite(lam)):
        raise ValueError(f"lam must be positive and finite, got {lam!r}")
    dev = resolve_device(device)
    y = as_tensor(img, dev)
    squeeze = y.ndim == 2
    if squeeze:
        y = y[None]
    k = as_tensor(ker, dev)
    if k.ndim == 2:
        k = k[None]
    if normalize_kernel:
        ksum = k.sum(dim=(-2, -1), keepdim=True)
        if (ksum.abs() < 1e-12).any():
            raise ValueError("a kernel sums to zero; cannot normalise it")
        k = k / ksum
    if pad is None:
        pad = max(k.shape[-2:]) // 2 + 4
    scale = y.abs().amax(dim=(-2, -1), keepdim=True).clamp(min=1e-12)
    yp = pad_fade(y / scale, pad)
    otf = psf2otf(k, yp.shape[-2:])
    x = kf_deconv(yp, otf, lam=lam, alpha=alpha,
                  betas=beta_schedule(beta0, beta_max, beta_rate), inner=inner)
    h, w = y.shape[-2:]
    x = x[..., pad:pad + h, pad:pad + w] * scale
    out = to_numpy(x).astype(np.float32)
    return out[0] if squeeze else out
