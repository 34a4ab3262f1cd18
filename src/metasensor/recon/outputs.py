"""What ``metasensor reconstruct`` writes: the image (TIFF, float32, the configuration in its
description), the Noll vectors per block, ``summary.json`` and a preview figure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["write_outputs", "image_meta", "RESULT_FILES"]

RESULT_FILES = ("image.tif", "image.zarr", "zernike.npy", "summary.json", "reconstruction.png")
PREVIEW_PX = 2048  # longest side of the images drawn in reconstruction.png


def _noise_summary(model) -> dict | None:
    """The noise model used, for summary.json (None: one global weight)."""
    if model is None:
        return None
    return {"a_dn_per_electron": model.a, "b_dn2": model.b, "source": model.source}


def write_outputs(out: Path, rec, views, origin=None, provenance: dict | None = None
                  ) -> list[Path]:
    """image.tif (float32, config JSON in the description), zernike.npy, summary.json and a PNG.
    ``origin``: the views' stored sensor origin (realign's), recorded with the image."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import tifffile

    from metasensor.io.atomic import atomic_path, atomic_write_text
    from metasensor.io.views import description

    out.mkdir(parents=True, exist_ok=True)
    image = np.asarray(rec.image, dtype=np.float32)
    meta = description(rec.config, **image_meta(rec, origin))
    with atomic_path(out / "image.tif") as tmp:
        tifffile.imwrite(tmp, image, description=json.dumps(meta), metadata=None)
    with atomic_path(out / "zernike.npy") as tmp:
        np.save(tmp, rec.zernike)
    summary = {"method": rec.method, "blocks": [len(rec.history), len(rec.history[0])],
               "solver": rec.solver,  # Richardson-Lucy's parameters; HQS uses neither
               "iterations": rec.iterations if rec.solver == "rl" else None,
               "subsets": rec.subsets if rec.solver == "rl" else None,
               "seconds": rec.seconds, "views_used": rec.views_used,
               "shape": list(image.shape), "history": rec.history,
               "registration_px": rec.registration,
               "registration_zernike": (None if rec.registration_zernike is None
                                        else rec.registration_zernike.tolist()),
               "noise_model": _noise_summary(getattr(rec, "noise_model", None))}
    if rec.method in ("wave", "geometric"):  # DAO: the estimated wavefront of every block
        summary["zernike_per_block"] = np.asarray(rec.zernike).tolist()
        summary["dao_applied"] = rec.dao_applied  # False: negligible, the start's bank kept
        if rec.dao_zernike is not None:
            summary["dao_zernike_per_block"] = np.asarray(rec.dao_zernike).tolist()
        fit = getattr(rec, "dao_fit_px", None)  # the last shift fit's residual, pixels
        if fit is not None:
            summary["dao_fit_px_per_block"] = [[float(v) if np.isfinite(v) else None
                                                for v in row] for row in np.asarray(fit)]
    if provenance is not None:
        summary["provenance"] = provenance
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=1, default=str))
    c = rec.config.center
    d = rec.config.scan_step_px
    f = _preview_factor(image.shape)  # a sensor-sized field is drawn block-averaged
    centre = _upsampled_block_mean(np.asarray(views[c, c], dtype=np.float32), d, f)
    shown = _block_mean(image, f)
    fig, axes = plt.subplots(1, 2, figsize=(10, 5.4), constrained_layout=True)
    for ax, img, title in ((axes[0], centre, f"centre view ({c}, {c}), up-sampled x{d}"),
                           (axes[1], shown, f"ISA reconstruction ({rec.method})")):
        lo, hi = np.percentile(img, [0.5, 99.5])
        ax.imshow(img, cmap="gray", vmin=lo, vmax=hi if hi > lo else lo + 1)
        ax.set_title(title)
        ax.set_axis_off()
    for b in rec.blocks[1:] if len(rec.blocks) > 1 else []:
        y0, y1, x0, x1 = (e / f for e in b.core)
        axes[1].plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], lw=0.4, color="tab:orange")
    with atomic_path(out / "reconstruction.png") as tmp:
        fig.savefig(tmp, dpi=120, format="png")
    plt.close(fig)
    return [out / n for n in ("image.tif", "zernike.npy", "summary.json", "reconstruction.png")]


def _preview_factor(shape) -> int:
    return max(1, -(-max(shape) // PREVIEW_PX))


def _block_mean(img: np.ndarray, f: int) -> np.ndarray:
    """Mean over f x f blocks (the figure's preview of a large field; f = 1: the image)."""
    if f == 1:
        return img
    h, w = (img.shape[0] // f) * f, (img.shape[1] // f) * f
    return img[:h, :w].reshape(h // f, f, w // f, f).mean(axis=(1, 3))


def _overlap_matrix(n: int, d: int, f: int) -> np.ndarray:
    """(n·d // f, n) weights: the share of preview pixel i's f pixels that sample s covers when
    up-sampled x d (pixels [s·d, (s+1)·d)), over f."""
    edges = np.arange(n * d // f + 1, dtype=np.int32) * np.int32(f)
    starts = np.arange(n + 1, dtype=np.int32) * np.int32(d)
    width = np.minimum(edges[1:, None], starts[None, 1:]) - np.maximum(edges[:-1, None],
                                                                      starts[None, :-1])
    return np.clip(width, 0, None).astype(np.float32) / np.float32(f)


def _upsampled_block_mean(view: np.ndarray, d: int, f: int) -> np.ndarray:
    """``_block_mean(np.kron(view, ones((d, d))), f)`` without the d²-times larger intermediate
    (190 MB for the centre view of the whole sensor): two overlap products (their int32 weights
    ~21 MB each at f = 4)."""
    if f == 1:
        return np.kron(view, np.ones((d, d), np.float32))
    ay = _overlap_matrix(view.shape[0], d, f)
    ax = _overlap_matrix(view.shape[1], d, f)
    return ay @ view @ ax.T


def image_meta(rec, origin) -> dict:
    """What an image's description keeps under "metasensor": its kind, the method, and the
    sensor ``origin`` (row, col) of the views it came from when they stored one (realign's:
    image pixel (i, j) is sensor point ``origin + (i + o, j + o)``, docs/conventions.md)."""
    meta = {"kind": "image", "method": rec.method}
    if origin is not None:
        meta["origin"] = origin
    return meta
