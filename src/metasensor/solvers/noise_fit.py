"""Fit the Poisson–Gaussian noise model ``var(y) = a·y + b`` to the views themselves.

Hand-written: scikit-image's ``estimate_sigma`` gives one global σ and no library ships the
signal-dependent fit. The method is that of Foi et al. (IEEE TIP 17, 1737–1754, 2008,
"Practical Poissonian–Gaussian noise modeling and fitting for single-image raw-data"), on the
view samples (each one sensor pixel, noise independent between samples):

1. detail ``d = (k ⊗ k) ∗ y / 6`` with ``k = [1, −2, 1]`` (a separable second difference: it
   removes every signal that is linear along either axis, and ``E d² = Σ w_i var(y_i)`` with
   ``w = (k ⊗ k)² / 36``), and the local level ``m = w ∗ y`` (weights summing to 1), so that
   ``E d² = a·E m + b`` exactly under the model;
2. smooth samples: per level bin, those whose local gradient (of a 5 x 5 mean) is below the bin's
   median (edges and texture add signal to ``d``); samples next to a clipped value (0 or the
   largest value) are left out (clipping lowers the variance);
3. per bin (equal counts along ``m``): the robust variance ``(1.4826·MAD(d))²``;
4. the line ``a·m + b`` through the bins' (level, variance) by robust least squares (SciPy's
   ``least_squares``, soft-L1 loss, each bin's residual divided by its standard error).
5. twice more: each bin's variance re-measured with every sample's detail divided by its σ
   under the fitted line (a bin spanning levels of different variance, as the sparse dark end
   does, is a scale mixture whose MAD understates the mean variance), and the line refitted.

The fit is refused (one-line ValueError) with too few usable bins or a negative slope, and
warns once where ``a`` is poorly determined (the levels span too little).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from metasensor.solvers.noise_model import PoissonGaussian

__all__ = ["NoiseFitOptions", "NoiseFit", "fit_poisson_gaussian", "fitted_noise_rms",
           "quiet_fit", "MAX_LACK_OF_FIT"]

MAD_SIGMA = 1.4826  # σ of a normal distribution per median absolute deviation
MAD_VAR_EFFICIENCY = 2.72  # variance of a MAD-based σ² estimate over the sample variance's
#: lack of fit (reduced χ² of the bins) above which the views are taken not to follow the model:
#: noisy captures read well below it, noise-free ones (the variance is the scene's) well above
#: (the measurements: docs/decisions.md)
MAX_LACK_OF_FIT = 500.0


@dataclass(frozen=True)
class NoiseFitOptions:
    """Settings of :func:`fit_poisson_gaussian` (frozen, validated).

    Attributes
    ----------
    bins : int
        Level bins (equal sample counts), >= 3 (default 16).
    min_samples : int
        Smooth samples a bin needs to count (default 400).
    min_bins : int
        Usable bins the fit needs, >= 3 (default 4).
    max_views : int
        Views used at most, evenly spread over the lit ones (default 25).
    max_side : int
        Samples per side of each view used at most (a central crop; default 256).
    smooth_quantile : float
        Per bin, the samples whose local gradient is below this quantile count as smooth
        (default 0.5).
    max_rel_error : float
        Relative standard error of ``a`` above which the fit warns (default 0.25).
    """

    bins: int = 16
    min_samples: int = 400
    min_bins: int = 4
    max_views: int = 25
    max_side: int = 256
    smooth_quantile: float = 0.5
    max_rel_error: float = 0.25

    def __post_init__(self) -> None:
        for name, low in (("bins", 3), ("min_samples", 10), ("min_bins", 3), ("max_views", 1),
                          ("max_side", 8)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {value!r}")
        if self.min_bins > self.bins:
            raise ValueError(f"min_bins ({self.min_bins}) exceeds bins ({self.bins})")
        if not (0 < self.smooth_quantile <= 1):
            raise ValueError(f"smooth_quantile must be in (0, 1], got {self.smooth_quantile!r}")
        if not (self.max_rel_error > 0 and math.isfinite(self.max_rel_error)):
            raise ValueError(f"max_rel_error must be > 0, got {self.max_rel_error!r}")


@dataclass(frozen=True)
class NoiseFit:
    """Result of :func:`fit_poisson_gaussian`.

    Attributes
    ----------
    model : PoissonGaussian
        The fitted model (``source="fit"``; ``b`` clipped at 0).
    a_error, b_error : float
        Standard errors of ``a`` and of the unclipped ``b``.
    levels, variances, counts : numpy.ndarray
        The bins' mean level, robust variance (data units, units²) and smooth-sample count.
    lack_of_fit : float
        The bins' mean squared distance from the fitted line, in their standard errors (a
        reduced χ²): near 1 where the smooth samples' variance is noise that follows the model,
        far above it where it is the scene's own structure (views without measurable noise).
    """

    model: PoissonGaussian
    a_error: float
    b_error: float
    levels: np.ndarray
    variances: np.ndarray
    counts: np.ndarray
    lack_of_fit: float = float("nan")

    def holds(self, max_lack_of_fit: float = MAX_LACK_OF_FIT) -> bool:
        """Whether the views follow the fitted model: ``lack_of_fit`` at most
        ``max_lack_of_fit`` (default :data:`MAX_LACK_OF_FIT`)."""
        return bool(self.lack_of_fit <= max_lack_of_fit)


def _select(views: np.ndarray, options: NoiseFitOptions) -> np.ndarray:
    """``(n, h, w)`` float64: up to ``max_views`` lit views (evenly spread), centrally cropped."""
    arr = views if hasattr(views, "shape") and hasattr(views, "__getitem__") else np.asarray(
        views)
    shape = tuple(arr.shape)
    if len(shape) not in (3, 4):
        raise ValueError(f"views must have shape (nnum, nnum, H, W) or (V, H, W), got {shape}")
    if min(shape[-2:]) < 8:
        raise ValueError(f"views of {shape[-2:]} samples are too small to fit noise "
                         "(at least 8 x 8)")
    h, w = shape[-2:]
    s = options.max_side
    ys, xs = slice(max((h - s) // 2, 0), max((h - s) // 2, 0) + s), slice(
        max((w - s) // 2, 0), max((w - s) // 2, 0) + s)
    index = ([(i,) for i in range(shape[0])] if len(shape) == 3 else
             [(u, v) for u in range(shape[0]) for v in range(shape[1])])

    def crop(i: int) -> np.ndarray:
        return np.asarray(arr[(*index[i], ys, xs)], np.float64)

    means = np.array([float(crop(i).mean()) for i in range(len(index))])
    if not np.all(np.isfinite(means)):
        raise ValueError("views contain NaN or infinite values")
    lit = np.flatnonzero(means > 0.05 * means.max()) if means.max() > 0 else []
    if len(lit) == 0:
        raise ValueError("views hold no light: no noise to fit")
    pick = lit[np.unique(np.linspace(0, len(lit) - 1, min(options.max_views, len(lit)))
                         .round().astype(int))]
    return np.stack([crop(i) for i in pick])


def _statistics(stack: np.ndarray):
    """Per sample (valid interior): detail d, level m, gradient g, clipped-neighbour flag."""
    from scipy import ndimage

    k = np.array([1.0, -2.0, 1.0])
    w = k**2 / 6.0
    d = ndimage.correlate1d(ndimage.correlate1d(stack, k, axis=1), k, axis=2) / 6.0
    m = ndimage.correlate1d(ndimage.correlate1d(stack, w, axis=1), w, axis=2)
    box = ndimage.uniform_filter(stack, size=(1, 5, 5))
    g = np.hypot(ndimage.sobel(box, axis=1), ndimage.sobel(box, axis=2))
    lo, hi = float(stack.min()), float(stack.max())
    clipped = ndimage.maximum_filter((stack <= lo) | (stack >= hi), size=(1, 3, 3))
    inner = (slice(None), slice(2, -2), slice(2, -2))
    keep = ~clipped[inner]
    return d[inner][keep], m[inner][keep], g[inner][keep]


def _bins(d, m, g, options: NoiseFitOptions, line: tuple[float, float] | None = None):
    """(level, robust variance, count) of each bin with enough smooth samples.

    With ``line`` = (a, b), each sample's detail is first divided by its predicted σ
    ``sqrt(a·m + b)`` and the bin's variance is the prediction at the bin's mean level times the
    robust variance of those ratios: a bin spanning levels of different variance (the sparse
    dark end) is a scale mixture, whose MAD understates its mean variance."""
    order = np.argsort(m, kind="stable")
    out = []
    for idx in np.array_split(order, options.bins):
        if idx.size == 0:
            continue
        smooth = idx[g[idx] <= np.quantile(g[idx], options.smooth_quantile)]
        if smooth.size < options.min_samples:
            continue
        level = float(m[smooth].mean())
        if line is None:
            dv, unit = d[smooth], 1.0
        else:
            floor = 1e-6 * max(line[0] * level + line[1], 1e-30)
            dv = d[smooth] / np.sqrt(np.maximum(line[0] * m[smooth] + line[1], floor))
            unit = max(line[0] * level + line[1], floor)
        mad = float(np.median(np.abs(dv - np.median(dv))))
        out.append((level, unit * (MAD_SIGMA * mad) ** 2, smooth.size))
    return np.array(out, dtype=np.float64).reshape(-1, 3)


def _line(levels, variances, counts):
    """Robust weighted fit of ``variance = a·level + b``: (a, b, a_error, b_error)."""
    from scipy.optimize import least_squares

    se_rel = np.sqrt(2.0 * MAD_VAR_EFFICIENCY / counts)
    design = np.stack([levels, np.ones_like(levels)], 1)
    p0 = np.linalg.lstsq(design / (variances * se_rel)[:, None], 1.0 / se_rel, rcond=None)[0]
    for _ in range(3):  # the standard errors from the line (not the noisy bin variances)
        se = np.maximum(design @ p0, 1e-12 * variances.max()) * se_rel
        fit = least_squares(lambda p, se=se: (design @ p - variances) / se, p0, loss="soft_l1")
        p0 = fit.x
    cov = np.linalg.pinv(fit.jac.T @ fit.jac)
    return float(p0[0]), float(p0[1]), float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1]))


def fit_poisson_gaussian(views, options: NoiseFitOptions = NoiseFitOptions()) -> NoiseFit:
    """Fit ``var(y) = a·y + b`` to the views' own noise (module docstring).

    Parameters
    ----------
    views : array_like
        ``(nnum, nnum, H, W)`` view stack or ``(V, H, W)`` views (data units, e.g. DN, zero
        level at 0); not modified. A zarr array is read in the crops used only.
    options : NoiseFitOptions
        Bins, sample counts, crop.

    Returns
    -------
    NoiseFit
        The model and its standard errors, and the bins it was fitted to.
    """
    if not isinstance(options, NoiseFitOptions):
        raise TypeError(f"options must be NoiseFitOptions, got {type(options).__name__}")
    d, m, g = _statistics(_select(views, options))
    bins = _bins(d, m, g, options)
    if len(bins) < options.min_bins:
        raise ValueError(f"noise fit unreliable: {len(bins)} level bins with {options.min_samples}"
                         f" smooth samples each, {options.min_bins} needed (views too small or "
                         "too textured)")
    levels, variances, counts = bins.T
    a, b, a_err, b_err = _line(levels, variances, counts)
    for _ in range(2):  # the bins' variances re-measured under the fitted line
        if not a > 0:
            break
        levels, variances, counts = _bins(d, m, g, options, (a, max(b, 0.0))).T
        a, b, a_err, b_err = _line(levels, variances, counts)
    if not a > 0:
        raise ValueError(f"noise fit unreliable: the variance falls with the level (slope "
                         f"{a:.3g}); the views do not follow a Poisson-Gaussian model")
    if a_err > options.max_rel_error * a:
        warnings.warn(f"noise fit: the gain a = {a:.3g} is poorly determined (standard error "
                      f"{a_err / a:.0%}); the views' levels span too little", UserWarning,
                      stacklevel=2)
    return NoiseFit(PoissonGaussian(a, max(b, 0.0), source="fit"), a_err, b_err, levels,
                    variances, counts.astype(np.int64), _lack_of_fit(a, b, levels, variances,
                                                                     counts))


def _lack_of_fit(a: float, b: float, levels, variances, counts) -> float:
    """Reduced χ² of the bins about the line ``a·level + b`` (each bin's standard error that of
    a MAD-based variance of its count of samples)."""
    predicted = np.maximum(a * levels + max(b, 0.0), 1e-30)
    se = predicted * np.sqrt(2.0 * MAD_VAR_EFFICIENCY / counts)
    return float(np.mean(((predicted - variances) / se) ** 2))


def quiet_fit(views) -> NoiseFit | None:
    """:func:`fit_poisson_gaussian` of ``views`` (a tensor or array, default options), or None
    where the fit is refused; its warnings are not shown (the caller judges the fit, e.g. by
    :meth:`NoiseFit.holds`)."""
    if hasattr(views, "detach"):
        views = views.detach().cpu().numpy()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        try:
            return fit_poisson_gaussian(views)
        except ValueError:
            return None


def fitted_noise_rms(data, mask=None, options: NoiseFitOptions = NoiseFitOptions()) -> float:
    """The r.m.s. noise of view samples under their own fitted Poisson–Gaussian model.

    ``PoissonGaussian.rms`` over the observed samples, ``(a, b)`` from
    :func:`fit_poisson_gaussian` on the same samples. Unlike a global median of second
    differences, the fit reads only smooth samples, so texture and the coarse samples of a
    sparse scan do not raise it.

    Parameters
    ----------
    data : torch.Tensor or array_like
        ``(V, My, Mx)`` view samples (data units, zero level at 0); not modified.
    mask : torch.Tensor or array_like, optional
        ``(My, Mx)`` bool, True on observed samples (unobserved ones are zero, which the fit
        leaves out as clipped); default all.
    options : NoiseFitOptions
        The fit's settings.

    Returns
    -------
    float
        Noise r.m.s., data units.

    Raises
    ------
    ValueError
        Where the views do not support the fit (:func:`fit_poisson_gaussian`).
    """
    import torch

    y = torch.as_tensor(data)
    if y.ndim != 3:
        raise ValueError(f"data must be (V, My, Mx) view samples, got shape {tuple(y.shape)}")
    model = fit_poisson_gaussian(y.detach().cpu().numpy(), options).model
    return model.rms(y, None if mask is None else torch.as_tensor(mask))
