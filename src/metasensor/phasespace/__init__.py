"""The phase-space forward model and everything derived from a PSF bank: the operator ``A``
(:mod:`.operator`), its folded normal operator ``AᵀA`` (:mod:`.normal`) and the masked normal
operator of a padded window (:mod:`.masked_normal`)."""
