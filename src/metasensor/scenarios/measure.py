"""Measurements the scenarios report: local resolved frequency, kymograph scan artefacts.

- :func:`resolved_frequency`: the finest spatial frequency (cycles/pixel) an image transfers in a
  region, from the cross-spectral transfer ``T(f) = Re Σ F_img conj(F_truth) / Σ |F_truth|²``
  over rings of radial frequency (the image's contrast at f relative to the truth's: the MTF of
  the whole chain, including what a reconstruction restores), Hann-windowed; the resolved
  frequency is where T first falls below ``threshold`` (0.2: a bar group is still seen at about
  that modulation). Rings where the truth holds too little energy are skipped. Bar groups
  "k times finer" are k times this frequency.
- :func:`lattice_energy`: the energy of an image sequence's kymograph at the scan lattice's
  temporal frequency (one cycle per scan step of a sliding window) relative to its mean power
  (hand-written: a one-dimensional spectrum along time).
"""

from __future__ import annotations

import numpy as np

__all__ = ["resolved_frequency", "field_resolution", "lattice_energy"]


def _spectrum(a: np.ndarray) -> np.ndarray:
    from skimage.filters import window

    a = np.asarray(a, dtype=np.float64)
    return np.fft.fft2((a - a.mean()) * window("hann", a.shape))


def resolved_frequency(image, truth, threshold: float = 0.2, rings: int = 32,
                       min_energy: float = 1e-3) -> float:
    """Resolved frequency (cycles/pixel, at most 0.5) of ``image`` against ``truth`` (same
    shape, same intensity scale) in that region (module docstring)."""
    img, tru = np.asarray(image, float), np.asarray(truth, float)
    if img.shape != tru.shape or img.ndim != 2 or min(img.shape) < 16:
        raise ValueError(f"image and truth must be equal 2-D regions >= 16 px, got "
                         f"{img.shape} and {tru.shape}")
    fi, ft = _spectrum(img), _spectrum(tru)
    fy = np.fft.fftfreq(img.shape[0])[:, None]
    fx = np.fft.fftfreq(img.shape[1])[None, :]
    fr = np.hypot(fy, fx)
    edges = np.linspace(0.0, 0.5, rings + 1)
    total = (np.abs(ft) ** 2).sum()
    last = 0.0
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        ring = (fr >= lo) & (fr < hi) & (fr > 0)
        power = (np.abs(ft[ring]) ** 2).sum()
        if power < min_energy * total / rings:
            continue
        t = float(np.real((fi[ring] * np.conj(ft[ring])).sum()) / power)
        if t < threshold:
            return last
        last = float(hi)
    return last


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
