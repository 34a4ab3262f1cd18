"""The ``metasensor psf`` command, the HDF5 bank format and the --zernike parser."""

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from metasensor.config import SystemConfig
from metasensor.optics.commands import register
from metasensor.optics.psf import view_psfs
from metasensor.optics.psf_io import load_psf, parse_zernike, save_psf

runner = CliRunner()


def _make_app() -> typer.Typer:
    """An app with this stage's commands plus a dummy, so "psf" is a sub-command whatever
    else is registered."""
    app = typer.Typer(pretty_exceptions_enable=False)
    register(app)

    @app.command("noop")
    def noop() -> None:  # pragma: no cover
        """Placeholder."""

    return app


app = _make_app()


@pytest.fixture
def tiny_cfg_file(tmp_path):
    cfg = SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
    return cfg, cfg.to_toml(tmp_path / "cfg.toml")


def test_parse_zernike():
    z = parse_zernike("4:0.5, 7:-0.2")
    np.testing.assert_array_equal(z, [0, 0, 0, 0.5, 0, 0, -0.2])
    assert parse_zernike("") is None
    for bad in ("4", "4:x", "a:1", "0:1", "4:0.5;7:1", "4:nan"):
        with pytest.raises(ValueError, match="zernike"):
            parse_zernike(bad)


def test_parse_zernike_reads_a_noll_vector_file(tmp_path):
    # simulate's wavefront.npy, passed on to reconstruct --zernike
    np.save(tmp_path / "w.npy", np.array([0, 0, 0, 0.4, 0.1]))
    np.testing.assert_array_equal(parse_zernike(str(tmp_path / "w.npy")), [0, 0, 0, 0.4, 0.1])
    np.save(tmp_path / "grid.npy", np.zeros((2, 2, 5)))
    with pytest.raises(ValueError, match="1-D Noll vector"):
        parse_zernike(str(tmp_path / "grid.npy"))
    with pytest.raises(FileNotFoundError, match="zernike"):
        parse_zernike(str(tmp_path / "none.npy"))
    (tmp_path / "bad.npy").write_bytes(b"junk")
    with pytest.raises(ValueError, match="not a readable"):
        parse_zernike(str(tmp_path / "bad.npy"))


def test_psf_command_writes_bank_and_figure(tiny_cfg_file, tmp_path):
    cfg, path = tiny_cfg_file
    before = path.read_text()
    out = tmp_path / "psf.h5"
    res = runner.invoke(app, ["psf", "--config", str(path), "--zernike", "4:0.3",
                              "--depth", "1e-5", "--size", "9", "--out", str(out)])
    assert res.exit_code == 0, res.output
    psf, cfg2 = load_psf(out)
    assert cfg2 == cfg and psf.shape == (3, 3, 9, 9) and psf.dtype == np.float32
    z = np.zeros(4)
    z[3] = 0.3
    np.testing.assert_allclose(psf, view_psfs(cfg, z, 1e-5, size=9), rtol=1e-6, atol=1e-9)
    png = out.with_suffix(".png")
    assert png.is_file() and png.read_bytes()[:4] == b"\x89PNG"
    assert path.read_text() == before  # the input is never modified
    assert not list(tmp_path.glob(".psf.h5*"))  # no temporary left behind


@pytest.mark.parametrize("args, match", [
    (["--zernike", "4=0.5"], "zernike"),
    (["--zernike", "0:1"], "Noll"),
    (["--size", "8"], "size"),
    (["--subsample", "2"], "subsample"),
])
def test_psf_command_bad_args(tiny_cfg_file, tmp_path, args, match):
    _, path = tiny_cfg_file
    out = tmp_path / "psf.h5"
    res = runner.invoke(app, ["psf", "--config", str(path), "--out", str(out), *args])
    assert res.exit_code != 0
    assert isinstance(res.exception, ValueError) and match in str(res.exception)
    assert not out.exists()


def test_psf_command_missing_config(tmp_path):
    res = runner.invoke(app, ["psf", "--config", str(tmp_path / "nope.toml"),
                              "--out", str(tmp_path / "psf.h5")])
    assert res.exit_code != 0
    assert isinstance(res.exception, ValueError) and "not found" in str(res.exception)


def test_main_prints_one_line_error(tiny_cfg_file, tmp_path, monkeypatch, capsys):
    """metasensor.cli.main turns a bad argument into one line on stderr and exit status 2."""
    import sys

    from metasensor.cli import main

    _, path = tiny_cfg_file
    sub = ["psf"]  # the app lists its commands lazily (cli._COMMANDS)
    monkeypatch.setattr(sys, "argv", ["metasensor", *sub, "--config", str(path),
                                      "--zernike", "x", "--out", str(tmp_path / "p.h5")])
    with pytest.raises(SystemExit) as exc:
        main()
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "zernike" in err[0]


def test_load_psf_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_psf(tmp_path / "missing.h5")
    bad = tmp_path / "bad.h5"
    bad.write_bytes(b"not hdf5")
    with pytest.raises(ValueError, match="HDF5"):
        load_psf(bad)
    cfg = SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
    with pytest.raises(ValueError, match="shape"):
        save_psf(tmp_path / "x.h5", np.zeros((2, 2, 5, 5)), cfg)
