"""Settings of :func:`metasensor.reconstruct`: one frozen, validated options object."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from metasensor.dao.estimate import DaoOptions
from metasensor.phasespace.views import ORDERS
from metasensor.recon.dao_choice import DAO_SAMPLES, PROBE_SAMPLES
from metasensor.recon.layers import resolve_depth_layers
from metasensor.solvers.hqs import HQSOptions
from metasensor.solvers.noise_model import PoissonGaussian

__all__ = ["ReconOptions", "SOLVERS", "HQS_MAX_STEP", "NOISE_MODELS"]

SOLVERS = ("rl", "hqs")
NOISE_MODELS = ("global", "fit", "auto")
HQS_MAX_STEP = 5  # HQS up to this scan step (pixels): a 1 x 1 scan would factor 225² systems


def _int_or_none(name: str, value, low: int) -> None:
    if value is not None and (isinstance(value, bool) or not isinstance(value, int | np.integer)
                              or value < low):
        raise ValueError(f"{name} must be an integer >= {low} (or None), got {value!r}")


@dataclass(frozen=True, eq=False)
class ReconOptions:
    """Everything :func:`metasensor.reconstruct` takes besides the views, the system, the method,
    the aberration and the block grid (frozen, validated).

    Attributes
    ----------
    overlap : int
        Block overlap in output pixels (default 20).
    iterations, subsets : int or None
        Richardson–Lucy's iterations and view subsets per iteration (defaults 5, and 16 or 1 for
        scan steps above 5 px: :func:`metasensor.solvers.richardson_lucy.default_subsets`).
    solver : str or None
        ``"hqs"`` (a prior: :mod:`metasensor.solvers.hqs`) or ``"rl"``; None: HQS unless
        ``iterations``/``subsets`` is given or the scan step exceeds 5 px.
    solver_options : HQSOptions or None
        The HQS solver's settings (prior, ``lam_scale``, ``noise``, ...).
    noise_model : str or PoissonGaussian
        The views' noise (:mod:`metasensor.solvers.noise_model`): ``"global"`` (default: one
        weight for every sample, the noise from ``solver_options.noise`` or the data), ``"fit"`` (a
        Poisson–Gaussian model fitted to the views once,
        :func:`metasensor.solvers.noise_fit.fit_poisson_gaussian`; an unreliable fit warns once
        and falls back to ``"global"``), a :class:`PoissonGaussian` (e.g. from the capture's
        metadata, ``PoissonGaussian.from_metadata(cap.noise)``), or ``"auto"`` (the fitted
        model for HQS where the fit is reliable, else silently ``"global"``; Richardson–Lucy
        keeps plain Poisson). HQS weighs each sample by ``1/var``; Richardson–Lucy takes
        the shifted-Poisson form. A model given in ``solver_options`` wins;
        ``Reconstruction.noise_model`` is the model used (None: global).
    register : bool
        Register every block's views against its bank first
        (:mod:`metasensor.dao.bank_registration`; for banks that may be off). Default False.
    view_radius : float or None
        Pupil radius (in views) of the views used (``cfg.view_mask``; default the authors' 113).
    order : str
        View visiting order: "spiral", "radius" or "raster" (:mod:`metasensor.phasespace.views`).
    margin : int or None
        Pixels of view data around each block (default: a given bank's radius, else nnum).
    pad : bool
        Pad the estimate by the PSF radius (linear convolution; False: circular, for study).
    space_variant : bool
        Model each block with PSF banks at its core's four corners, blended bilinearly inside
        the operator (:mod:`metasensor.recon.space_variant`), instead of one bank at its
        centre: PSFs continuous across blocks for aberrations that change inside a block.
        ``method="isa"`` with the HQS solver only; about 4x the solve's cost. Default False.
    field_points : int
        With ``space_variant``: field points per side of each block's core (>= 2; default 2,
        its corners), on an even grid shared with the neighbouring blocks; the banks are
        blended bilinearly between neighbouring points. Where a view's PSF moves by more than
        its width between two points, their blend is two images of a point, not one moved
        image; closer points blend PSFs that differ less. Cost about ``field_points²`` banks.
    depth_layers : str or DepthLayers
        ``"off"`` (default: one bank per block) or ``"auto"`` / a
        :class:`metasensor.recon.layers.DepthLayers` (its settings): a block whose views show
        two depth layers (its disparity, the block's wavefront removed, splits in two) is
        solved with one bank per layer, the block's wavefront plus the layer's defocus, blended
        by the layers' soft masks inside the operator (:mod:`metasensor.recon.layers`); blocks
        of one layer are reconstructed as with ``"off"``. Banks from a Noll vector only (no
        ``psf``, ``space_variant``, ``register`` or geometric DAO), the HQS solver.
    dao : DaoOptions or None
        DAO's settings for ``method="wave"``/``"geometric"`` (its ``method`` is set from
        ``reconstruct``'s).
    dao_negligible : float or None
        Waves r.m.s. (Noll 4-45): a block whose DAO estimate differs from its starting
        aberration by less keeps the bank of that aberration (None: ``method="auto"``'s
        :data:`metasensor.recon.dao_choice.NEGLIGIBLE_RMS`, else 0: always applied).
    dao_probe_samples : int
        View samples per side (at least 8) of the sub-window on which a block's probe decides
        whether its estimate is negligible (default
        :data:`metasensor.recon.dao_choice.PROBE_SAMPLES`; smaller windows are probed whole).
    dao_samples : int
        View samples per side (at least 8) of the sub-window on which a block's DAO estimates
        its wavefront: the most detailed of the block's centre and edges
        (:func:`metasensor.recon.probe.probe_window`; default
        :data:`metasensor.recon.dao_choice.DAO_SAMPLES`; smaller windows are read whole). The
        estimate applies to the whole block; DAO's time and memory grow with this window, not
        with the block.
    device : str or None
        "cpu" or "cuda" (default: CUDA when present).
    psf : numpy.ndarray or None
        A given ``(nnum, nnum, K, K)`` bank for every block (``method="isa"`` only).
    psf_fn : callable or None
        ``psf_fn(cfg, zernike (J,), device) -> bank``, replacing ``optics.psf.view_psfs``.
    scheduler : None, "threads", "sync", an address "tcp://host:port", or a dask Client/cluster
    num_workers : int, "auto" or None
        Local blocks run at once (default 1); ``"auto"``: one per CPU thread, as many as half
        the free memory holds at the largest block window
        (:func:`metasensor.recon.parallel.local_workers`), one on CUDA.
    out : array or None
        A writable ``(H, W)`` float32 array (e.g. zarr) to stitch into; None: NumPy.
    progress : bool
        Show a progress bar.
    """

    overlap: int = 20
    iterations: int | None = None
    subsets: int | None = None
    solver: str | None = None
    solver_options: HQSOptions | None = None
    noise_model: Any = "global"
    register: bool = False
    view_radius: float | None = None
    order: str = "spiral"
    margin: int | None = None
    pad: bool = True
    space_variant: bool = False
    field_points: int = 2
    depth_layers: Any = "off"
    dao: DaoOptions | None = None
    dao_negligible: float | None = None
    dao_probe_samples: int = PROBE_SAMPLES
    dao_samples: int = DAO_SAMPLES
    device: Any = None
    psf: Any = None
    psf_fn: Any = None
    scheduler: Any = None
    num_workers: int | str | None = None
    out: Any = None
    progress: bool = False

    def __post_init__(self) -> None:
        for name, low in (("iterations", 0), ("subsets", 1), ("margin", 0)):
            _int_or_none(name, getattr(self, name), low)
        if self.num_workers != "auto":
            _int_or_none("num_workers", self.num_workers, 1)
        _int_or_none("overlap", self.overlap, 0)
        for name in ("dao_probe_samples", "dao_samples"):
            s = getattr(self, name)
            if isinstance(s, bool) or not isinstance(s, int | np.integer) or s < 8:
                raise ValueError(f"{name} must be an integer >= 8, got {s!r}")
        r = self.view_radius
        if r is not None and (isinstance(r, bool) or not (
                isinstance(r, int | float | np.number) and math.isfinite(r) and r >= 0)):
            raise ValueError(f"view_radius must be a finite number of views >= 0, got {r!r}")
        if self.solver is not None and self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {SOLVERS}, got {self.solver!r}")
        if self.order not in ORDERS:
            raise ValueError(f"order must be one of {ORDERS}, got {self.order!r}")
        if self.solver_options is not None and not isinstance(self.solver_options, HQSOptions):
            raise TypeError("solver_options must be HQSOptions")
        nm = self.noise_model
        if not isinstance(nm, PoissonGaussian) and not (isinstance(nm, str)
                                                         and nm in NOISE_MODELS):
            raise ValueError(f"noise_model must be one of {NOISE_MODELS} or a PoissonGaussian, "
                             f"got {nm!r}")
        if self.dao is not None and not isinstance(self.dao, DaoOptions):
            raise TypeError("dao must be DaoOptions")
        if not isinstance(self.space_variant, bool):
            raise TypeError(f"space_variant must be True or False, got {self.space_variant!r}")
        n = self.field_points
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 2:
            raise ValueError(f"field_points must be an integer >= 2, got {n!r}")
        resolve_depth_layers(self.depth_layers)  # refuses anything else
        g = self.dao_negligible
        if g is not None and (isinstance(g, bool) or not (
                isinstance(g, int | float | np.number) and math.isfinite(g) and g >= 0)):
            raise ValueError(f"dao_negligible must be a non-negative number of waves (or None), "
                             f"got {g!r}")
        if self.psf_fn is not None and not callable(self.psf_fn):
            raise TypeError("psf_fn must be callable(cfg, zernike, device)")

    @classmethod
    def resolve(cls, options: ReconOptions | None, settings: dict) -> ReconOptions:
        """``options`` (default ``ReconOptions()``) with ``settings`` (keywords named as its
        fields) replacing its values; unknown names are refused."""
        base = cls() if options is None else options
        if not isinstance(base, cls):
            raise TypeError(f"options must be ReconOptions, got {type(base).__name__}")
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(settings) - names)
        if unknown:
            raise TypeError(f"reconstruct() got unknown settings {unknown}")
        return replace(base, **settings) if settings else base

    def resolved_solver(self, step: int) -> str:
        """The solver for a scan step of ``step`` pixels (see ``solver``)."""
        if self.solver is not None:
            if self.solver == "hqs" and step > HQS_MAX_STEP:
                raise ValueError(f"solver='hqs' needs a scan step of at most {HQS_MAX_STEP} px "
                                 f"(scan >= 3 for nnum 15), got {step} px; use solver='rl'")
            return self.solver
        rl_asked = self.iterations is not None or self.subsets is not None
        return "rl" if rl_asked or step > HQS_MAX_STEP else "hqs"
