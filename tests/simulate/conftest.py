"""Use the real optics stage when it is installed, else the stand-in PSFs of fake_optics."""

import importlib
import sys
import types
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


def _real_optics() -> bool:
    try:
        importlib.import_module("metasensor.optics.psf")
        importlib.import_module("metasensor.optics.zernike")
        return True
    except ImportError:
        return False


REAL = _real_optics()


@pytest.fixture(autouse=True)
def optics_standin(monkeypatch):
    if REAL:
        yield False
        return
    import fake_optics

    psf = types.ModuleType("metasensor.optics.psf")
    psf.view_psfs = fake_optics.view_psfs
    psf.widefield_psf = fake_optics.widefield_psf
    zer = types.ModuleType("metasensor.optics.zernike")
    zer.wavefront = fake_optics.wavefront
    zer.random_zernike = fake_optics.random_zernike
    monkeypatch.setitem(sys.modules, "metasensor.optics.psf", psf)
    monkeypatch.setitem(sys.modules, "metasensor.optics.zernike", zer)
    import metasensor.optics as optics_pkg

    monkeypatch.setattr(optics_pkg, "psf", psf, raising=False)
    monkeypatch.setattr(optics_pkg, "zernike", zer, raising=False)
    yield True
