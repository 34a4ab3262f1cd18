"""Global system-aberration calibration (dao/system_aberration.py)."""

import numpy as np
import pytest

from metasensor.config import SystemConfig
from metasensor.dao.system_aberration import SystemAberration, calibrate_system, plot_wavefront_map
from metasensor.dao.wavefront import gradient_matrix, zernike_rms
from metasensor.optics.field import evaluate_field_zernike, normalised_field
from metasensor.optics.zernike import random_zernike

CFG = SystemConfig()


def _checker(y, x, period=24.0):
    # smooth analytic checkerboard (image pixels): no interpolation error when displaced
    return 0.5 + 0.4 * np.tanh(3 * np.sin(2 * np.pi * y / period) * np.sin(2 * np.pi * x / period))


def _field_views(cfg, field_zernike, samples):
    """Views whose content is displaced by the modelled view shifts of a field-dependent
    aberration (geometric optics): V_uv(Y, X) = I(p − s_uv(p)), p the sample's image pixel."""
    d = cfg.scan_step_px
    g, _ = gradient_matrix(cfg)
    py = np.arange(samples) * d + d // 2
    yy, xx = np.meshgrid(py, py, indexing="ij")
    yn, xn = normalised_field(yy, xx, (samples * d, samples * d))
    z = evaluate_field_zernike(field_zernike, yn, xn)  # (h, w, J)
    shifts = np.einsum("uvcj,hwj->uvchw", g[..., : z.shape[-1]], z)  # pixels
    return _checker(yy - shifts[:, :, 0], xx - shifts[:, :, 1]).astype(np.float32)


@pytest.fixture(scope="module")
def calibrated():
    # 2 x 2 field grid of random aberrations, 0.3 λ r.m.s. over modes 4-15 at every centre
    truth = np.stack([np.stack([random_zernike(0.3, modes=range(4, 16), seed=10 * i + j)
                                for j in range(2)]) for i in range(2)])
    views = _field_views(CFG, truth, 72)
    sa = calibrate_system(views, CFG, blocks=(2, 2), grid=(6, 6), iterations=60)
    return truth, views, sa


@pytest.mark.slow
def test_recovers_field_dependent_wavefront(calibrated):
    # the wavefront at every block centre within 0.15 λ r.m.s. (modes 4-45) of the truth
    truth, _, sa = calibrated
    assert sa.zernike.shape == (2, 2, 45)
    for i in range(2):
        for j in range(2):
            assert zernike_rms(sa.zernike[i, j] - truth[i, j]) < 0.15


@pytest.mark.slow
def test_shift_maps_and_roundtrip(calibrated, tmp_path):
    truth, views, sa = calibrated
    maps = sa.shift_maps()
    assert maps.shape == (15, 15, 2, *views.shape[2:]) and maps.dtype == np.float32
    np.testing.assert_allclose(maps[7, 7], 0.0, atol=0.05)  # centre view is the reference
    assert sa.shift_maps((30, 40)).shape == (15, 15, 2, 30, 40)
    path = sa.save(tmp_path / "system.h5")
    back = SystemAberration.load(path)
    np.testing.assert_array_equal(back.zernike, sa.zernike)
    np.testing.assert_array_equal(back.shift_grid, sa.shift_grid)
    assert back.config == sa.config and back.view_shape == sa.view_shape
    png = plot_wavefront_map(sa, tmp_path / "map.png", truth=truth)
    assert png.stat().st_size > 1000


def test_bad_files_and_input(tmp_path):
    with pytest.raises(FileNotFoundError):
        SystemAberration.load(tmp_path / "missing.h5")
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(ValueError, match="HDF5"):
        SystemAberration.load(bad)
    with pytest.raises(ValueError, match="views"):
        calibrate_system(np.zeros((3, 3, 8, 8)), CFG)
    with pytest.raises(ValueError, match="blocks"):
        calibrate_system(np.ones((15, 15, 8, 8)), CFG, blocks=(0, 2))


@pytest.mark.slow
def test_cli_calibrate_aberration(calibrated, tmp_path):
    import typer
    from typer.testing import CliRunner

    from metasensor.dao.commands import register
    from metasensor.io.views import write_views

    app = typer.Typer()
    register(app)

    @app.command("noop")
    def _noop() -> None:  # a second command keeps typer in multi-command mode
        pass

    runner = CliRunner()
    res = runner.invoke(app, ["calibrate-aberration", "--help"])
    assert res.exit_code == 0 and "Example" in res.output
    _, views, _ = calibrated
    path = write_views(tmp_path / "checker.tif", views, CFG)
    before = path.read_bytes()
    out = tmp_path / "system.h5"
    res = runner.invoke(app, ["calibrate-aberration", str(path), "--out", str(out), "--blocks",
                              "2x2", "--grid", "6x6", "--iterations", "60"])
    assert res.exit_code == 0, res.output
    assert SystemAberration.load(out).zernike.shape == (2, 2, 45)
    assert out.with_suffix(".png").is_file()
    assert path.read_bytes() == before  # input untouched
    res = runner.invoke(app, ["calibrate-aberration", str(path), "--blocks", "2by2"])
    assert res.exit_code != 0 and "--blocks" in str(res.exception)
