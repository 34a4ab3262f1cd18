"""The demo's resolution measurements and its comparison figure (:mod:`metasensor.report.demo`).

Per image against its truth: the resolved frequency (:func:`metasensor.metrics.spectral.
resolved_frequency`), the fringe ratio at the reconstruction's block borders
(:func:`metasensor.metrics.fringes.fringe_ratio`) and, on the bar chart, the finest resolved bar
group at each location (:func:`metasensor.metrics.bars.bar_resolution`). The 2D sensor restored
with the same kind of prior as the reconstruction (hyper-Laplacian, Krishnan & Fergus 2009) shows
what the 2D sensor's own data allow with a prior (docs/decisions.md, finding 1).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["measure", "restore_2d", "comparison_figure", "HL_LAMBDAS"]

#: Data weights of the 2D sensor's hyper-Laplacian restoration; the best by SSIM to the truth
#: is kept (an oracle choice in the 2D sensor's favour).
HL_LAMBDAS = (2e3, 1e4, 5e4)


def restore_2d(cap, zernike) -> np.ndarray:
    """``cap.sensor2d`` deconvolved by the widefield PSF of ``zernike`` (Noll, waves) with the
    hyper-Laplacian prior, the best of :data:`HL_LAMBDAS` by SSIM to ``cap.truth``."""
    from metasensor.metrics import ssim
    from metasensor.optics.widefield import widefield_psf
    from metasensor.solvers.krishnan_fergus import KFOptions, hyper_laplacian_deconv

    psf = widefield_psf(cap.config, zernike=np.asarray(zernike, np.float64))
    rng = float(cap.truth.max() - cap.truth.min())
    best = None
    for lam in HL_LAMBDAS:
        img = np.asarray(hyper_laplacian_deconv(cap.sensor2d, psf, KFOptions(lam=lam)),
                         np.float32)
        score = ssim(truth=cap.truth, image=img, data_range=rng)
        if best is None or score > best[0]:
            best = (score, img)
    return best[1]


def measure(table: list[dict], results: dict, places: dict, size: int, bars: str | None
            ) -> list[dict]:
    """Add ``resolved_cpp`` and ``fringe_ratio`` to every row of ``table`` (by its ``sensor``)
    and return the bar-group rows: per location the finest resolved period [px] of each image
    (None: not even the coarsest group), its coarsest period and the ratio of the 2D sensor's
    period to the meta-imaging sensor's (a lower bound where the 2D sensor resolves none).

    ``results``: name -> (image, truth); ``places``: name -> (scene pixel of the truth's
    pixel 0, (truth shape, block grid, scan step) of the block borders); ``bars``: the bar
    chart's layout (:func:`metasensor.simulation.bars.bar_groups`), None for another scene."""
    from metasensor.metrics.bars import bar_resolution
    from metasensor.metrics.fringes import block_borders, fringe_ratio
    from metasensor.metrics.spectral import resolved_frequency
    from metasensor.simulation.bars import bar_groups

    readings = {}
    for row in table:
        name = row["sensor"]
        image, truth = results[name]
        origin, (shape, blocks, d) = places[name]
        ys, xs = block_borders(shape, blocks, d)
        row["resolved_cpp"] = resolved_frequency(image, truth)
        row["fringe_ratio"] = fringe_ratio(truth=truth, image=image, rows=ys, cols=xs)
        if bars:
            readings[name] = bar_resolution(image, bar_groups(size, origin=float(origin),
                                                              layout=bars))
    if not bars:
        return []
    meta = next(k for k in readings if k.startswith("meta-imaging"))
    rows = []
    for loc, first in readings["2D sensor"].items():
        row = {"location": loc}
        row.update({name: r[loc]["period_px"] for name, r in readings.items()})
        row["coarsest_px"] = first["coarsest_px"]
        flat, ours = row["2D sensor"], row[meta]
        row["gain_2d_over_meta"] = (None if ours is None else
                                    (flat or first["coarsest_px"]) / ours)
        row["gain_is_lower_bound"] = ours is not None and flat is None
        rows.append(row)
    return rows


def comparison_figure(path: Path, cap, lf, results: dict) -> Path:
    """Two rows of panels of one size on the meta-imaging capture's grid: the truth and every
    image (one intensity range, colour bar in DN), then each image minus the truth (one
    symmetric range, colour bar in DN)."""
    from metasensor.io.figures import new_figure, save_figure
    from metasensor.report.demo import _on_grid

    truth = cap.truth
    shift = cap.config.field_offset_px - lf.config.field_offset_px
    imgs = [(k, _on_grid(v[0], shift, truth.shape) if v[1] is lf.truth else v[0])
            for k, v in results.items()]
    n = len(imgs) + 1
    fig, axes = new_figure(2, n, size=(3.0 * n + 1.4, 6.6))
    fig.subplots_adjust(left=0.01, right=0.9, top=0.9, bottom=0.02, wspace=0.04, hspace=0.12)
    lo, hi = float(truth.min()), float(truth.max())
    diffs = [a - truth for _, a in imgs]
    span = float(np.nanpercentile(np.abs(np.stack(diffs)), 99.5)) or 1.0
    im = None
    for ax, (title, a) in zip(axes[0], [("ground truth", truth)] + imgs, strict=True):
        im = ax.imshow(np.clip(a, lo, hi), cmap="gray", vmin=lo, vmax=hi, interpolation="nearest")
        ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=list(axes[0]), fraction=0.015, pad=0.01, label="intensity (DN)")
    for ax, (title, _), dif in zip(axes[1, 1:], imgs, diffs, strict=True):
        im = ax.imshow(dif, cmap="RdBu_r", vmin=-span, vmax=span, interpolation="nearest")
        ax.set_title(f"{title} − truth", fontsize=10)
    fig.colorbar(im, ax=list(axes[1]), fraction=0.015, pad=0.01, label="difference (DN)")
    for ax in axes.ravel():
        ax.set_axis_off()
    h, w = truth.shape
    fig.suptitle(f"Single plastic lens, f/10, strong field aberrations ({w} x {h} px)")
    return save_figure(fig, path, tight=False)
