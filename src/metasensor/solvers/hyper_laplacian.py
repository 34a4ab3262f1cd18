"""The hyper-Laplacian proximal operator: ``argmin_w |w|^alpha + (beta/2)(w − v)²`` element-wise.

Hand-written (Krishnan & Fergus, "Fast image deconvolution using hyper-Laplacian priors",
NeurIPS 2009; no maintained Python package has it): closed forms for alpha = 2/3 (the roots of a
quartic, :func:`solve_w`) and alpha = 1 (soft thresholding), and a lookup table for tensors
(:func:`solve_w_table`, after the authors' per-beta tables: one table for every beta).
:class:`metasensor.solvers.priors.HyperLaplacian` is the prior built on them.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

__all__ = ["solve_w", "solve_w_table"]


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


#: the normalised argument ``s = beta^(3/4)·|v|`` is tabulated on [0, UNIT_TABLE_MAX] ...
UNIT_TABLE_MAX = 1024.0
#: ... every UNIT_TABLE_STEP (linear interpolation between the points)
UNIT_TABLE_STEP = 1.0 / 512.0


@functools.lru_cache(maxsize=8)
def _unit_table(device: str, dtype: torch.dtype) -> torch.Tensor:
    """The largest stationary point of ``|w|^(2/3) + ½(w − s)²`` (beta 1) at ``s = i·step``,
    ``i = 0 … max/step + 1`` (0 where none exists), computed in float64 and stored in
    ``dtype`` on ``device``."""
    n = int(round(UNIT_TABLE_MAX / UNIT_TABLE_STEP)) + 2
    s = torch.arange(n, dtype=torch.float64, device="cpu") * UNIT_TABLE_STEP  # on the host
    w, exists = _stationary_two_thirds(s, 1.0)
    return torch.where(exists, w, torch.zeros_like(w)).to(device=device, dtype=dtype)


def solve_w_table(v: torch.Tensor, beta: float, alpha: float = 2.0 / 3.0) -> torch.Tensor:
    """Fast :func:`solve_w` for tensors, element-wise (an element's result does not depend on
    the others).

    For alpha = 2/3 the minimiser scales as ``w(v; beta) = beta^(-3/4)·w(beta^(3/4)·v; 1)``
    (the objective is invariant under ``w → beta^(-3/4) w, v → beta^(-3/4) v``), so one table of
    the beta = 1 closed form in ``s = beta^(3/4)·|v|`` serves every beta (built once per device
    and dtype, :func:`_unit_table`; Krishnan & Fergus tabulate per beta instead): linear
    interpolation on [0, 1024] in steps of 1/512 (2 MB in float32), exactly 0 below the
    threshold (:func:`_threshold_two_thirds`); above 1024, where ``w`` is within 0.1 % of
    ``s``, four rounds of the fixed point ``w = s − (2/3)·w^(-1/3)`` (contraction factor
    < 1e-4). Error: at most a few 1e-6 of ``beta^(-3/4)`` (interpolation next to the
    threshold) and float32 rounding, tested against the closed form.
    alpha = 1 is computed directly."""
    if abs(alpha - 2.0 / 3.0) > 1e-9:
        return solve_w(v, beta, alpha)
    if v.numel() == 0:
        return torch.zeros_like(v)
    scale = float(beta) ** 0.75
    table = _unit_table(str(v.device), v.dtype)
    s = v.abs().mul_(scale)
    pos = s.clamp(max=UNIT_TABLE_MAX).mul_(1.0 / UNIT_TABLE_STEP)
    i0 = pos.long().clamp_(0, table.numel() - 2)
    frac = pos.sub_(i0)
    lo = table[i0]
    w = torch.lerp(lo, table[i0 + 1], frac)
    w.masked_fill_(s <= _threshold_two_thirds(1.0), 0.0)
    big = s > UNIT_TABLE_MAX
    if bool(big.any()):
        sb = s[big]
        wb = sb.clone()
        for _ in range(4):
            wb = sb - (2.0 / 3.0) * wb.pow(-1.0 / 3.0)
        w[big] = wb
    return w.mul_(1.0 / scale).copysign_(v)
