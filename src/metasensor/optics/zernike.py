"""Zernike polynomials in Noll order, r.m.s.-normalised on the unit disk (hand-written).

Convention (docs/conventions.md): Noll index ``j = 1`` is piston; a coefficient vector ``z`` holds
``z[j-1]`` for mode j, in waves. ``x`` grows with the column index, ``y`` with the row index and
the polar angle theta runs from +x towards +y, so ``Z2 = 2 rho cos(theta) = 2 x``,
``Z3 = 2 y``, ``Z4 = sqrt(3) (2 rho^2 - 1)``, ``Z5 = sqrt(6) rho^2 sin(2 theta)``,
``Z6 = sqrt(6) rho^2 cos(2 theta)``, ... (Noll 1976: even j -> cos(m theta), odd j -> sin).

Why hand-written: prysm 0.21's ``prysm.polynomials`` cannot be imported in this environment
(its package ``__init__`` needs ``pkg_resources``), and aotools only draws modes on pixel grids
without gradients. The modes are evaluated as exact polynomials in (x, y) —
``rho^(n-2k-|m|) * Re/Im((x + i y)^|m|)`` — so values and gradients are regular everywhere
(including rho = 0) and are defined outside the unit disk too (callers mask). The index and
normalisation conventions are pinned by tests against the closed forms above and aotools.
"""

from __future__ import annotations

from collections.abc import Iterable
from math import factorial

import numpy as np

__all__ = [
    "noll_indices",
    "noll_to_nm",
    "zernike_basis",
    "zernike_gradients",
    "wavefront",
    "fit_zernike",
    "random_zernike",
]


