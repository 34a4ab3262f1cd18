"""Sampled linear convolution: many kernels applied to one image, kept only on a sample lattice.

The simulator needs ``V_b(p) = Σ_q I(q) K_b(p − q)`` (zero outside the image) for every kernel b
(one per view) but only at the lenslet centres ``p = offset + stride · i``. Written by hand
(no library does tiled, decimated, multi-kernel FFT convolution): overlap-save tiles whose FFTs
are shared by all kernels; per kernel one product with the tile spectra, a fold of the spectrum
along y (decimation in y costs a sum of ``stride`` spectrum slices, the DFT aliasing identity)
and a small inverse transform. Torch, float32, CPU or CUDA; kernels processed in chunks so that
the working set stays under ``max_bytes``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["Lattice", "sampled_conv", "fft_size"]


@dataclass(frozen=True)
class Lattice:
    """Sample positions ``offset + stride * i`` for ``i`` in ``[start, stop)`` along one axis."""

    offset: int
    stride: int
    count: int
    start: int = 0
    stop: int | None = None

    @property
    def end(self) -> int:
        return self.count if self.stop is None else min(self.stop, self.count)

    def restrict(self, lo: int, hi: int) -> Lattice:
        """Keep the samples whose position lies in ``[lo, hi]`` (pixels)."""
        s = self.stride
        first = max(0, -(-(lo - self.offset) // s))
        last = min(self.count - 1, (hi - self.offset) // s)
        return Lattice(self.offset, s, self.count, max(first, self.start),
                       max(min(last + 1, self.end), max(first, self.start)))


def fft_size(n: int, multiple: int) -> int:
    """Smallest ``multiple · k >= n`` with k 5-smooth (a 5-smooth size when ``multiple`` is
    one; a stride with another prime factor, e.g. 13, has no 5-smooth multiple)."""
    k = max(1, -(-n // multiple))
    while True:
        r = k
        for p in (2, 3, 5):
            while r % p == 0:
                r //= p
        if r == 1:
            return multiple * k
        k += 1


def _plan(count: int, stride: int, c: int, tile: int) -> tuple[int, int]:
    """Tiling of ``count`` samples along one axis: (samples per tile, FFT length), choosing the
    number of tiles that minimises a cost model (products ∝ tiles · P; the kernels' own FFTs
    ∝ P log P once per kernel), with P <= max(tile, the smallest single-tile size)."""
    best = None
    for k in range(1, count + 1):
        n = -(-count // k)
        size = fft_size(stride * (n - 1) + 2 * c + 1, stride)
        if size > tile and k < count and best is not None:
            continue
        cost = k * size + 0.3 * size * max(size.bit_length(), 1) / 4
        if best is None or cost < best[0]:
            best = (cost, (size - 2 * c - 1) // stride + 1, size)
        if size <= 2 * c + stride:
            break
    return best[1], best[2]


def sampled_conv(image: torch.Tensor, kernels: torch.Tensor, rows: Lattice, cols: Lattice,
                 out: torch.Tensor | None = None, *, tile: int = 768,
                 max_bytes: int = 256 * 2**20) -> torch.Tensor:
    """Linear convolution of ``image`` (H, W) with ``kernels`` (B, k, k), k odd, centre k//2 =
    zero displacement, evaluated at the lattice samples; zero outside the image.

    Returns (or accumulates into) ``out`` of shape (B, rows.count, cols.count); only the samples
    in ``rows.start:rows.end`` × ``cols.start:cols.end`` are touched.
    """
    if image.ndim != 2 or kernels.ndim != 3 or kernels.shape[1] != kernels.shape[2]:
        raise ValueError("sampled_conv needs an (H, W) image and (B, k, k) kernels")
    k = kernels.shape[-1]
    if k % 2 == 0:
        raise ValueError(f"kernel size must be odd, got {k}")
    c = k // 2
    nb = kernels.shape[0]
    dev, dt = image.device, torch.float32
    if out is None:
        out = torch.zeros((nb, rows.count, cols.count), device=dev, dtype=dt)
    r0, r1, c0, c1 = rows.start, rows.end, cols.start, cols.end
    if r1 <= r0 or c1 <= c0:
        return out
    sy, sx = rows.stride, cols.stride
    ny_t, py = _plan(r1 - r0, sy, c, tile)
    nx_t, px = _plan(c1 - c0, sx, c, tile)
    h, w = image.shape
    # tile windows (zero padded): window of a tile starting at sample i covers input rows
    # [offset + s*i - c, offset + s*i - c + P)
    ty = list(range(r0, r1, ny_t))
    tx = list(range(c0, c1, nx_t))
    windows = torch.zeros((len(ty), len(tx), py, px), device=dev, dtype=dt)
    for a, i in enumerate(ty):
        y0 = rows.offset + sy * i - c
        ya, yb = max(y0, 0), min(y0 + py, h)
        if yb <= ya:
            continue
        for b, j in enumerate(tx):
            x0 = cols.offset + sx * j - c
            xa, xb = max(x0, 0), min(x0 + px, w)
            if xb <= xa:
                continue
            windows[a, b, ya - y0:yb - y0, xa - x0:xb - x0] = image[ya:yb, xa:xb]
    spec_img = torch.fft.rfft2(windows)  # (ty, tx, py, px//2+1)
    del windows
    nty, ntx = len(ty), len(tx)
    per_kernel = nty * ntx * py * (px // 2 + 1) * 8 * 3
    chunk = max(1, min(nb, max_bytes // max(per_kernel, 1)))
    for b0 in range(0, nb, chunk):
        kb = kernels[b0:b0 + chunk].to(device=dev, dtype=dt)
        # kernel element e placed at index (e - 2c) mod P: out_circ[m] = conv at window + m + c
        kpad = torch.zeros((kb.shape[0], py, px), device=dev, dtype=dt)
        iy = torch.arange(k, device=dev) - 2 * c
        kpad[:, (iy % py)[:, None], (iy % px)[None, :]] = kb
        spec_k = torch.fft.rfft2(kpad)[:, None, None]  # (B, 1, 1, py, px//2+1)
        del kpad
        m = py // sy
        folded = None
        for j in range(sy):  # fold along y: decimation by sy
            part = spec_img[None, :, :, j * m:(j + 1) * m] * spec_k[..., j * m:(j + 1) * m, :]
            folded = part if folded is None else folded + part
        folded = torch.fft.ifft(folded, dim=-2) / sy
        res = torch.fft.irfft(folded, n=px, dim=-1)[..., ::sx]  # (B, ty, tx, m, px//sx)
        res = res[..., :ny_t, :nx_t]
        for a, i in enumerate(ty):
            ni = min(ny_t, r1 - i)
            for b, j in enumerate(tx):
                nj = min(nx_t, c1 - j)
                out[b0:b0 + chunk, i:i + ni, j:j + nj] += res[:, a, b, :ni, :nj]
    return out
