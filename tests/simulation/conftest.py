"""PSFs for the simulator's tests.

Physics tests (photometry, point sources, field-dependent blur, AO, ...) use the real optics stage
(``metasensor.optics.psf``) on a small system (``SMALL``: nnum = 5, 1.0 s per fine bank) whenever
it is installed. Geometry and statistics tests (exact realignment for every scan period and order
with nnum = 15, noise statistics, motion bookkeeping, CLI) do not depend on the PSFs' physics and
request the ``standin`` fixture: the fast geometric stand-in of ``fake_optics.py``, patched over
the real functions of ``metasensor.optics.psf`` / ``metasensor.optics.zernike`` for the test.
"""

import sys
from pathlib import Path

import pytest

import metasensor as ms

sys.path.insert(0, str(Path(__file__).parent))

# a 5 x 5-pixel lenslet system with the prototype's pixel, NA and lenslet f-number
SMALL = ms.SystemConfig(nnum=5, mla_pitch=23e-6, mla_focal=230e-6, scan=5,
                        sensor_shape=(64, 64))


def _install(monkeypatch):
    """The stand-in functions in place of the real ones, patched on the real modules (the
    simulator looks them up there at call time), on the package's lazy names too."""
    import fake_optics

    from metasensor.optics import psf, zernike

    _ = ms.view_psfs, ms.widefield_psf  # resolve the lazy names before patching them
    for module, names in ((psf, ("view_psfs", "widefield_psf")),
                          (zernike, ("wavefront", "random_zernike"))):
        for name in names:
            monkeypatch.setattr(module, name, getattr(fake_optics, name))
    monkeypatch.setattr(ms, "view_psfs", fake_optics.view_psfs)
    monkeypatch.setattr(ms, "widefield_psf", fake_optics.widefield_psf)


@pytest.fixture
def standin(monkeypatch):
    """Force the geometric stand-in PSFs (geometry/statistics tests)."""
    _install(monkeypatch)
    return True


@pytest.fixture
def view_bank():
    """The pixel-pitch bank of whatever optics is active: ``view_bank(cfg, zernike=None)``."""
    from metasensor.optics import psf

    return lambda cfg, zernike=None: psf.view_psfs(cfg, zernike)
