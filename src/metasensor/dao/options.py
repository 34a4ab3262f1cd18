"""Settings and result of the DAO loop (:func:`metasensor.dao.estimate.run_dao`): one frozen,
validated :class:`DaoOptions` and one :class:`DaoResult` for wave and geometric DAO alike."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from metasensor.dao.wavefront import DAO_MODES
from metasensor.optics.zernike import noll_indices
from metasensor.solvers.krishnan_fergus import DEFAULT_LAMBDA

__all__ = ["DaoOptions", "DaoResult", "resolve_options"]

_METHODS = ("wave", "geometric")
_ESTIMATORS = ("isa", "views")


def _positive(name: str, value) -> None:
    if isinstance(value, bool) or not (isinstance(value, int | float) and math.isfinite(value)
                                       and value > 0):
        raise ValueError(f"{name} must be a positive number, got {value!r}")


@dataclass(frozen=True)
class DaoOptions:
    """Settings of :func:`run_dao` (frozen, validated).

    Attributes
    ----------
    method : str
        ``"wave"`` (PSFs regenerated from the estimated pupil) or ``"geometric"`` (ideal PSFs
        translated by the measured shifts).
    max_iter : int
        Phase updates at most (>= 1; default 5).
    inner : int
        Estimate / measure rounds per update of the ``"views"`` estimator (>= 1; default 3).
    tol : float
        Stop once an update's r.m.s. is below this (waves; 0: run all; default 0.1).
    lam : float
        λ of the views' Krishnan–Fergus deconvolutions (images scaled to [0, 1]; default 5e4).
    max_shift_px : float
        Largest view shift measured (pixels; default 50, the authors' limit).
    max_reach_px : float
        Farthest the estimate's rays may reach (pixels, :func:`metasensor.dao.banks.ray_reach_px`;
        default 200): an update going beyond is shortened to stay within, or refused where even a
        quarter of it would not. It bounds the banks' windows (about ``2·(reach + margin) + 1``
        pixels) and so their memory.
    modes : tuple of int or None
        Noll modes fitted; None (default): the largest leading set, up to 4–45, that the views
        used determine well (:func:`metasensor.dao.modes.choose_modes`, which also refuses
        given modes the views cannot determine).
    chunk : int
        Views processed together (default 16).
    psf_size : int, "auto" or None
        PSF window K: "auto" :func:`metasensor.dao.banks.psf_window` of the current estimate
        over the used views; None ``view_psfs``' default; or an odd int.
    weigh_views : bool
        Weight every view's shift in the fit by its precision (default True; False: the paper's
        plain least squares).
    estimator : str
        ``"isa"`` (default: the views' mean while the last update exceeds ``isa_below`` waves,
        then the block's ISA) or ``"views"`` (always the paper's mean).
    isa_below : float
        Waves (>= 0; default 0.5; ``inf``: the ISA from the first update).
    progress : bool
        Show a progress bar (closed on return and on error).
    """

    method: str = "wave"
    max_iter: int = 5
    inner: int = 3
    tol: float = 0.1
    lam: float = DEFAULT_LAMBDA
    max_shift_px: float = 50.0
    max_reach_px: float = 200.0
    modes: tuple | None = None
    chunk: int = 16
    psf_size: int | str | None = "auto"
    weigh_views: bool = True
    estimator: str = "isa"
    isa_below: float = 0.5
    progress: bool = False

    def __post_init__(self) -> None:
        if self.method not in _METHODS:
            raise ValueError(f"method must be 'wave' or 'geometric', got {self.method!r}")
        if self.estimator not in _ESTIMATORS:
            raise ValueError(f"estimator must be 'isa' or 'views', got {self.estimator!r}")
        if not self.isa_below >= 0:
            raise ValueError(f"isa_below must be a non-negative number of waves, "
                             f"got {self.isa_below!r}")
        if self.max_iter < 1 or self.inner < 1:
            raise ValueError(f"max_iter and inner must be >= 1, got {self.max_iter}, "
                             f"{self.inner}")
        _positive("lam", self.lam)
        _positive("max_shift_px", self.max_shift_px)
        _positive("max_reach_px", self.max_reach_px)
        if not (isinstance(self.tol, int | float) and math.isfinite(self.tol) and self.tol >= 0):
            raise ValueError(f"tol must be a non-negative number of waves, got {self.tol!r}")
        if not (isinstance(self.chunk, int | np.integer) and self.chunk >= 1):
            raise ValueError(f"chunk must be a positive integer, got {self.chunk!r}")
        size = self.psf_size
        if not (size is None or size == "auto" or (
                isinstance(size, int | np.integer) and size > 0 and size % 2)):
            raise ValueError(f"psf_size must be 'auto', None or a positive odd int, got {size!r}")
        if self.modes is not None:
            try:
                modes = noll_indices(self.modes, max(DAO_MODES))
            except (TypeError, ValueError) as exc:
                raise ValueError(f"{exc} (or None: chosen from the views)") from None
            object.__setattr__(self, "modes", tuple(int(j) for j in modes))


@dataclass
class DaoResult:
    """What one DAO run produced.

    Attributes
    ----------
    zernike : numpy.ndarray
        ``(45,)`` Noll vector, waves.
    history : list of float
        r.m.s. (waves) of every update.
    shifts : numpy.ndarray
        ``(nnum, nnum, 2)`` pixels (y, x): the view shifts of the result's PSF bank against the
        aberration-free bank, for either method (geometric: the accumulated shifts the ideal
        PSFs are translated by; wave: the shifts the estimated wavefront's gradient predicts,
        :func:`gradient_shifts`); 0 for unused views.
    residual_shifts : numpy.ndarray
        ``(nnum, nnum, 2)`` pixels: the shifts the last update measured against the bank then
        in use (the misfit it corrected); 0 for unused views.
    method : str
    image : numpy.ndarray or None
        The last intermediate estimate I (pixel grid, the views' scale).
    fits : list of float
        Residual r.m.s. (pixels) of every shift fit.
    psf_size : int or None
        K of the banks (None: ``view_psfs``' default window).
    estimates : list of numpy.ndarray
        φ ``(45,)`` after every update.
    steps : list of float
        The fraction of every fitted update applied: 1, or less where the whole update would
        send the rays beyond twice ``max_shift_px`` (:func:`metasensor.dao.estimate.run_dao`).
    modes : tuple of int
        The Noll modes fitted (:func:`metasensor.dao.modes.choose_modes`).
    """

    zernike: np.ndarray
    history: list[float]
    shifts: np.ndarray
    method: str
    residual_shifts: np.ndarray | None = None
    image: np.ndarray | None = None
    fits: list[float] = field(default_factory=list)
    psf_size: int | None = None
    estimates: list[np.ndarray] = field(default_factory=list)
    steps: list[float] = field(default_factory=list)
    modes: tuple = DAO_MODES


def resolve_options(options: DaoOptions | None, settings: dict) -> DaoOptions:
    """``options`` (default ``DaoOptions()``) with ``settings`` (its field names) replacing
    its values; unknown names are refused."""
    base = DaoOptions() if options is None else options
    if not isinstance(base, DaoOptions):
        raise TypeError(f"options must be DaoOptions, got {type(base).__name__}")
    unknown = set(settings) - set(DaoOptions.__dataclass_fields__)
    if unknown:
        raise TypeError(f"run_dao got unknown settings {sorted(unknown)}")
    return replace(base, **settings) if settings else base
