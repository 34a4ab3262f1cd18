"""Sub-pixel shifts between images by cross-correlation, and Fourier (sub-pixel) translation.

Written here (batched torch, CPU or CUDA) because DAO measures ~100 views at once; it follows
scikit-image's ``phase_cross_correlation`` (Guizar-Sicairos et al., Opt. Lett. 2008): an FFT
cross-correlation gives the integer peak, a matrix-multiply DFT evaluates the correlation on an
``upsample``-times finer grid within ±1 sample of it, and a quadratic fit to the finest 3 × 3
neighbourhood gives the final estimate. Plain (not phase-normalised) correlation of mean-free,
Tukey-windowed images is used: it is the maximum-likelihood estimate under white noise and stays
robust at low SNR.

Sign convention (shared with :func:`fourier_shift`): ``measure_shifts(reference, moving)``
returns ``s = (dy, dx)`` with ``moving(p) ≈ reference(p − s)``, i.e. ``moving`` is ``reference``
displaced by ``+s`` samples (rows, columns).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from metasensor.backend import as_tensor, resolve_device, to_numpy

__all__ = ["fourier_shift", "measure_shifts", "measure_shifts_torch", "shift_precision", "tukey2d"]


def tukey2d(shape: tuple[int, int], alpha: float = 0.25, device=None,
            dtype=torch.float32) -> torch.Tensor:
    """Separable Tukey window: flat centre, raised-cosine edges of ``alpha/2`` of each side,
    sampled at the pixel centres ``(i + 0.5) / n`` (``scipy.signal.windows.tukey`` of
    ``2n + 1`` points, every other one)."""
    from scipy.signal.windows import tukey

    rows, cols = (torch.from_numpy(tukey(2 * int(n) + 1, alpha)[1::2].copy())
                  for n in shape)
    return (rows[:, None] * cols[None, :]).to(device=device, dtype=dtype)


def fourier_shift(x: torch.Tensor, shifts: torch.Tensor) -> torch.Tensor:
    """Translate images ``x (B, H, W)`` by ``shifts (B, 2)`` = (dy, dx) samples, sub-pixel, with
    a Fourier phase ramp (circular boundary): ``out(p) = x(p − s)``. Real in, real out."""
    h, w = x.shape[-2:]
    fy = torch.fft.fftfreq(h, device=x.device, dtype=x.dtype)
    fx = torch.fft.rfftfreq(w, device=x.device, dtype=x.dtype)
    s = shifts.to(device=x.device, dtype=x.dtype)
    phase = -2.0 * math.pi * (s[:, 0, None, None] * fy[None, :, None]
                              + s[:, 1, None, None] * fx[None, None, :])
    spec = torch.fft.rfft2(x) * torch.polar(torch.ones_like(phase), phase)
    return torch.fft.irfft2(spec, s=(h, w))


def _dft_upsampled(spec: torch.Tensor, cy: torch.Tensor, cx: torch.Tensor, up: int,
                   half: int) -> torch.Tensor:
    """Correlation ``ifft2(spec)`` (unnormalised) evaluated at ``c + k/up``, k = −half..half,
    around per-image centres (cy, cx) (B,), by two batched matrix products. → (B, n, n) real."""
    b, h, w = spec.shape
    dev = spec.device
    off = torch.arange(-half, half + 1, device=dev, dtype=torch.float64) / up
    ky = torch.fft.fftfreq(h, device=dev, dtype=torch.float64) * h  # integer frequencies
    kx = torch.fft.fftfreq(w, device=dev, dtype=torch.float64) * w
    py = cy.double()[:, None] + off[None, :]  # (B, n)
    px = cx.double()[:, None] + off[None, :]
    ey = torch.polar(torch.ones(1, device=dev, dtype=torch.float64),
                     2.0 * math.pi * py[:, :, None] * ky[None, None, :] / h)  # (B, n, H)
    ex = torch.polar(torch.ones(1, device=dev, dtype=torch.float64),
                     2.0 * math.pi * kx[None, :, None] * px[:, None, :] / w)  # (B, W, n)
    cdt = spec.dtype
    out = torch.bmm(torch.bmm(ey.to(cdt), spec), ex.to(cdt))
    return out.real


def _quadratic_peak(c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Sub-sample offset (dy, dx) of the maximum of a 3 × 3 patch ``c (B, 3, 3)`` from its centre
    by a separable parabola fit, clamped to ±0.5."""

    def para(m, z, p):
        den = m - 2.0 * z + p
        off = torch.where(den.abs() > 1e-30, 0.5 * (m - p) / den, torch.zeros_like(den))
        return off.clamp(-0.5, 0.5)

    dy = para(c[:, 0, 1], c[:, 1, 1], c[:, 2, 1])
    dx = para(c[:, 1, 0], c[:, 1, 1], c[:, 1, 2])
    return dy, dx


