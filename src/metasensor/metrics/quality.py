"""Full-reference image quality: PSNR, SSIM (scikit-image) and the SNR of a noisy signal.

Both take their images by keyword only, ``psnr(truth=..., image=...)``: scikit-image's order
is ``(truth, image)`` and this package's was the reverse, so a positional call could silently
swap them (the data range, and therefore the answer, follows the truth). Images are compared
**as given**: no rescaling or matching of the intensity scale. ``data_range``
defaults to the range of the reference, ``truth.max() - truth.min()`` (as in the paper's figures;
scikit-image would otherwise guess it from the dtype).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["psnr", "ssim", "snr_db"]


def _pair(image, truth, names=("image", "truth")) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(image)
    b = np.asarray(truth)
    for arr, name in ((a, names[0]), (b, names[1])):
        if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
            raise TypeError(f"{name} must be a real numeric array, got dtype {arr.dtype}")
        if arr.ndim != 2:
            raise ValueError(f"{name} must be a 2-D image (H, W), got shape {arr.shape}")
    if a.shape != b.shape:
        raise ValueError(f"{names[0]} shape {a.shape} differs from {names[1]} shape {b.shape}")
    for arr, name in ((a, names[0]), (b, names[1])):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} contains NaN or infinite values")
    return a.astype(np.float64), b.astype(np.float64)


def _range(truth: np.ndarray, data_range) -> float:
    if data_range is None:
        data_range = float(truth.max() - truth.min())
    if not (np.isfinite(data_range) and data_range > 0):
        raise ValueError(f"data_range must be positive (a constant truth needs an explicit "
                         f"data_range), got {data_range!r}")
    return float(data_range)


def psnr(*, truth, image, data_range: float | None = None) -> float:
    """Peak signal-to-noise ratio in dB, ``10 log10(data_range^2 / MSE)`` (inf if identical).

    Parameters
    ----------
    truth, image : array_like, (H, W)
        The reference and the image under test, equal shapes, compared as given (keyword only).
    data_range : float, optional
        Peak-to-peak range of the data; default ``truth.max() - truth.min()``.

    Returns
    -------
    float
        PSNR in dB (scikit-image's ``peak_signal_noise_ratio``).
    """
    from skimage.metrics import peak_signal_noise_ratio

    a, b = _pair(image, truth)
    rng = _range(b, data_range)
    if np.array_equal(a, b):
        return float("inf")
    return float(peak_signal_noise_ratio(b, a, data_range=rng))


def ssim(*, truth, image, data_range: float | None = None) -> float:
    """Structural similarity (scikit-image defaults: 7x7 uniform window), in [-1, 1].

    Parameters
    ----------
    truth, image : array_like, (H, W)
        The reference and the image under test, equal shapes (>= 7x7), compared as given
        (keyword only).
    data_range : float, optional
        Peak-to-peak range of the data; default ``truth.max() - truth.min()``.

    Returns
    -------
    float
        SSIM (scikit-image's ``structural_similarity``).
    """
    from skimage.metrics import structural_similarity

    a, b = _pair(image, truth)
    if min(a.shape) < 7:
        raise ValueError(f"ssim needs images of at least 7x7 pixels, got {a.shape}")
    return float(structural_similarity(b, a, data_range=_range(b, data_range)))


def snr_db(clean, noisy) -> float:
    """Signal-to-noise ratio in dB: ``10 log10(sum clean^2 / sum (noisy - clean)^2)``.

    clean, noisy: arrays of equal shape (any number of dimensions); inf if they are equal.
    """
    c = np.asarray(clean, dtype=np.float64)
    n = np.asarray(noisy, dtype=np.float64)
    if c.shape != n.shape:
        raise ValueError(f"clean shape {c.shape} differs from noisy shape {n.shape}")
    if c.size == 0:
        raise ValueError("clean and noisy are empty")
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(n))):
        raise ValueError("clean or noisy contains NaN or infinite values")
    sig = float(np.sum(c**2))
    err = float(np.sum((n - c) ** 2))
    if err == 0:
        return float("inf")
    if sig == 0:
        raise ValueError("clean signal is all zeros: SNR undefined")
    return 10.0 * math.log10(sig / err)
