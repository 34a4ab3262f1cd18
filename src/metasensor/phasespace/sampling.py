"""Sampling every d-th column of a view in the Fourier domain (the forward model's last step).

Hand-written (no library folds a half spectrum). A view's samples ``V[m, n] = v[m·d, n·d]`` are
made from its row-folded half spectrum ``F(p, k)`` (rows already aliased to the My view
frequencies, columns k < Nx//2+1 of the domain): sampling every d-th column sums the d column
aliases ``k + b·Mx``; those beyond the half spectrum are conj F(−p, Nx − k) (a real view's
spectrum is Hermitian), so the samples come from inverse FFTs at the samples' size
(My, Mx//2+1) instead of the domain's followed by every d-th column.
"""

from __future__ import annotations

import torch

__all__ = ["column_fold", "sample_columns"]


def column_fold(geometry, device) -> tuple:
    """Index tensors of the column fold of :func:`sample_columns`: the
    half-spectrum column k of the samples (k < Mx//2+1) sums the domain's columns k + b·Mx
    (b < d); those under Nx//2+1 are read directly (``direct``: destination, source), the others
    as conj(F(−p, Nx − k)) (``source`` columns, ``conj`` destinations, ``flip`` the rows −p)."""
    d = geometry.d
    my, mx = geometry.grid
    nx = geometry.domain[1]
    nh = nx // 2 + 1
    dest = torch.arange(mx // 2 + 1, device=device)[:, None].expand(-1, d).flatten()
    col = (torch.arange(mx // 2 + 1, device=device)[:, None]
           + mx * torch.arange(d, device=device)[None]).flatten()
    inside = col < nh
    flip = torch.remainder(-torch.arange(my, device=device), my)
    return ((dest[inside], col[inside]), nx - col[~inside], dest[~inside], flip)


def sample_columns(folded: torch.Tensor, index: tuple, geometry) -> torch.Tensor:
    """View samples ``(c, My, Mx)`` from row-folded half spectra ``(c, My, Nx//2+1)``
    (module docstring; ``index`` from :func:`column_fold`), scaled by 1/d² (the operator's
    normalisation)."""
    d = geometry.d
    mx = geometry.grid[1]
    direct, source, conj, flip = index
    small = torch.zeros((*folded.shape[:-1], mx // 2 + 1), dtype=folded.dtype,
                        device=folded.device)
    small.index_add_(-1, direct[0], folded.index_select(-1, direct[1]))
    if source.numel():
        part = folded.index_select(-1, source).index_select(-2, flip).conj()
        small.index_add_(-1, conj, part)
    rows = torch.fft.ifft(small, dim=-2)  # the sampled rows' half spectra along x
    return torch.fft.irfft(rows, n=mx, dim=-1) / (d * d)
