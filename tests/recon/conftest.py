"""Helpers shared by the block-level tests of ``metasensor.recon.block``."""

from types import SimpleNamespace

import numpy as np
import pytest

import metasensor as ms
from metasensor.dao.estimate import DaoOptions
from metasensor.recon import block


@pytest.fixture()
def bank_task():
    """A factory of the stand-in ``BlockTask`` that :func:`metasensor.recon.block._bank`
    reads: wave DAO always applied, no probe, the given gate, bank function and DAO window."""
    def make(gate=None, psf_fn=None, dao_samples=block.DAO_SAMPLES):
        cfg = ms.SystemConfig()
        c = cfg.center
        return SimpleNamespace(zernike=np.zeros(15, np.float32), dao=DaoOptions(), psf=None,
                               psf_fn=psf_fn, cfg=cfg, device="cpu", dao_negligible=0.0,
                               progress=None, block=SimpleNamespace(index=(0, 0)),
                               setup_gate=gate, uv=[(c, c), (c, c + 1)], probe_samples=0,
                               dao_samples=dao_samples)
    return make
