"""Solvers of the phase-space inverse problem, all on one
:class:`~metasensor.phasespace.operator.PhaseSpaceOperator`: ordered-subset Richardson–Lucy
(:mod:`.richardson_lucy`), half-quadratic splitting with a pluggable prior (:mod:`.hqs` on the
loop of :mod:`.splitting`, priors in :mod:`.priors`), regularised least squares
(:mod:`.tikhonov`), and the single-kernel Krishnan–Fergus deconvolution (:mod:`.krishnan_fergus`).

``solve(op, y, mask, options)`` runs the solver that ``options`` configures.
"""

from __future__ import annotations

__all__ = ["solve"]


def solve(op, y, mask, options, progress=None):
    """Run the solver ``options`` configures on ``op``.

    Parameters
    ----------
    op : PhaseSpaceOperator
        The forward model.
    y : array_like
        ``(V, My, Mx)`` view samples on the operator's sample grid, zero where unobserved.
    mask : array_like
        ``(My, Mx)`` bool, True on observed samples.
    options : RLOptions or HQSOptions
        Richardson–Lucy (:class:`~metasensor.solvers.richardson_lucy.RLOptions`) or
        half-quadratic splitting with a prior (:class:`~metasensor.solvers.hqs.HQSOptions`).
    progress : callable, optional
        Called with 1 per iteration (RL) or per β (HQS; with 0 first, once its set-up is done).

    Returns
    -------
    SolveResult
        The estimate on the operator's domain and the residual history.
    """
    from metasensor.solvers.hqs import HQSOptions, hqs
    from metasensor.solvers.richardson_lucy import RLOptions, richardson_lucy

    if isinstance(options, RLOptions):
        return richardson_lucy(op, y, mask, options, progress=progress)
    if isinstance(options, HQSOptions):
        return hqs(op, y, mask, options, progress=progress)
    raise TypeError(f"options must be RLOptions or HQSOptions, got {type(options).__name__}")
