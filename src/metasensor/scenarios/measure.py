"""Measurements the scenarios report: local resolved frequency, kymograph scan artefacts.

- :func:`resolved_frequency`: the project's resolved frequency
  (:func:`metasensor.metrics.spectral.resolved_frequency`: the highest radial frequency below
  which the error-to-truth power ratio stays under 0.5) of one region, so that scenario
  figures and the quality benchmark use one definition. Bar groups "k times finer" are k
  times this frequency.
- :func:`bar_periods` / :func:`bar_gains`: the finest three-bar group resolved per location of
  the bar chart (:func:`metasensor.metrics.bars.bar_resolution`) and the factor by which one
  sensor resolves finer groups than another there; where the worse sensor resolves none of
  the location's groups, the factor is a lower bound (its coarsest period over the better
  sensor's), flagged as such.
- :func:`lattice_energy`: the energy of an image sequence's kymograph at the scan lattice's
  temporal frequency (one cycle per scan step of a sliding window) relative to its mean power
  (hand-written: a one-dimensional spectrum along time).
"""

from __future__ import annotations

import numpy as np

__all__ = ["resolved_frequency", "frequency_floor", "field_resolution", "bar_periods", "bar_gains",
           "lattice_energy"]


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


def frequency_floor(shape: tuple[int, int]) -> float:
    """The lowest frequency [cycles/px] :func:`resolved_frequency` reads in a region of
    ``shape``: the centre of the first of the radial bins of
    :func:`metasensor.metrics.spectral.spectral_fidelity` (``min(H, W) // 4`` bins, 8 to 64,
    over 0..0.5 cycles/px). A region that resolves nothing (0) resolves less than this."""
    n = int(np.clip(min(int(shape[0]), int(shape[1])) // 4, 8, 64))
    return 0.25 / n


def field_resolution(image, truth, grid: tuple[int, int] = (4, 4), **kw) -> np.ndarray:
    """(gy, gx) resolved frequencies over a grid of equal regions of the field."""
    img, tru = np.asarray(image), np.asarray(truth)
    ys = np.array_split(np.arange(img.shape[0]), grid[0])
    xs = np.array_split(np.arange(img.shape[1]), grid[1])
    return np.array([[resolved_frequency(img[y[0]:y[-1] + 1, x[0]:x[-1] + 1],
                                         tru[y[0]:y[-1] + 1, x[0]:x[-1] + 1], **kw)
                      for x in xs] for y in ys])


def bar_periods(image, groups, exclude=None) -> dict[str, dict]:
    """Finest resolved bar period per chart location of ``image``.

    Parameters
    ----------
    image : array_like
        2-D image on the chart's pixel grid.
    groups : list of BarGroup
        :func:`metasensor.simulation.bars.bar_groups` in the image's coordinates.
    exclude : (y0, y1, x0, x1) or None
        A box [px]; locations with a group inside it are left out (e.g. covered by an object).

    Returns
    -------
    dict
        ``{location: {"period_px": finest resolved period or None, "coarsest_px": p}}``.
    """
    from metasensor.metrics.bars import bar_resolution

    keep = list(groups)
    if exclude is not None:
        y0, y1, x0, x1 = exclude
        hit = {g.location for g in keep if g.y0 < y1 and g.y0 + g.extent > y0
               and g.x0 < x1 and g.x0 + g.extent > x0}
        keep = [g for g in keep if g.location not in hit]
    if not keep:
        raise ValueError("no bar group left outside the excluded box")
    res = bar_resolution(image, keep)
    return {loc: {"period_px": r["period_px"], "coarsest_px": r["coarsest_px"]}
            for loc, r in res.items()}


def bar_gains(worse: dict, better: dict) -> dict[str, dict]:
    """Per location, how many times finer ``better`` resolves than ``worse`` (both from
    :func:`bar_periods`): ``{"gain": p_worse / p_better, "bound": True}`` where ``worse``
    resolves nothing (then ``p_worse`` is taken as the coarsest period: a lower bound);
    gain 0 where ``better`` resolves nothing. Locations read in both."""
    out = {}
    for loc, w in worse.items():
        if loc not in better:
            continue
        pb = better[loc]["period_px"]
        pw = w["period_px"]
        if pb is None:
            out[loc] = {"gain": 0.0, "bound": False}
        else:
            out[loc] = {"gain": (w["coarsest_px"] if pw is None else pw) / pb,
                        "bound": pw is None}
    return out


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
