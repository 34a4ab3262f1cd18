"""From the binned edge-spread function to the MTF: steps 4 and 5 of the slanted-edge method
(:mod:`metasensor.metrics.mtf`), hand-written after Burns' ``sfrmat3``/``sfrmat4``.

Line-spread function (LSF) = first difference of the ESF, kept within ``max(MAX_REACH px,
10 edge widths)`` of the edge; beyond ISO 12233, its tails beyond ``TAIL_CORE`` edge widths
low-passed (``tail_smoothing``); a Hamming (or Tukey / no) window centred on the edge; FFT;
modulus normalised to 1 at zero frequency; the two-point difference's ``sinc(f · delta)`` and
(``correct_binning``) the bin average's divided out.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["MAX_REACH", "TAIL_CORE", "TAIL_TAPER", "WINDOWS", "edge_spectrum"]

WINDOWS = ("hamming", "tukey", "none")
TAIL_CORE = 2.5  # LSF core kept unsmoothed: this many 10-90 % edge widths each side
MAX_REACH = 48.0  # pixels of the LSF kept each side of the edge (at least 10 edge widths)
TAIL_TAPER = 0.5  # blend from core to smoothed tails over this fraction of the core


def edge_spectrum(esf, oversample: int, window: str, tail_smoothing: bool,
                  correct_binning: bool, roi):
    """The MTF of a binned edge-spread function (steps 4 and 5 of
    :mod:`metasensor.metrics.mtf`).

    Parameters
    ----------
    esf : numpy.ndarray
        The edge-spread function, bins ``1 / oversample`` px wide along the edge normal.
    oversample : int
        ESF bins per pixel.
    window : str
        ``"hamming"`` (ISO 12233), ``"tukey"`` or ``"none"``, centred on the edge.
    tail_smoothing : bool
        Low-pass the LSF tails beyond ``TAIL_CORE`` edge widths (:func:`_smooth_tails`).
    correct_binning : bool
        Divide out the bin average's ``sinc`` too (the two-point derivative's always).
    roi : tuple
        ``(y0, y1, x0, x1)``, for the error message only.

    Returns
    -------
    lsf : numpy.ndarray
        The windowed line-spread function (within ``max(MAX_REACH px, 10 edge widths)`` of the
        edge).
    freq : numpy.ndarray
        Frequencies [cycles per pixel along the edge normal].
    mtf : numpy.ndarray
        Its modulus, 1 at zero frequency, corrected.

    Raises
    ------
    ValueError
        A line-spread function that sums to zero (no edge).
    """
    delta = 1.0 / oversample
    lsf = np.diff(esf)
    lsf = lsf * np.sign(lsf.sum())
    mid, width = _lsf_centre_width(esf * np.sign(esf[-1] - esf[0]), oversample)
    # far from the edge the ESF holds only noise: keep max(MAX_REACH px, 10 edge widths) a side
    reach = max(MAX_REACH * oversample, 10.0 * width)
    lo_b, hi_b = max(0, int(mid - reach)), min(lsf.size, int(math.ceil(mid + reach)) + 1)
    lsf, mid = lsf[lo_b:hi_b], mid - lo_b
    if tail_smoothing:
        lsf = _smooth_tails(lsf, mid, max(TAIL_CORE * width, 4.0 * oversample), oversample)
    half = max(mid, lsf.size - 1 - mid)
    lsf_w = lsf * _window(lsf.size, mid, half, window)

    nfft = 1 << max(10, int(math.ceil(math.log2(4 * lsf.size))))
    spec = np.abs(np.fft.rfft(lsf_w, n=nfft))
    freq = np.fft.rfftfreq(nfft, d=delta)  # cycles per pixel along the normal
    if spec[0] <= 0:
        raise ValueError(f"no edge found in roi {roi}: the line-spread function sums to zero")
    mtf = spec / spec[0]
    corr = np.sinc(freq * delta)  # two-point derivative
    if correct_binning:
        corr = corr * np.sinc(freq * delta)  # box average over the bin width
    mtf = mtf / corr
    return lsf_w, freq, mtf


def _window(n: int, centre: float, half: float, kind: str) -> np.ndarray:
    """The LSF window ``kind`` (one of :data:`WINDOWS`) over ``n`` bins, centred on ``centre``
    and ``half`` bins to each side."""
    x = np.arange(n) - centre
    t = np.clip(np.abs(x) / half, 0.0, 1.0)
    if kind == "hamming":
        w = 0.54 + 0.46 * np.cos(np.pi * t)
        w[np.abs(x) > half] = 0.0
        return w
    if kind == "tukey":  # flat over the inner half, cosine taper over the outer half
        w = np.where(t < 0.5, 1.0, 0.5 * (1 + np.cos(np.pi * (2 * t - 1))))
        return w
    return np.ones(n)


def _lsf_centre_width(esf: np.ndarray, oversample: int) -> tuple[float, float]:
    """Edge centre (LSF bin index) and 10-90 % rise width (bins) of a rising ESF.

    The ESF is smoothed over one pixel first so that noise does not move the crossings.
    """
    from scipy.ndimage import uniform_filter1d

    e = uniform_filter1d(esf, oversample, mode="nearest")
    q = max(2, e.size // 10)
    lo, hi = np.median(e[:q]), np.median(e[-q:])
    t = (e - lo) / (hi - lo)

    def crossing(level: float) -> float:
        i = int(np.argmax(t >= level))
        if i == 0:
            return 0.0
        return i - 1 + (level - t[i - 1]) / max(t[i] - t[i - 1], 1e-12)

    c10, c50, c90 = crossing(0.1), crossing(0.5), crossing(0.9)
    return c50 - 0.5, max(c90 - c10, 1.0)  # the LSF bin i sits between ESF bins i and i + 1


def _smooth_tails(lsf: np.ndarray, mid: float, core: float, oversample: int) -> np.ndarray:
    """Keep the LSF core (|x - mid| < core bins) as is; low-pass the tails beyond it.

    Hand-written noise reduction (not in ISO 12233): far from the edge the true LSF is small and
    slowly varying, while pixel noise there is white and, after the derivative, dominates the
    high frequencies. Smoothing the tails with a Gaussian of one pixel (sigma) removes that noise
    but keeps their area, so the low-frequency MTF (and MTF[0] = 1) is not biased as it is by
    truncating the LSF. The blend uses a raised-cosine taper over another ``core`` bins.
    """
    from scipy.ndimage import gaussian_filter1d

    x = np.abs(np.arange(lsf.size) - mid)
    t = np.clip((x - core) / (TAIL_TAPER * core), 0.0, 1.0)
    keep = 0.5 * (1 + np.cos(np.pi * t))
    tail = gaussian_filter1d(lsf * (1 - keep), float(oversample), mode="constant")
    return lsf * keep + tail
