"""The per-block records of a reconstruction, gathered as its blocks finish."""

from __future__ import annotations

import numpy as np

from metasensor.recon.block import BlockResult
from metasensor.recon.blocks import Stitcher

__all__ = ["Collector"]


class Collector:
    """Stitches block results as they arrive and keeps their per-block records (the
    :class:`~metasensor.recon.api.Reconstruction`'s per-block fields)."""

    def __init__(self, shape, grid, zern: np.ndarray, out, register: bool, bar) -> None:
        by, bx = grid
        self.stitcher = Stitcher(shape, out)
        self.history = [[[] for _ in range(bx)] for _ in range(by)]
        self.dao = [[[] for _ in range(bx)] for _ in range(by)]
        self.registration = [[[] for _ in range(bx)] for _ in range(by)]
        self.applied = [[None] * bx for _ in range(by)]
        self.layers = [[() for _ in range(bx)] for _ in range(by)]
        self.dao_zernike = None
        self.dao_fit = None
        from metasensor.dao.bank_registration import WAVEFRONT_MODES

        self.reg_zernike = (np.zeros((by, bx, max(WAVEFRONT_MODES)), np.float32) if register
                            else None)
        self.zernike = zern.copy()
        self.bar = bar

    def __call__(self, res: BlockResult) -> None:
        self.stitcher.add(res.block, res.image)
        iy, ix = res.block.index
        self.history[iy][ix] = res.history
        self.dao[iy][ix] = res.dao_history
        self.registration[iy][ix] = res.registration
        self.applied[iy][ix] = res.dao_applied
        self.layers[iy][ix] = res.layers
        if res.dao_zernike is not None:
            if self.dao_zernike is None:
                self.dao_zernike = np.zeros_like(self.zernike)
            self.dao_zernike[iy, ix, :] = 0
            m = min(res.dao_zernike.size, self.zernike.shape[-1])
            self.dao_zernike[iy, ix, :m] = res.dao_zernike[:m]
        if res.dao_fit_px is not None:
            if self.dao_fit is None:
                self.dao_fit = np.full(self.zernike.shape[:2], np.nan)
            self.dao_fit[iy, ix] = res.dao_fit_px
        if self.reg_zernike is not None and res.registration_zernike is not None:
            self.reg_zernike[iy, ix] = res.registration_zernike
        z = np.asarray(res.zernike, np.float32)
        n = self.zernike.shape[-1]
        self.zernike[iy, ix, :] = 0
        self.zernike[iy, ix, :min(z.size, n)] = z[:n]
        if self.bar is not None:
            self.bar(len(res.history))
