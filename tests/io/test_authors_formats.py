"""The authors' and napari-LF's formats: "meta image" view stacks (nnum² pages, page u·nnum + v,
no description, any dtype), MATLAB v7.3 PSF files (``psf_z``, MATLAB size (y, x, u, v), h5py
reads it reversed; possibly oversampled) and napari-LF ``.lfc`` calibrations (cubic lenslet ->
pixel map). Files are generated here in those layouts; references: the bank they were made from
(exact), ``view_psfs``' sub-lattice rule for oversampled banks, and the similarity behind a
``reverseCoefficients`` map (exact, plus a known cubic term)."""

from __future__ import annotations

import math

import h5py
import numpy as np
import pytest
import tifffile

from metasensor.config import SystemConfig
from metasensor.io.views import read_views
from metasensor.optics.psf import view_psfs
from metasensor.optics.psf_io import is_matlab_psf, load_matlab_psf
from metasensor.sensor.lfc import read_lfc

TINY = SystemConfig(nnum=7, mla_pitch=32.2e-6, mla_focal=322e-6, scan=7)


@pytest.mark.parametrize("dtype", ["uint16", "float32", "float64", "int32"])
def test_meta_image_stack_reads_as_views(tmp_path, dtype):
    views = (np.random.default_rng(0).random((13, 13, 6, 8)) * 1000).astype(dtype)
    tifffile.imwrite(tmp_path / "meta.tif", views.reshape(169, 6, 8))  # no description
    got = read_views(tmp_path / "meta.tif")
    assert got.shape == (13, 13, 6, 8) and got.dtype == views.dtype
    assert np.array_equal(got, views)


def _write_mat(path, bank, oversample=None):
    """A MATLAB v7.3 file: HDF5 with a 512-byte MATLAB header; psf_z of MATLAB size
    (y, x, u, v) is stored column-major, i.e. as the h5py dataset (v, u, x, y)."""
    with h5py.File(path, "w", userblock_size=512) as f:
        f.create_dataset("psf_z", data=bank.transpose(1, 0, 3, 2))
        if oversample is not None:
            f.create_dataset("OSR", data=np.array([[float(oversample)]]))
    with open(path, "r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(116, b" "))


def test_matlab_psf_file_reads_as_the_bank(tmp_path):
    bank = view_psfs(TINY, size=15, cache=False, device="cpu")
    _write_mat(tmp_path / "psf_init.mat", bank)
    assert is_matlab_psf(tmp_path / "psf_init.mat")
    got = load_matlab_psf(tmp_path / "psf_init.mat", nnum=7)
    assert np.array_equal(got, bank)
    from metasensor.recon.commands import read_psf_file

    got2, cfg = read_psf_file(tmp_path / "psf_init.mat")
    assert cfg is None and np.array_equal(got2, bank)
    with pytest.raises(ValueError, match="nnum is 9"):
        load_matlab_psf(tmp_path / "psf_init.mat", nnum=9)


def test_oversampled_matlab_psf_is_brought_to_the_pixel_grid(tmp_path):
    """view_psfs(subsample=3)'s sub-lattice through the centre, times 9, is the subsample-1
    bank (its documented normalisation): the reader applies the same rule."""
    fine = view_psfs(TINY, size=15, subsample=3, cache=False, device="cpu")
    coarse = view_psfs(TINY, size=15, cache=False, device="cpu", oversample=3)
    _write_mat(tmp_path / "psf_os.mat", fine, oversample=3)
    got = load_matlab_psf(tmp_path / "psf_os.mat")
    assert got.shape == coarse.shape
    np.testing.assert_allclose(got, coarse, atol=1e-6 * coarse.max())


def _cubic_from_similarity(pitch, rot_deg, centre, cubic=0.0):
    """reverseCoefficients (2, 10) of lenslet (s, t) -> pixel (x, y) for a grid of ``pitch``
    px rotated by ``rot_deg`` with lenslet (0, 0) at ``centre`` (row, col), plus ``cubic``·s³
    in x."""
    t = math.radians(rot_deg)
    c = np.zeros((2, 10))
    c[0, :3] = [centre[1], pitch * math.cos(t), -pitch * math.sin(t)]  # x = col
    c[1, :3] = [centre[0], pitch * math.sin(t), pitch * math.cos(t)]  # y = row
    c[0, 6] = cubic
    return c


def _write_lfc(path, coeffs, ns=20, nt=18, nu=13, shape=(260, 280)):
    with h5py.File(path, "w") as f:
        g = f.create_group("geometry")
        g.attrs.update(nu=nu, nv=nu, ns=ns, nt=nt, alignment_method="cubic")
        g.create_dataset("reverseCoefficients", data=coeffs.astype(np.float32))
        r = f.create_group("radiometry")
        r.create_dataset("radiometry", data=np.ones(shape, np.float32))


def test_lfc_calibration_reads_as_a_calibration(tmp_path):
    _write_lfc(tmp_path / "cal.lfc", _cubic_from_similarity(13.02, 0.4, (9.3, 11.7)))
    cal = read_lfc(tmp_path / "cal.lfc")
    assert cal.nnum == 13 and cal.sensor_shape == (260, 280)
    assert cal.pitch == pytest.approx(13.02, abs=1e-4)
    assert cal.rotation == pytest.approx(0.4, abs=1e-4)
    # the kept lenslet (0, 0) is a lattice point of the file's grid
    k = np.linalg.solve(cal.matrix * 13, np.asarray(cal.center) - np.array([9.3, 11.7]))
    np.testing.assert_allclose(k, np.round(k), atol=1e-4)
    assert cal.fit_residual is not None and cal.fit_residual < 1e-3
    # a cubic distortion a similarity cannot follow is refused, naming it
    _write_lfc(tmp_path / "bent.lfc", _cubic_from_similarity(13.0, 0.0, (6, 6), cubic=1e-3))
    with pytest.raises(ValueError, match="departs from one pitch and rotation"):
        read_lfc(tmp_path / "bent.lfc")