def _window(moving: torch.Tensor, window: float, weight: torch.Tensor | None) -> torch.Tensor:
    """Tukey window (H, W), times the per-sample ``weight`` (B or 1, H, W) when given."""
    win = tukey2d(moving.shape[-2:], window, device=moving.device, dtype=moving.dtype)
    return win if weight is None else win * weight.to(moving.dtype)


def _coarse_shifts(reference: torch.Tensor, moving: torch.Tensor, upsample: int, window: float,
                   max_shift: float | None, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Peak of the windowed FFT cross-correlation, refined on an upsampled DFT grid. (B, 2)."""
    b, h, w = moving.shape
    win = _window(moving, window, weight)
    wsum = win.sum(dim=(-2, -1), keepdim=True).clamp(min=1e-12)

    def prep(x):
        x = x - x.mean(dim=(-2, -1), keepdim=True)
        x = x * win
        return x - (x.sum(dim=(-2, -1), keepdim=True) / wsum) * win

    fm = torch.fft.fft2(prep(moving))
    fr = torch.fft.fft2(prep(reference))
    spec = fm * fr.conj()
    corr = torch.fft.ifft2(spec).real  # corr[s] = Σ_p moving(p) reference(p − s)
    if max_shift is not None:
        sy = torch.fft.fftfreq(h, device=corr.device) * h
        sx = torch.fft.fftfreq(w, device=corr.device) * w
        far = (sy.abs()[:, None] > max_shift) | (sx.abs()[None, :] > max_shift)
        corr = corr.masked_fill(far, -torch.inf)
    idx = corr.reshape(b, -1).argmax(dim=1)
    iy = (idx // w).double()
    ix = (idx % w).double()
    iy = torch.where(iy > h // 2, iy - h, iy)
    ix = torch.where(ix > w // 2, ix - w, ix)
    up = max(int(upsample), 1)
    if up == 1:
        return torch.stack([iy, ix], dim=1)
    # Σ spec e^{+i2π k s / N} is the correlation at lag s
    fine = _dft_upsampled(spec, iy, ix, up, up)
    n = fine.shape[-1]
    j = fine.reshape(b, -1).argmax(dim=1)
    jy = (j // n).clamp(1, n - 2)
    jx = (j % n).clamp(1, n - 2)
    ar = torch.arange(b, device=fine.device)
    patch = torch.stack([torch.stack([fine[ar, jy + a, jx + c] for c in (-1, 0, 1)], -1)
                         for a in (-1, 0, 1)], -2)
    dy, dx = _quadratic_peak(patch)
    return torch.stack([iy + ((jy - up).double() + dy.double()) / up,
                        ix + ((jx - up).double() + dx.double()) / up], dim=1)


def _warp(reference: torch.Tensor, shifts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``reference(p − s)`` (B, H, W) by a Fourier shift of the reference padded with a
    reflection fading to its mean (band-limited interpolation, no ringing from the borders),
    and the mask of the points whose source lies at least one sample inside the reference."""
    from metasensor.solvers.krishnan_fergus import pad_fade

    b, (h, w) = shifts.shape[0], reference.shape[-2:]
    dev = reference.device
    pad = int(math.ceil(float(shifts.abs().max()))) + 8
    ref = pad_fade(reference.expand(b, h, w), pad)
    out = fourier_shift(ref, shifts)[:, pad:pad + h, pad:pad + w]
    yy = torch.arange(h, device=dev, dtype=torch.float64)[None, :, None] - shifts[:, 0, None, None]
    xx = torch.arange(w, device=dev, dtype=torch.float64)[None, None, :] - shifts[:, 1, None, None]
    valid = (yy >= 1) & (yy <= h - 2) & (xx >= 1) & (xx <= w - 2)
    return out, valid


def _refine_shifts(reference: torch.Tensor, moving: torch.Tensor, shifts: torch.Tensor,
                   window: float, iterations: int,
                   weight: torch.Tensor | None = None) -> torch.Tensor:
    """Gauss–Newton on the weighted SSD  Σ_p w(p) (moving(p) − a·reference(p − s) − c)²  over
    (s, a, c) per image: unbiased where the coarse correlation peak is pulled by the image
    borders. The weight is a Tukey window times the mask where the reference is defined (times
    ``weight`` when given)."""
    b = moving.shape[0]
    win = _window(moving, window, weight)
    s = shifts.clone()
    eye = 1e-9 * torch.eye(4, dtype=torch.float64, device=moving.device)
    for _ in range(iterations):
        r, valid = _warp(reference, s)
        gy, gx = _gradients(r)
        wgt = win * valid
        # model a·r(p − s) + c; Jacobian columns (−a ∂y r, −a ∂x r, r, 1); a is absorbed below.
        # The weighted normal equations as two batched products (B, 4, HW) x (B, HW, 4 | 1)
        cols = torch.stack([-gy, -gx, r, torch.ones_like(r)], dim=1).reshape(b, 4, -1)
        wcols = cols * wgt.reshape(-1, 1, cols.shape[-1])
        del gy, gx, r
        normal = torch.bmm(wcols, cols.transpose(1, 2)).double()
        rhs = torch.bmm(wcols, moving.reshape(b, -1, 1))[:, :, 0].double()
        del cols, wcols
        # linear least squares of moving on (−∂y r, −∂x r, r, 1): the coefficients are
        # (a·δy, a·δx, a, c) for the first-order model a·r(p − s − δ) + c
        coef = torch.linalg.solve(normal + eye, rhs[:, :, None])[:, :, 0]
        gain = torch.where(coef[:, 2].abs() > 1e-12, coef[:, 2], torch.ones_like(coef[:, 2]))
        step = coef[:, :2] / gain[:, None]
        s = s + step.clamp(-1.0, 1.0)
    return s


def _gradients(r: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Central differences (rows, columns) of ``r (B, H, W)``, 0 on the outer samples."""
    gy = torch.zeros_like(r)
    gx = torch.zeros_like(r)
    gy[:, 1:-1] = 0.5 * (r[:, 2:] - r[:, :-2])
    gx[:, :, 1:-1] = 0.5 * (r[:, :, 2:] - r[:, :, :-2])
    return gy, gx


def shift_precision(reference: torch.Tensor, moving: torch.Tensor, shifts: torch.Tensor,
                    window: float = 0.25, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Precision (B,) of measured shifts, in 1/samples²: ``2 / (var(s_y) + var(s_x))`` for the
    model ``moving(p) = a·reference(p − s) + c + noise`` at ``s = shifts``, solved by weighted
    least squares: ``var(s_k) = σ² Σ w² g_k² / (a Σ w g_k²)²`` (g_k the reference's gradient,
    (a, c) fitted, σ² the weighted variance of the residual; w the Tukey window times ``weight``
    times the mask where the warped reference is defined, as in the Gauss–Newton refinement).
    Under white noise its inverse is the variance of each shift component, so a joint fit of many
    shifts (e.g. the DAO wavefront fit) can weight them by it. 0 where nothing is weighted."""
    r, valid = _warp(reference, shifts.double())
    gy, gx = _gradients(r)
    w = _window(moving, window, weight) * valid
    sw = w.sum(dim=(-2, -1)).clamp(min=1e-30)
    rc = r - ((w * r).sum(dim=(-2, -1)) / sw)[:, None, None]
    mc = moving - ((w * moving).sum(dim=(-2, -1)) / sw)[:, None, None]
    a = (w * rc * mc).sum(dim=(-2, -1)) / (w * rc * rc).sum(dim=(-2, -1)).clamp(min=1e-30)
    var = (w * (mc - a[:, None, None] * rc) ** 2).sum(dim=(-2, -1)) / sw
    # a floor of 1e-12 of the signal's variance keeps noise-free data finite
    var = torch.maximum(var, 1e-12 * (w * mc * mc).sum(dim=(-2, -1)) / sw)
    # weighted least squares: var(s_k) = σ² Σ w² g_k² / (a Σ w g_k²)² (the sandwich form)
    var_s = sum((w * w * g * g).sum(dim=(-2, -1)) / (w * g * g).sum(dim=(-2, -1)).square()
                .clamp(min=1e-30) for g in (gy, gx)) * var / (a * a).clamp(min=1e-30)
    return torch.where(var_s > 0, 2.0 / var_s.clamp(min=1e-300), 0.0).double()


def measure_shifts_torch(reference: torch.Tensor, moving: torch.Tensor, upsample: int = 10,
                         window: float = 0.25, max_shift: float | None = None,
                         refine: int = 4, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Tensor core of :func:`measure_shifts`: ``reference`` (B or 1, H, W), ``moving`` (B, H, W)
    → shifts (B, 2) float64 in samples (see the module docstring for the sign). ``weight``
    (B or 1, H, W), non-negative: how much each sample of ``moving`` counts (multiplies the
    Tukey window), e.g. 0 where the reference is not known."""
    s = _coarse_shifts(reference, moving, upsample, window, max_shift, weight)
    if refine > 0:
        s = _refine_shifts(reference, moving, s, window, refine, weight)
    if max_shift is not None:
        s = s.clamp(-max_shift, max_shift)
    return s


def measure_shifts(reference, moving, upsample: int = 10, window: float = 0.25,
                   max_shift: float | None = None, refine: int = 4, device=None) -> np.ndarray:
    """Sub-pixel shifts of ``moving`` relative to ``reference``.

    reference : (H, W) shared, or (B, H, W) one per moving image.
    moving : (H, W) or (B, H, W).
    upsample : refinement factor of the matrix-multiply DFT (1: parabola on integer samples).
    window : Tukey taper fraction applied before correlating (0: none).
    max_shift : search and clip range in samples (None: half the image).
    refine : Gauss–Newton iterations on the weighted SSD after the correlation peak (0: none).
    Returns (2,) or (B, 2) float64: (dy, dx) with ``moving(p) ≈ reference(p − s)``.
    """
    ref = np.asarray(reference)
    mov = np.asarray(moving)
    if mov.ndim not in (2, 3) or ref.ndim not in (2, 3):
        raise ValueError(f"images must be (H, W) or (B, H, W); got {ref.shape} and {mov.shape}")
    if ref.shape[-2:] != mov.shape[-2:]:
        raise ValueError(f"reference {ref.shape} and moving {mov.shape} differ in size")
    if not (np.isfinite(ref).all() and np.isfinite(mov).all()):
        raise ValueError("images contain NaN or infinite values")
    if min(mov.shape[-2:]) < 4:
        raise ValueError(f"images too small to correlate: {mov.shape}")
    dev = resolve_device(device)
    squeeze = mov.ndim == 2
    m = as_tensor(mov, dev)
    m = m[None] if squeeze else m
    r = as_tensor(ref, dev)
    r = r[None] if r.ndim == 2 else r
    if r.shape[0] not in (1, m.shape[0]):
        raise ValueError(f"reference batch {r.shape[0]} does not match moving batch {m.shape[0]}")
    out = to_numpy(measure_shifts_torch(r, m, upsample, window, max_shift, refine))
    return out[0] if squeeze else out
