"""Optics tests: a private PSF cache folder for the session, small systems."""

import os

import pytest

from metasensor.config import SystemConfig


@pytest.fixture(scope="session", autouse=True)
def _psf_cache(tmp_path_factory):
    old = os.environ.get("METASENSOR_CACHE")
    os.environ["METASENSOR_CACHE"] = str(tmp_path_factory.mktemp("psf_cache"))
    yield
    if old is None:
        os.environ.pop("METASENSOR_CACHE", None)
    else:
        os.environ["METASENSOR_CACHE"] = old


@pytest.fixture(scope="session")
def small_cfg() -> SystemConfig:
    """9 x 9 pixels per lenslet, same pixel, wavelength, NA and f-numbers as the prototype
    (pupil image radius NA·f/pitch = 4.5 px = nnum / 2): the optics are size-independent."""
    return SystemConfig(nnum=9, mla_pitch=9 * 4.6e-6, mla_focal=9 * 46e-6, scan=3)
