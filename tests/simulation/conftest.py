"""PSFs for the simulator's tests.

Physics tests (photometry, point sources, field-dependent blur, AO, ...) use the real optics stage
(``metasensor.optics.psf``) on a small system (``SMALL``: nnum = 5, 1.0 s per fine bank) whenever
it is installed. Geometry and statistics tests (exact realignment for every scan period and order
with nnum = 15, noise statistics, motion bookkeeping, CLI) do not depend on the PSFs' physics and
request the ``standin`` fixture: the fast geometric stand-in of ``fake_optics.py``. Without the
optics stage every test uses the stand-in.
"""

import importlib
import sys
import types
from pathlib import Path

import pytest

import metasensor as ms

sys.path.insert(0, str(Path(__file__).parent))

# a 5 x 5-pixel lenslet system with the prototype's pixel, NA and lenslet f-number
SMALL = ms.SystemConfig(nnum=5, mla_pitch=23e-6, mla_focal=230e-6, scan=5,
                        sensor_shape=(64, 64))


def _real_optics() -> bool:
    try:
        importlib.import_module("metasensor.optics.psf")
        importlib.import_module("metasensor.optics.zernike")
        return True
    except ImportError:
        return False


REAL = _real_optics()


def _install(monkeypatch):
    import fake_optics

    if REAL:  # resolve metasensor's lazy names now: resolved under the stand-in modules below,
        _ = ms.view_psfs, ms.widefield_psf  # monkeypatch would "restore" the stand-ins

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
    monkeypatch.setattr(ms, "view_psfs", fake_optics.view_psfs, raising=False)
    monkeypatch.setattr(ms, "widefield_psf", fake_optics.widefield_psf, raising=False)


@pytest.fixture
def standin(monkeypatch):
    """Force the geometric stand-in PSFs (geometry/statistics tests)."""
    _install(monkeypatch)
    return True


@pytest.fixture(autouse=True)
def _fallback(monkeypatch):
    if not REAL:
        _install(monkeypatch)
    yield


@pytest.fixture
def view_bank():
    """The pixel-pitch bank of whatever optics is active: ``view_bank(cfg, zernike=None)``."""
    return lambda cfg, zernike=None: sys.modules["metasensor.optics.psf"].view_psfs(cfg, zernike)
