"""Digital adaptive optics: view shifts to wavefronts (:mod:`.wavefront`), the per-block DAO loop
(:mod:`.estimate`, :mod:`.block`), pupil amplitude (:mod:`.pupil`), registration of a PSF bank
against the views (:mod:`.bank_registration`) and global system calibration
(:mod:`.system_aberration`)."""
