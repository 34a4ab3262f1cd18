"""The space-variant model of a block (``reconstruct(space_variant=True)``): PSF banks at the
four corners of the block's core (or a finer grid of field points spanning it,
``ReconOptions.field_points``), blended bilinearly inside the operator.

Field points on the corners of the block grid (:func:`corner_zernikes`) are shared by the blocks
that meet there, so neighbouring blocks see the same, continuous PSFs along their common border
(:class:`metasensor.phasespace.space_variant.SpaceVariantOperator` with
:func:`~metasensor.phasespace.space_variant.corner_weights`), where one bank per block changes
abruptly from block to block and is wrong towards the block's borders. With ``register`` the
views are registered against the mean of the four banks (the bank at the core's centre) and every
corner bank is translated by the same shifts (:mod:`metasensor.dao.bank_registration`).
"""

from __future__ import annotations

import numpy as np

from metasensor.recon.blocks import Block

__all__ = ["corner_zernikes", "space_variant_operator"]


def corner_zernikes(blocks: list[Block], shape: tuple[int, int], zernike=None,
                    field_zernike=None, n_modes: int = 45, points: int = 2) -> dict:
    """Noll vectors ``(points², J)`` [waves] at each block core's field points: a
    ``points`` × ``points`` grid spanning the core, row-major (``points`` 2: its corners
    (y0, x0), (y0, x1), (y1, x0), (y1, x1)); ``zernike`` (global) plus ``field_zernike``
    evaluated there (normalised field coordinates ``2·y / H − 1`` of the point, continuous
    coordinates). Returns ``{block.index: array}``."""
    from metasensor.optics.field import evaluate_field_zernike

    h, w = shape
    out = {}
    n = int(points)
    for b in blocks:
        y0, y1, x0, x1 = b.core
        gy, gx = np.meshgrid(np.linspace(y0, y1, n), np.linspace(x0, x1, n), indexing="ij")
        yn = 2.0 * gy.ravel() / h - 1.0
        xn = 2.0 * gx.ravel() / w - 1.0
        parts = [np.zeros((n * n, n_modes))]
        if field_zernike is not None:
            parts.append(evaluate_field_zernike(field_zernike, yn, xn))
        if zernike is not None:
            parts.append(np.broadcast_to(np.asarray(zernike, np.float64).ravel(),
                                         (n * n, np.size(zernike))))
        z = np.zeros((n * n, max(p.shape[-1] for p in parts)))
        for p in parts:
            z[:, :p.shape[-1]] += p
        out[b.index] = z.astype(np.float32)
    return out


def space_variant_operator(task, data_win: np.ndarray, rows, cols):
    """The block's :class:`~metasensor.phasespace.space_variant.SpaceVariantOperator` (views
    ``rows, cols`` of the banks at ``task.corner_zernike``), the registration's r.m.s. shifts per
    round and its wavefront (empty / None without ``task.register``)."""
    import torch

    from metasensor.phasespace.operator import make_geometry
    from metasensor.phasespace.space_variant import SpaceVariantOperator, corner_weights, pad_banks
    from metasensor.recon.block import default_psfs

    make = task.psf_fn or default_psfs
    banks = pad_banks([np.asarray(make(task.cfg, z, task.device), np.float32)[rows, cols]
                       for z in np.asarray(task.corner_zernike)])
    history, reg_zernike = [], None
    if task.register:
        from metasensor.dao.bank_registration import register_views, translate_psfs

        reg = register_views(sum(banks) / len(banks), data_win, task.cfg.scan_step_px,
                             cfg=task.cfg, uv=task.uv, device=task.device, pad=task.pad)
        history, reg_zernike = reg.history, reg.zernike
        if reg.history and reg.shifts.abs().max() > 0:
            banks = [translate_psfs(torch.from_numpy(b), reg.shifts).numpy() for b in banks]
    geometry = make_geometry(data_win.shape[-2:], task.cfg.scan_step_px, banks[0].shape[-1] // 2,
                             pad=task.pad)
    block = task.block
    points = int(round(len(banks) ** 0.5))
    weights = corner_weights(geometry, (block.window[0], block.window[2]), block.core, points)
    return SpaceVariantOperator(banks, weights, geometry, device=task.device), history, reg_zernike
