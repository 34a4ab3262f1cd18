"""Measurements the scenarios report: local resolved frequency, kymograph scan artefacts.

- :func:`resolved_frequency`: the project's resolved frequency
  (:func:`metasensor.metrics.spectral.resolved_frequency`: the highest radial frequency below
  which the error-to-truth power ratio stays under 0.5) of one region, so that scenario
  figures and the quality benchmark use one definition. Bar groups "k times finer" are k
  times this frequency.
- :func:`lattice_energy`: the energy of an image sequence's kymograph at the scan lattice's
  temporal frequency (one cycle per scan step of a sliding window) relative to its mean power
  (hand-written: a one-dimensional spectrum along time).
"""

from __future__ import annotations

import numpy as np

__all__ = ["resolved_frequency", "field_resolution", "lattice_energy"]


def resolved_frequency(image, truth, threshold: float = 0.5) -> float:
    """Resolved frequency [cycles/px] of ``image`` against ``truth`` in one region.

    Parameters
    ----------
    image, truth : array_like
        Equal 2-D regions of at least 16 px a side, on one intensity scale.
    threshold : float
        Error-to-truth power ratio that counts as unresolved.

    Returns
    -------
    float
        :func:`metasensor.metrics.spectral.resolved_frequency` of the region.
    """
    from metasensor.metrics.spectral import resolved_frequency as spectral_resolved

    img, tru = np.asarray(image, float), np.asarray(truth, float)
    if img.shape != tru.shape or img.ndim != 2 or min(img.shape) < 16:
        raise ValueError(f"image and truth must be equal 2-D regions >= 16 px, got "
                         f"{img.shape} and {tru.shape}")
    return spectral_resolved(img, tru, threshold)


def field_resolution(image, truth, grid: tuple[int, int] = (4, 4), **kw) -> np.ndarray:
    """(gy, gx) resolved frequencies over a grid of equal regions of the field."""
    img, tru = np.asarray(image), np.asarray(truth)
    ys = np.array_split(np.arange(img.shape[0]), grid[0])
    xs = np.array_split(np.arange(img.shape[1]), grid[1])
    return np.array([[resolved_frequency(img[y[0]:y[-1] + 1, x[0]:x[-1] + 1],
                                         tru[y[0]:y[-1] + 1, x[0]:x[-1] + 1], **kw)
                      for x in xs] for y in ys])


def lattice_energy(kymograph, period: int) -> float:
    """Power of a kymograph (time, position) at the temporal frequencies ``k / period``
    (k = 1 .. period // 2) relative to the mean power over all non-zero temporal frequencies."""
    k = np.asarray(kymograph, dtype=np.float64)
    if k.ndim != 2 or k.shape[0] < 2 * period:
        raise ValueError(f"kymograph must be (time >= {2 * period}, position), got {k.shape}")
    spec = np.abs(np.fft.rfft(k - k.mean(axis=0), axis=0)) ** 2
    f = np.fft.rfftfreq(k.shape[0])
    lattice = np.zeros(f.size, bool)
    for m in range(1, period // 2 + 1):
        lattice[np.argmin(np.abs(f - m / period))] = True
    rest = spec[1:].mean()
    return float(spec[lattice].mean() / max(rest, 1e-30))
