"""Box and guided filters in torch (O(1) per pixel, any leading batch dimensions).

Written here by hand: OpenCV's guided filter lives in ``ximgproc`` (opencv-contrib), which the
headless OpenCV wheel does not ship, and we want the same code on CPU and CUDA. The guided filter
is He, Sun & Tang, "Guided image filtering" (ECCV 2010 / TPAMI 2013), grey-scale guide.
"""

from __future__ import annotations

import torch

__all__ = ["box_mean", "GuidedFilter", "sample_at"]


def _box_sum_axis(x: torch.Tensor, r: int, dim: int) -> torch.Tensor:
    """Sum over the window ``[i − r, i + r]`` along ``dim``, clipped at the borders."""
    n = x.shape[dim]
    c = torch.cumsum(x, dim=dim)
    zero_shape = list(x.shape)
    zero_shape[dim] = 1
    c = torch.cat([torch.zeros(zero_shape, dtype=x.dtype, device=x.device), c], dim=dim)
    i = torch.arange(n, device=x.device)
    hi = torch.clamp(i + r + 1, max=n)
    lo = torch.clamp(i - r, min=0)
    return c.index_select(dim, hi) - c.index_select(dim, lo)


def _counts(n: int, r: int, device) -> torch.Tensor:
    i = torch.arange(n, device=device)
    return (torch.clamp(i + r, max=n - 1) - torch.clamp(i - r, min=0) + 1).to(torch.float32)


def box_mean(x: torch.Tensor, r: int) -> torch.Tensor:
    """Mean over a ``(2r+1) × (2r+1)`` window (clipped at the borders) of the last two axes."""
    r = int(r)
    if r <= 0:
        return x.clone()
    h, w = x.shape[-2:]
    s = _box_sum_axis(_box_sum_axis(x, r, x.ndim - 1), r, x.ndim - 2)
    counts = _counts(h, r, x.device)[:, None] * _counts(w, r, x.device)[None, :]
    return s / counts.to(x.dtype)


class GuidedFilter:
    """Edge-preserving smoothing of images ``(..., H, W)`` steered by a guide ``(H, W)``.

    ``radius`` in pixels; ``eps`` is the regularisation in units of the guide's variance
    (the guide is normalised to zero mean and unit variance first, so ``eps`` is scale-free:
    small → edges kept sharply, large → plain box filter). The guide statistics are computed
    once and reused for every image filtered (``__call__`` changes no state).
    """

    def __init__(self, guide: torch.Tensor, radius: int, eps: float = 0.01) -> None:
        if guide.ndim != 2:
            raise ValueError(f"guide must be 2-D (H, W), got shape {tuple(guide.shape)}")
        g = guide.to(torch.float32)
        g = (g - g.mean()) / (g.std() + 1e-12)
        self.radius = int(radius)
        self.eps = float(eps)
        self.guide = g
        self.mean_i = box_mean(g, self.radius)
        self.var_i = box_mean(g * g, self.radius) - self.mean_i**2

    def __call__(self, p: torch.Tensor) -> torch.Tensor:
        if p.shape[-2:] != self.guide.shape:
            raise ValueError(
                f"image shape {tuple(p.shape[-2:])} != guide {tuple(self.guide.shape)}"
            )
        r = self.radius
        mean_p = box_mean(p, r)
        cov = box_mean(p * self.guide, r) - self.mean_i * mean_p
        a = cov / (self.var_i + self.eps)
        b = mean_p - a * self.mean_i
        return box_mean(a, r) * self.guide + box_mean(b, r)

    def weighted(self, p: torch.Tensor, weight: torch.Tensor, floor: float = 1e-6) -> torch.Tensor:
        """Normalised (confidence-weighted) filtering: ``GF(w · p) / GF(w)``."""
        num = self(p * weight)
        den = self(weight)
        return num / torch.clamp(den, min=floor)


def sample_at(img: torch.Tensor, y: torch.Tensor, x: torch.Tensor,
              mode: str = "bilinear") -> torch.Tensor:
    """Samples of ``img (H, W)`` at the points ``(y, x)`` [px] (any equal shapes), edges
    replicated: torch's ``grid_sample`` with ``align_corners=True`` (``mode`` "bilinear" or
    "bicubic", the latter cubic convolution with a = −0.75)."""
    h, w = img.shape
    gx = 2 * x / max(w - 1, 1) - 1
    gy = 2 * y / max(h - 1, 1) - 1
    grid = torch.stack([gx.reshape(-1), gy.reshape(-1)], dim=-1)[None, None]
    out = torch.nn.functional.grid_sample(img[None, None], grid, mode=mode,
                                          padding_mode="border", align_corners=True)
    return out.reshape(y.shape)
