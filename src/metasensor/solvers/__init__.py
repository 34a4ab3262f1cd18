"""Solvers of the phase-space inverse problem: ordered-subset Richardson–Lucy
(:mod:`.richardson_lucy`), half-quadratic splitting with a pluggable prior (:mod:`.hqs`) and the
single-kernel Krishnan–Fergus deconvolution (:mod:`.krishnan_fergus`)."""
