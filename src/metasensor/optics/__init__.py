"""Wave optics: Zernike polynomials, pupils, the coded-MLA phase-space PSFs, turbulence.

Public: :func:`view_psfs` (``optics.psf``), :func:`widefield_psf` (``optics.widefield``), the
Zernike tools (``optics.zernike``), pupil functions (``optics.pupil``), the PSF cache
(``optics.cache``) and :func:`load_psf` / :func:`save_psf` (HDF5 banks written by
``metasensor psf``).
"""

from metasensor.optics import zernike as _zernike
from metasensor.optics.psf import view_psfs
from metasensor.optics.widefield import widefield_psf
from metasensor.optics.zernike import *  # noqa: F403 - the Zernike tools, zernike.__all__

__all__ = ["view_psfs", "widefield_psf", *_zernike.__all__]
