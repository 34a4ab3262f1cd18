"""The noise the solvers' data term is weighed by, decided once per capture: the
Poisson–Gaussian model :class:`~metasensor.recon.options.ReconOptions` asks for, the model
behind HQS's ``noise_estimate="poisson-gaussian"`` or ``"auto"``, and whether the views carry
measurable noise at all (HQS's x-step tolerance); all fitted on the whole capture
(:func:`metasensor.solvers.noise_fit.fit_poisson_gaussian`), as one block may hold too few
smooth samples for a fit of its own."""

from __future__ import annotations

from metasensor.recon.options import ReconOptions

__all__ = ["noise_model", "capture_noise"]


def noise_model(views, opts: ReconOptions, solver: str):
    """The Poisson–Gaussian model ``opts.noise_model`` asks for (fitted here for ``"fit"`` and
    ``"auto"``: once, on the whole stack), or None for one global weight."""
    if not isinstance(opts.noise_model, str):
        return opts.noise_model
    if opts.noise_model == "global" or (opts.noise_model == "auto" and solver != "hqs"):
        return None
    import warnings

    from metasensor.solvers.noise_fit import fit_poisson_gaussian

    if opts.noise_model == "auto":  # quietly global where the fit is refused or imprecise
        with warnings.catch_warnings():
            warnings.simplefilter("error", UserWarning)
            try:
                return fit_poisson_gaussian(views).model
            except (ValueError, UserWarning):
                return None
    try:
        return fit_poisson_gaussian(views).model
    except ValueError as exc:
        warnings.warn(f"reconstruct: the noise fit failed ({exc}); using one global noise "
                      "weight", UserWarning, stacklevel=4)
        return None


def capture_noise(hqs_opts, views):
    """HQS's settings for this capture's ``views``, decided once on the whole capture (a block
    may hold too few smooth samples for a fit of its own).

    ``noise_estimate`` ``"poisson-gaussian"`` or ``"auto"`` becomes the model fitted here
    (:func:`~metasensor.solvers.noise_fit.fit_poisson_gaussian`); ``"auto"`` becomes
    ``"differences"`` where the views do not follow the model (refused, or ``NoiseFit.holds``
    false: no measurable noise). Under every ``noise_estimate``, views that carry no measurable
    noise get their x-steps solved to ``NOISELESS_CG_TOL`` (no noise hides a loose solve there;
    a tighter ``cg_tol`` given is kept). ``"poisson-gaussian"`` keeps its name (no model)
    where its fit is refused (each solve then tries its own, or warns). Nothing is measured
    where the noise is given or a ``noise_model`` weighs the samples (its own σ is used
    then)."""
    from dataclasses import replace

    from metasensor.solvers.hqs_options import NOISELESS_CG_TOL
    from metasensor.solvers.noise_fit import fit_poisson_gaussian, quiet_fit

    if (not isinstance(hqs_opts.noise_estimate, str) or hqs_opts.noise is not None
            or hqs_opts.noise_model is not None or views is None):
        return hqs_opts  # a given noise or model, or weights whose own σ the solver uses
    def precise(opts):
        return replace(opts, cg_tol=min(opts.cg_tol, NOISELESS_CG_TOL))

    if hqs_opts.noise_estimate == "poisson-gaussian":  # its own fit, warnings shown
        try:
            fit = fit_poisson_gaussian(views)
        except ValueError:
            return precise(hqs_opts)
        opts = replace(hqs_opts, noise_estimate=fit.model)
        return opts if fit.holds() else precise(opts)
    fit = quiet_fit(views)
    if fit is not None and fit.holds():
        if hqs_opts.noise_estimate == "auto":
            return replace(hqs_opts, noise_estimate=fit.model)
        return hqs_opts
    return precise(replace(hqs_opts, noise_estimate="differences"))