def noll_to_nm(j: int) -> tuple[int, int]:
    """Radial order n and signed azimuthal order m of Noll index j (>= 1).

    ``m > 0``: cos(m theta) mode (even j); ``m < 0``: sin(|m| theta) mode (odd j); m = 0 radial.
    """
    if isinstance(j, bool) or not isinstance(j, (int, np.integer)) or j < 1:
        raise ValueError(f"Noll index must be an integer >= 1, got {j!r}")
    j = int(j)
    n = 0
    while (n + 1) * (n + 2) // 2 < j:
        n += 1
    # modes of order n occupy j = n(n+1)/2 + 1 ... (n+1)(n+2)/2, with |m| ascending in pairs
    p = j - n * (n + 1) // 2  # 1-based position within the order
    if n % 2 == 0:
        am = 2 * (p // 2)
    else:
        am = 2 * ((p - 1) // 2) + 1
    if am == 0:
        return n, 0
    return n, am if j % 2 == 0 else -am


def _radial_terms(n: int, am: int) -> list[tuple[float, int]]:
    """Coefficients c_k and exponents a_k with R_n^|m|(rho) = rho^|m| * sum c_k (rho^2)^a_k."""
    terms = []
    for k in range((n - am) // 2 + 1):
        c = (-1) ** k * factorial(n - k) / (
            factorial(k) * factorial((n + am) // 2 - k) * factorial((n - am) // 2 - k)
        )
        terms.append((float(c), (n - 2 * k - am) // 2))
    return terms


def _norm(n: int, m: int) -> float:
    return float(np.sqrt(n + 1.0) if m == 0 else np.sqrt(2.0 * (n + 1.0)))


def _check_xy(x, y) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    if x.shape != y.shape:
        raise ValueError(f"x and y must have the same shape, got {x.shape} and {y.shape}")
    return x, y


def _check_jmax(jmax: int) -> int:
    if isinstance(jmax, bool) or not isinstance(jmax, (int, np.integer)) or jmax < 1:
        raise ValueError(f"jmax must be an integer >= 1, got {jmax!r}")
    return int(jmax)


def zernike_basis(x, y, jmax: int = 45) -> np.ndarray:
    """Modes j = 1..jmax at normalised pupil coordinates (x, y) -> float64 (jmax, *x.shape)."""
    x, y = _check_xy(x, y)
    jmax = _check_jmax(jmax)
    r2 = x * x + y * y
    w = x + 1j * y
    out = np.empty((jmax, *x.shape), dtype=np.float64)
    for j in range(1, jmax + 1):
        n, m = noll_to_nm(j)
        am = abs(m)
        radial = sum(c * r2**a for c, a in _radial_terms(n, am))
        wm = w**am
        ang = wm.real if m >= 0 else wm.imag
        out[j - 1] = _norm(n, m) * radial * ang
    return out


def zernike_gradients(x, y, jmax: int = 45) -> np.ndarray:
    """Gradients (d/dx, d/dy) of modes j = 1..jmax -> float64 (jmax, 2, *x.shape)."""
    x, y = _check_xy(x, y)
    jmax = _check_jmax(jmax)
    r2 = x * x + y * y
    w = x + 1j * y
    out = np.empty((jmax, 2, *x.shape), dtype=np.float64)
    for j in range(1, jmax + 1):
        n, m = noll_to_nm(j)
        am = abs(m)
        terms = _radial_terms(n, am)
        s = sum(c * r2**a for c, a in terms)
        ds = sum(c * a * r2 ** (a - 1) for c, a in terms if a > 0)  # d s / d(rho^2)
        wm = w**am
        dwm = am * w ** (am - 1) if am > 0 else np.zeros_like(w)
        # Z = N * s(r2) * A(w); dA/dx = Re/Im(dwm), dA/dy = Re/Im(i dwm)
        pick = np.real if m >= 0 else np.imag
        a = pick(wm)
        ax = pick(dwm)
        ay = pick(1j * dwm)
        norm = _norm(n, m)
        out[j - 1, 0] = norm * (ds * 2 * x * a + s * ax)
        out[j - 1, 1] = norm * (ds * 2 * y * a + s * ay)
    return out


def _as_coeffs(z, name: str = "zernike") -> np.ndarray:
    z = np.asarray(z, dtype=np.float64)
    if z.ndim != 1 or z.size == 0:
        raise ValueError(f"{name} must be a 1-D Noll coefficient vector, got shape {z.shape}")
    if not np.isfinite(z).all():
        raise ValueError(f"{name} contains NaN or infinite values")
    return z


def wavefront(z, x, y) -> np.ndarray:
    """Wavefront ``sum_j z[j-1] Z_j(x, y)`` in waves, same shape as x (float64).

    Accumulated mode by mode (memory of a few copies of x, not ``len(z)`` of them)."""
    z = _as_coeffs(z)
    x, y = _check_xy(x, y)
    out = np.zeros(x.shape)
    r2 = x * x + y * y
    w = x + 1j * y
    powers: dict[int, np.ndarray] = {0: np.ones(x.shape, dtype=complex)}
    for j in np.flatnonzero(z) + 1:
        n, m = noll_to_nm(int(j))
        am = abs(m)
        if am not in powers:
            powers[am] = w**am
        radial = np.zeros(x.shape)
        for c, a in _radial_terms(n, am):
            radial += c * r2**a
        ang = powers[am].real if m >= 0 else powers[am].imag
        out += (z[j - 1] * _norm(n, m)) * radial * ang
    return out


def noll_indices(modes: Iterable[int] | None, jmax: int) -> np.ndarray:
    """The distinct Noll indices ``modes`` (None: ``1..jmax``), sorted, checked to lie in
    ``1..jmax``.

    Parameters
    ----------
    modes : iterable of int or None
    jmax : int
        The largest Noll index allowed.

    Returns
    -------
    numpy.ndarray of int

    Raises
    ------
    ValueError
        Where ``modes`` is empty or holds an index outside ``1..jmax``.
    """
    if modes is None:
        return np.arange(1, jmax + 1)
    idx = np.asarray(list(modes), dtype=int)
    if idx.size == 0 or idx.min() < 1 or idx.max() > jmax:
        raise ValueError(f"modes must be Noll indices in 1..{jmax}, got {list(idx)}")
    return np.unique(idx)


def fit_zernike(w, x, y, mask=None, jmax: int = 45, modes: Iterable[int] | None = None):
    """Least-squares Zernike coefficients (waves) of a sampled wavefront ``w`` (waves).

    ``mask``: boolean array selecting the samples to fit (default: the unit disk, finite w).
    Returns a float64 vector of length jmax; entries outside ``modes`` are 0.
    """
    x, y = _check_xy(x, y)
    w = np.asarray(w, dtype=np.float64)
    if w.shape != x.shape:
        raise ValueError(f"w must have the shape of x {x.shape}, got {w.shape}")
    jmax = _check_jmax(jmax)
    idx = noll_indices(modes, jmax)
    if mask is None:
        mask = (x * x + y * y) <= 1.0
    else:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != x.shape:
            raise ValueError(f"mask must have the shape of x {x.shape}, got {mask.shape}")
    mask = mask & np.isfinite(w)
    if mask.sum() < idx.size:
        raise ValueError(f"fit_zernike: {int(mask.sum())} samples cannot fit {idx.size} modes")
    basis = zernike_basis(x[mask], y[mask], jmax=int(idx.max()))[idx - 1]
    coef, *_ = np.linalg.lstsq(basis.T, w[mask], rcond=None)
    z = np.zeros(jmax)
    z[idx - 1] = coef
    return z


def random_zernike(rms: float, modes: Iterable[int] = range(4, 46), jmax: int = 45,
                   seed: int = 0) -> np.ndarray:
    """Seeded random Noll vector (length jmax) with ``sqrt(sum z[modes]**2) == rms`` waves.

    Gaussian directions over the chosen modes (default 4-45: no piston, tip, tilt); the
    r.m.s. of the wavefront over the unit disk equals ``rms`` (the modes are orthonormal).
    """
    jmax = _check_jmax(jmax)
    if not (isinstance(rms, (int, float, np.floating)) and np.isfinite(rms) and rms >= 0):
        raise ValueError(f"rms must be a finite non-negative number, got {rms!r}")
    idx = noll_indices(modes, jmax)
    rng = np.random.default_rng(seed)
    v = rng.standard_normal(idx.size)
    z = np.zeros(jmax)
    z[idx - 1] = v * (rms / np.linalg.norm(v))
    return z
