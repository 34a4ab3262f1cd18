"""Any image denoiser as a plug-and-play prior; BM3D through the optional ``bm3d`` package.

Plug-and-play (Venkatakrishnan, Bouman & Wohlberg, GlobalSIP 2013): the proximal operator of the
prior, ``argmin_w weight·R(w) + ½‖w − z‖²``, is the MAP denoiser of ``z`` under white Gaussian
noise of variance ``weight``, so any denoiser ``D(z, sigma)`` stands in for it at ``sigma =
strength · sqrt(weight)``. :class:`FunctionPrior` wraps a NumPy denoiser so; it runs on the host
whatever the solver's device (the image goes there and back once per w-step).

BM3D (Dabov, Foi, Katkovnik & Egiazarian, IEEE TIP 16, 2007; the implementation of Mäkinen,
Azzari & Foi, IEEE TIP 29, 2020) is the texture-preserving denoiser this wraps by default. The
``bm3d`` package is free for non-commercial use only, so it is an optional extra
(``pip install 'metasensor[bm3d]'``), never a dependency or a default; :func:`bm3d_options`
gives the HQS settings that run it. Nothing here is hand-written beyond the adapter.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from metasensor.priors.pnp import check_noise_levels, noise_level
from metasensor.solvers.priors import IDENTITY, Identity

__all__ = ["FunctionPrior", "bm3d_denoise", "bm3d_options", "require_bm3d", "BM3D_INSTALL"]

#: BM3D's binary (``bm4d``) keeps one thread pool per process and aborts the process when two
#: threads call it at once (blocks reconstructed in parallel): its calls are serialised.
_BM3D_LOCK = threading.Lock()

BM3D_INSTALL = ("BM3D needs the optional package bm3d (free for non-commercial use only): "
                "pip install 'metasensor[bm3d]'")


@dataclass(frozen=True)
class FunctionPrior:
    """``prox(z, weight) = denoise(z, clip(strength·sqrt(weight), sigma_min, sigma_max))``, image
    by image.

    Parameters
    ----------
    denoise : callable
        ``denoise(image, sigma) -> image``: a 2D float64 NumPy image in the solver's units (the
        phase-space HQS normalises to mean 0.5) and the standard deviation of its white Gaussian
        noise, same units; returns an array of the image's shape. It is handed a copy of the
        solver's image, and must be deterministic for the solver to be.
    strength : float
        Scale from ``sqrt(weight)`` to the noise level asked for (> 0); larger smooths more.
    sigma_min, sigma_max : float
        The noise level asked for is clamped to this range (``0 <= sigma_min <= sigma_max``).
    """

    denoise: Callable[[np.ndarray, float], np.ndarray]
    strength: float = 1.0
    sigma_min: float = 0.0
    sigma_max: float = 0.2
    transform: Identity = IDENTITY

    def __post_init__(self) -> None:
        if not callable(self.denoise):
            raise TypeError(f"denoise must be callable (image, sigma) -> image, got "
                            f"{type(self.denoise).__name__}")
        check_noise_levels(self.strength, self.sigma_min, self.sigma_max)

    def sigma(self, weight: float) -> float:
        """The noise level the denoiser is asked for at the prox weight ``weight`` (> 0)."""
        return noise_level(weight, self.strength, self.sigma_min, self.sigma_max)

    def prox(self, z: torch.Tensor, weight: float) -> torch.Tensor:
        """Denoise each image of ``z`` (..., H, W) at the noise level of ``weight``."""
        sigma = self.sigma(weight)
        flat = z.detach().reshape(-1, *z.shape[-2:]).to("cpu", torch.float64)
        out = []
        for img in flat.numpy():
            den = np.asarray(self.denoise(img.copy(), sigma), dtype=np.float64)
            if den.shape != img.shape:
                raise ValueError(f"the denoiser returned shape {den.shape} for an image of "
                                 f"shape {img.shape}")
            out.append(torch.from_numpy(den))
        return torch.stack(out).reshape(z.shape).to(z.device, z.dtype)


def require_bm3d():
    """The optional ``bm3d`` module.

    Raises
    ------
    ImportError
        Where the package is not installed, with :data:`BM3D_INSTALL` (the extra to install).
    """
    try:
        import bm3d
    except ImportError as err:
        raise ImportError(BM3D_INSTALL) from err
    return bm3d


def bm3d_denoise(image: np.ndarray, sigma: float) -> np.ndarray:
    """BM3D of a 2D image with white Gaussian noise of standard deviation ``sigma`` (the image's
    units), through the optional ``bm3d`` package (module docstring). One call at a time per
    process: the package's binary is not safe to call from two threads at once.

    Parameters
    ----------
    image : numpy.ndarray
        2D image (any float dtype; read as float64, not modified).
    sigma : float
        Standard deviation of its noise, in the image's units.

    Returns
    -------
    numpy.ndarray
        The denoised image, float64, the image's shape.

    Raises
    ------
    ImportError
        Where the package is not installed, naming the extra that installs it.
    """
    bm3d = require_bm3d()
    with _BM3D_LOCK:
        return np.asarray(bm3d.bm3d(np.asarray(image, dtype=np.float64), float(sigma)))


def bm3d_options(lam_scale: float = 2.0, strength: float = 1.0):
    """HQS options (:class:`metasensor.solvers.hqs_options.HQSOptions`) that run the phase-space
    solver with BM3D as its prior: data weight ``lam_scale`` and a continuation of β from 25
    (BM3D at sigma 0.2 of the mean-0.5 image) to 4096 (sigma 0.016), doubling. The data weight
    was chosen on dead-leaves captures, not on the photographs it is measured on
    (docs/decisions.md). Pass the result as ``reconstruct(..., solver_options=bm3d_options())``.

    Parameters
    ----------
    lam_scale : float
        HQS's data weight scale (:class:`~metasensor.solvers.hqs_options.HQSOptions`).
    strength : float
        :class:`FunctionPrior`'s scale from the prox weight to BM3D's noise level.

    Returns
    -------
    HQSOptions
        The solver's options, the prior a :class:`FunctionPrior` of :func:`bm3d_denoise`.

    Raises
    ------
    ImportError
        Where the optional ``bm3d`` package is not installed (checked here, not mid-solve).
    """
    from metasensor.solvers.hqs_options import HQSOptions
    from metasensor.solvers.splitting import Continuation

    require_bm3d()
    return HQSOptions(prior=FunctionPrior(bm3d_denoise, strength=strength), lam_scale=lam_scale,
                      continuation=Continuation(beta0=25.0, beta_max=4096.0, beta_rate=2.0),
                      noise_estimate="differences")
