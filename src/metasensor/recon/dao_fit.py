"""Whether DAO's one-wavefront-per-block model held in a reconstruction: its shift-fit residual.

Multisite DAO (Wu et al. 2022, Methods: "We assume the aberration is uniform in each block")
fits one wavefront's gradient to the shifts its views measure against the current PSF bank
(:func:`metasensor.dao.wavefront.fit_shifts`). Where the block is isoplanatic the shifts are
that gradient up to the measurement noise and the last update's residual stays at a tenth of a
pixel or two. Where the aberration changes inside the block in its high orders (it varies faster
than the blocks, as a wrap or a turbulent layer near the pupil does) no single wavefront
explains the shifts: the residual grows towards a pixel and more, and the block's estimate is a
compromise of its parts. :func:`warn_dao_fit` says so once per reconstruction, naming the
blocks; the remedy is more, smaller blocks (or a given field aberration). What the residual does
not see: a smooth change across the block (the shifts of a linearly changing astigmatism average
to the mean wavefront's gradient), nor objects at different depths in one block whose wavefronts
differ by defocus alone (each layer shifts the views linearly in the pupil coordinate, and so
does their mixture): DAO then fits the block's mean with a small residual. Depths mixed behind a
strong high-order aberration (a near object behind plastic wrap) it does see. Shifts measured
poorly raise it too, in an isoplanatic block: fine texture (grass) under a few waves, where the
views' cross-correlations partly alias. The threshold and
the residuals it separates: docs/decisions.md ("DAO's shift-fit residual").
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["FIT_WARN_PX", "nonuniform_blocks", "warn_dao_fit"]

#: r.m.s. residual (pixels) of DAO's last shift fit above which a block is reported as not
#: isoplanatic (why this value: docs/decisions.md, "DAO's shift-fit residual")
FIT_WARN_PX = 0.5


def nonuniform_blocks(fits, threshold: float = FIT_WARN_PX) -> list[tuple[int, int]]:
    """Blocks whose DAO shift fit left more than ``threshold`` pixels r.m.s.

    Parameters
    ----------
    fits : array_like or None
        ``(by, bx)`` residuals in pixels (:attr:`Reconstruction.dao_fit_px`; NaN: no DAO
        there). None: no DAO at all.
    threshold : float
        Pixels r.m.s.; positive.

    Returns
    -------
    list of (int, int)
        Block indices ``(iy, ix)``, row-major.
    """
    if not (np.isfinite(threshold) and threshold > 0):
        raise ValueError(f"threshold must be a positive number of pixels, got {threshold!r}")
    if fits is None:
        return []
    f = np.asarray(fits, dtype=np.float64)
    if f.ndim != 2:
        raise ValueError(f"fits must be a (by, bx) array, got shape {f.shape}")
    return [(int(i), int(j)) for i, j in zip(*np.nonzero(np.nan_to_num(f, nan=0.0) > threshold),
                                              strict=True)]


def warn_dao_fit(fits, grid: tuple[int, int], threshold: float = FIT_WARN_PX) -> bool:
    """Warn once (``UserWarning``) when any block's DAO shift fit exceeds ``threshold``.

    Parameters
    ----------
    fits : array_like or None
        As :func:`nonuniform_blocks`.
    grid : (int, int)
        The reconstruction's block grid (named in the message).
    threshold : float
        Pixels r.m.s.

    Returns
    -------
    bool
        Whether it warned.
    """
    bad = nonuniform_blocks(fits, threshold)
    if not bad:
        return False
    f = np.asarray(fits, dtype=np.float64)
    worst = max(f[b] for b in bad)
    shown = ", ".join(str(b) for b in bad[:8]) + (" ..." if len(bad) > 8 else "")
    warnings.warn(
        f"DAO's one-wavefront fit left up to {worst:.2f} px r.m.s. of the view shifts "
        f"unexplained in {len(bad)} of {grid[0] * grid[1]} blocks ({shown}; an isoplanatic "
        f"block leaves 0.05-0.25 px): the aberration changes inside those blocks (or they "
        f"mix depths, or their shifts are poorly measured: fine texture under a large "
        f"aberration), so their estimate is a compromise; use more blocks than "
        f"{grid[0]}x{grid[1]} or give the field aberration", UserWarning, stacklevel=4)
    return True
