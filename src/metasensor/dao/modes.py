"""Which Zernike modes DAO fits: the leading Noll set the views' shifts can determine.

DAO fits the views' shifts by Noll modes and a common shift
(:func:`metasensor.dao.wavefront.fit_shifts`): two equations per view. With many views (the
prototype's 113) modes 4–45 are well determined; with few (small lenslets, a small
``view_radius``) they are not: the fit's matrix is rank-deficient or nearly so, and the shifts
of low orders are assigned partly to high ones (the defocus and astigmatism of an estimate
come out wrong while the fit looks fine). Where the caller has not chosen the modes
(``DaoOptions(modes=None)``), :func:`choose_modes` takes the largest leading set ``4..j``, ``j``
completing a radial order (:data:`ORDER_ENDS`), whose fit has a condition number of at most
:data:`MAX_CONDITION`, and warns when that is fewer than 4–45. Modes the caller chose are used
as given unless the views cannot determine them at all (a rank-deficient fit), which is refused.
Why the bound is what it is: docs/decisions.md ("daomodes").
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from metasensor.config import SystemConfig
from metasensor.dao.wavefront import DAO_MODES, gradient_matrix
from metasensor.optics.zernike import noll_indices

__all__ = ["ORDER_ENDS", "MAX_CONDITION", "fit_condition", "choose_modes"]

#: the Noll indices that complete radial orders 2..8: DAO's candidate sets are 4..j for these j
ORDER_ENDS = (6, 10, 15, 21, 28, 36, 45)
#: the largest condition number of the shift fit (modes and common shift, unweighted) with
#: which :func:`choose_modes` fits a mode set
MAX_CONDITION = 100.0


def _design(cfg: SystemConfig, used, modes, matrix, min_footprint: float) -> np.ndarray:
    """The unweighted shift-fit matrix ``(2·views, modes + 2)`` of the usable views."""
    g, frac = gradient_matrix(cfg, jmax=max(45, *modes)) if matrix is None else matrix
    use = np.asarray(used, dtype=bool) & (frac >= min_footprint)
    idx = np.asarray(modes, dtype=int) - 1
    k = int(use.sum())
    a = np.concatenate([g[use][..., idx], np.broadcast_to(np.eye(2), (k, 2, 2))], axis=-1)
    return a.reshape(2 * k, idx.size + 2)


def fit_condition(cfg: SystemConfig, used, modes, matrix=None,
                  min_footprint: float = 0.5) -> float:
    """Condition number of the shift fit of ``modes`` (and a common shift) over the views
    ``used`` whose footprint lies at least ``min_footprint`` inside the pupil.

    Parameters
    ----------
    cfg : SystemConfig
    used : array_like
        ``(nnum, nnum)`` bool, the views fitted.
    modes : iterable of int
        Noll indices.
    matrix : tuple, optional
        :func:`metasensor.dao.wavefront.gradient_matrix`'s result.
    min_footprint : float
        As :func:`metasensor.dao.wavefront.fit_shifts`.

    Returns
    -------
    float
        The ratio of the largest to the smallest singular value; ``inf`` where there are fewer
        equations than unknowns or the matrix is singular.
    """
    a = _design(cfg, used, tuple(int(j) for j in modes), matrix, min_footprint)
    if a.shape[0] < a.shape[1]:
        return math.inf
    sv = np.linalg.svd(a, compute_uv=False)
    return float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf


def _span(modes) -> str:
    m = sorted(modes)
    return f"{m[0]}-{m[-1]}" if m == list(range(m[0], m[-1] + 1)) else str(m)


def _auto(cfg: SystemConfig, used, matrix, n_views: int) -> tuple[tuple[int, ...], float]:
    """The largest well-conditioned leading set and the condition of the next larger one."""
    above = math.inf
    for j in sorted(ORDER_ENDS, reverse=True):
        cond = fit_condition(cfg, used, range(4, j + 1), matrix)
        if cond <= MAX_CONDITION:
            return tuple(range(4, j + 1)), above
        above = cond
    raise ValueError(f"the {n_views} views used cannot determine even Noll modes 4-6 (shift "
                     f"fit condition number {above:.3g}): DAO cannot estimate a wavefront; "
                     "use more views (a larger view_radius)")


def choose_modes(cfg: SystemConfig, used, modes=None, matrix=None, *, warn: bool = True,
                 stacklevel: int = 2) -> tuple[int, ...]:
    """The Noll modes DAO fits with the views ``used`` (module docstring).

    Parameters
    ----------
    cfg : SystemConfig
    used : array_like
        ``(nnum, nnum)`` bool, the views DAO measures.
    modes : iterable of int or None
        The caller's modes, checked: refused (ValueError) where their fit is rank-deficient
        for these views. None: the largest leading set ``4..j`` (``j`` in :data:`ORDER_ENDS`)
        whose fit's condition number is at most :data:`MAX_CONDITION`; ValueError where not
        even 4–6 is.
    matrix : tuple, optional
        :func:`metasensor.dao.wavefront.gradient_matrix`'s result.
    warn : bool
        Warn once (``UserWarning``) when the chosen set is smaller than 4–45.
    stacklevel : int
        Of the warning, as for :func:`warnings.warn` called here (2: this function's caller).

    Returns
    -------
    tuple of int
    """
    n_views = int(np.asarray(used, dtype=bool).sum())
    if modes is None:
        chosen, above = _auto(cfg, used, matrix, n_views)
        if warn and len(chosen) < len(DAO_MODES):
            nxt = ORDER_ENDS[ORDER_ENDS.index(chosen[-1]) + 1]
            warnings.warn(f"DAO fits Noll modes {_span(chosen)}, not {_span(DAO_MODES)}: the "
                          f"{n_views} views used cannot determine more (modes 4-{nxt}: shift "
                          f"fit condition number {above:.3g}); choose them with "
                          "DaoOptions(modes=...) or use more views (view_radius)", UserWarning,
                          stacklevel=stacklevel)
        return chosen
    jmax = 45 if matrix is None else matrix[0].shape[-1]
    given = tuple(int(j) for j in noll_indices(modes, jmax))
    a = _design(cfg, used, given, matrix, 0.5)
    if a.shape[0] < a.shape[1] or np.linalg.matrix_rank(a) < a.shape[1]:
        try:
            best = _auto(cfg, used, matrix, n_views)[0][-1]
            hint = f", e.g. DaoOptions(modes=tuple(range(4, {best + 1})))"
        except ValueError:
            hint = ""
        raise ValueError(f"DaoOptions(modes=...): the {n_views} views used cannot determine "
                         f"Noll modes {_span(given)} (rank-deficient shift fit: {a.shape[0]} "
                         f"equations, {a.shape[1]} unknowns with the common shift); fit fewer "
                         f"modes{hint}")
    return given
