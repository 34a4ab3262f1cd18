"""Wave optics: Zernike polynomials, pupils, the coded-MLA phase-space PSFs, turbulence.

Public: :func:`view_psfs`, :func:`widefield_psf` (``optics.psf``), the Zernike tools
(``optics.zernike``), pupil functions (``optics.pupil``), the PSF cache (``optics.cache``) and
:func:`load_psf` / :func:`save_psf` (HDF5 banks written by ``metasensor psf``).
"""

from metasensor.optics.psf import view_psfs, widefield_psf
from metasensor.optics.zernike import (
    fit_zernike,
    noll_to_nm,
    random_zernike,
    wavefront,
    zernike_basis,
    zernike_gradients,
)

__all__ = [
    "view_psfs",
    "widefield_psf",
    "noll_to_nm",
    "zernike_basis",
    "zernike_gradients",
    "wavefront",
    "fit_zernike",
    "random_zernike",
]
