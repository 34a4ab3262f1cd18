"""``metasensor reconstruct`` CLI: outputs, PSF file, errors; inputs never modified."""

import hashlib
import json

import h5py
import numpy as np
import pytest
import tifffile
from typer.testing import CliRunner

from metasensor.cli import app
from metasensor.config import SystemConfig
from metasensor.io.views import write_views
from metasensor.optics.psf_io import parse_zernike
from metasensor.recon.commands import read_psf_file
from recon_standin import gaussian_psfs, one_torch_thread, synth_views  # noqa: F401

CFG = SystemConfig(nnum=5, scan=5)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rec")
    rng = np.random.default_rng(2)
    bank = gaussian_psfs(nnum=5, radius=4)
    views, _ = synth_views(0.5 + rng.random((60, 60)).astype(np.float32), bank, 1, border=5)
    write_views(tmp / "views.tif", views, CFG)
    write_views(tmp / "views_origin.tif", views, CFG, extra={"origin": [3.25, -1.5]})
    write_views(tmp / "views_bad_origin.tif", views, CFG, extra={"origin": "12"})
    with h5py.File(tmp / "psf.h5", "w") as f:
        f.create_dataset("psf", data=bank)
        f.attrs["config"] = CFG.to_json()
    CFG.to_toml(tmp / "cfg.toml")
    return tmp


def test_reconstruct_cli_writes_image_and_figure(files):
    before = hashlib.sha256((files / "views.tif").read_bytes()).hexdigest()
    out = files / "out"
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--psf",
                                   str(files / "psf.h5"), "--blocks", "2x2", "--overlap", "6",
                                   "--iterations", "2", "--zarr", "--out", str(out)])
    assert res.exit_code == 0, res.output
    img = tifffile.imread(out / "image.tif")
    assert img.shape == (50, 50) and img.dtype == np.float32 and np.isfinite(img).all()
    assert (out / "reconstruction.png").stat().st_size > 1000
    summary = json.loads((out / "summary.json").read_text())
    assert summary["blocks"] == [2, 2] and len(summary["history"][0][0]) == 2
    assert summary["registration_px"] == [[[], []], [[], []]]  # Richardson-Lucy: no registration
    assert np.load(out / "zernike.npy").shape == (2, 2, 45)
    import zarr

    stored = zarr.open_array(str(out / "image.zarr"))
    np.testing.assert_array_equal(np.asarray(stored[:]), img)
    assert SystemConfig.from_dict(dict(stored.attrs)) == CFG  # the config, as image.tif has
    assert hashlib.sha256((files / "views.tif").read_bytes()).hexdigest() == before
    # the same folder again without --zarr: the earlier image.zarr would contradict image.tif
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--psf",
                                   str(files / "psf.h5"), "--iterations", "1", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert not (out / "image.zarr").exists()
    # default radius for nnum 5: 0.8 of the pupil radius 2.5 = 2, the views within 2 of the centre
    assert json.loads((out / "summary.json").read_text())["views_used"] == 13
    # view selection by pupil radius: radius 2 keeps 13 views
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--psf",
                                   str(files / "psf.h5"), "--iterations", "1", "--view-radius",
                                   "2", "--out", str(files / "out_r2")])
    assert res.exit_code == 0, res.output
    assert json.loads((files / "out_r2" / "summary.json").read_text())["views_used"] == 13


def test_reconstruct_records_the_views_origin(files):
    """realign stores where the views sit on the sensor (origin); the image keeps it (TIFF and
    Zarr), and an image of views without one has none."""
    import zarr

    from metasensor.io.views import stored_extras

    out = files / "out_origin"
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views_origin.tif"), "--psf",
                                   str(files / "psf.h5"), "--iterations", "1", "--zarr",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert stored_extras(out / "image.tif")["origin"] == [3.25, -1.5]
    assert zarr.open_array(str(out / "image.zarr")).attrs["metasensor"]["origin"] == [3.25, -1.5]
    assert "origin" not in stored_extras(files / "out" / "image.tif")
    bad = files / "out_bad_origin"  # a malformed stored origin is named and left out
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views_bad_origin.tif"), "--psf",
                                   str(files / "psf.h5"), "--iterations", "1", "--out", str(bad)])
    assert res.exit_code == 0, res.output
    assert "malformed origin" in res.output
    assert "origin" not in stored_extras(bad / "image.tif")


def test_cli_errors(files):
    runner = CliRunner()
    res = runner.invoke(app, ["reconstruct", str(files / "nope.tif"), "--out", str(files / "o")])
    assert res.exit_code != 0 and "not found" in str(res.exception)
    views, psf = str(files / "views.tif"), str(files / "psf.h5")
    res = runner.invoke(app, ["reconstruct", views, "--psf", psf,
                              "--config", str(files / "cfg.toml"), "--out", str(files / "o")])
    assert res.exit_code != 0 and "either" in str(res.exception)
    res = runner.invoke(app, ["reconstruct", views, "--psf", psf,
                              "--blocks", "4by4", "--out", str(files / "o")])
    assert res.exit_code != 0 and "--blocks" in str(res.exception)
    res = runner.invoke(app, ["reconstruct", "--help"])
    assert res.exit_code == 0 and "Example" in res.output


def test_psf_file_and_zernike_parsing(files):
    bank, cfg = read_psf_file(files / "psf.h5")
    assert bank.shape == (5, 5, 9, 9) and cfg == CFG
    z = parse_zernike("4:0.5,7:-0.2")
    assert z[3] == 0.5 and z[6] == -0.2 and np.count_nonzero(z) == 2
    with pytest.raises(ValueError, match="Noll index:waves"):
        parse_zernike("4=0.5")
    (files / "bad.h5").write_bytes(b"not hdf5")
    with pytest.raises(ValueError, match="HDF5"):
        read_psf_file(files / "bad.h5")


def test_cli_system_aberration_file_sets_the_field_map(files):
    from metasensor.dao.system_aberration import SystemAberration

    grid = np.zeros((2, 2, 45))
    grid[..., 3] = 0.25  # each block's bank is made with it, and it is reported per block
    sa = SystemAberration(zernike=grid, shift_grid=np.zeros((5, 5, 2, 2, 2)), view_shape=(50, 50),
                          config=CFG)
    sa.save(files / "system.h5")
    out = files / "out_sys"
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--config",
                                   str(files / "cfg.toml"), "--blocks", "2x2", "--overlap", "6",
                                   "--iterations", "1", "--system", str(files / "system.h5"),
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    np.testing.assert_array_equal(np.load(out / "zernike.npy"), grid)
    # with a given bank the field map would be ignored: refused
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--psf",
                                   str(files / "psf.h5"), "--system", str(files / "system.h5"),
                                   "--out", str(files / "out_sys2")])
    assert res.exit_code != 0 and "not both" in str(res.exception)
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--config",
                                   str(files / "cfg.toml"), "--system", str(files / "none.h5"),
                                   "--out", str(files / "out_sys3")])
    assert res.exit_code != 0 and "not found" in str(res.exception)


def test_figure_preview_block_averages_large_fields():
    # a sensor-sized field (5,985 x 7,905 px) is drawn as its 4 x 4 block means (<= 2,048 px)
    from metasensor.recon.outputs import PREVIEW_PX, _block_mean, _preview_factor

    assert _preview_factor((5985, 7905)) == 4
    assert max(5985, 7905) // _preview_factor((5985, 7905)) <= PREVIEW_PX
    assert _preview_factor((300, 400)) == 1
    img = np.arange(35, dtype=np.float32).reshape(5, 7)
    np.testing.assert_array_equal(_block_mean(img, 1), img)
    means = _block_mean(img, 2)  # the last odd row and column are dropped
    assert means.shape == (2, 3)
    assert means[0, 0] == pytest.approx((0 + 1 + 7 + 8) / 4)
    assert means[1, 2] == pytest.approx((18 + 19 + 25 + 26) / 4)


@pytest.mark.parametrize("d,f", [(3, 4), (3, 1), (5, 3), (3, 6), (2, 7)])
def test_centre_view_preview_equals_block_mean_of_the_upsampled_view(d, f):
    # the centre view is drawn up-sampled x d and block-averaged f x f; computed without the
    # up-sampled copy, it equals doing both (float32: 1e-6 relative)
    from metasensor.recon.outputs import _block_mean, _upsampled_block_mean

    view = np.random.default_rng(0).random((23, 31)).astype(np.float32)
    ref = _block_mean(np.kron(view, np.ones((d, d), np.float32)), f)
    got = _upsampled_block_mean(view, d, f)
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-6)


def test_cli_never_overwrites_its_input_and_leaves_no_partial_zarr(files, tmp_path):
    runner = CliRunner()
    views, psf = files / "views.tif", str(files / "psf.h5")
    before = hashlib.sha256(views.read_bytes()).hexdigest()
    named = tmp_path / "image.tif"  # a stack named like the result, in the output folder
    named.write_bytes(views.read_bytes())
    res = runner.invoke(app, ["reconstruct", str(named), "--psf", psf, "--out", str(tmp_path)])
    assert res.exit_code != 0 and "overwrite the input" in str(res.exception)
    assert named.read_bytes() == views.read_bytes()
    # a bad argument after the zarr target exists: no image.zarr, no temporary left behind
    out = tmp_path / "o"
    res = runner.invoke(app, ["reconstruct", str(views), "--psf", psf, "--zarr", "--method",
                              "nope", "--out", str(out)])
    assert res.exit_code != 0
    assert not (out / "image.zarr").exists() and not (out / ".image.zarr.partial").exists()
    assert hashlib.sha256(views.read_bytes()).hexdigest() == before


def test_reconstruct_rejects_dark_or_negative_banks():
    from metasensor.recon.api import reconstruct

    v = np.ones((5, 5, 12, 12), np.float32)
    with pytest.raises(ValueError, match="no light"):
        reconstruct(v, CFG, psf=np.zeros((5, 5, 5, 5), np.float32), iterations=1)
    with pytest.raises(ValueError, match="non-negative"):
        reconstruct(v, CFG, psf=-np.ones((5, 5, 5, 5), np.float32), iterations=1)
    bank = gaussian_psfs(nnum=5, radius=2)
    tiny = bank - np.float32(1e-6 * bank.max())  # background-subtracted: tiny negatives pass
    kept = tiny.copy()
    rec = reconstruct(v, CFG, psf=tiny, iterations=1)
    assert np.isfinite(rec.image).all() and np.array_equal(tiny, kept)


def test_psf_bank_and_an_aberration_are_refused_together(files, tmp_path):
    # --psf is a complete bank: an aberration beside it would be silently ignored
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--psf",
                                   str(files / "psf.h5"), "--zernike", "4:0.5", "--out",
                                   str(tmp_path / "r")])
    assert res.exit_code != 0 and "not both" in str(res.exception)
    import metasensor as ms

    bank, cfg = read_psf_file(files / "psf.h5")
    views = np.zeros((cfg.nnum, cfg.nnum, 8, 8), np.float32)
    with pytest.raises(ValueError, match="not both"):
        ms.reconstruct(views, cfg, psf=bank, zernike=[0, 0, 0, 0.5])
    with pytest.raises(ValueError, match="DAO"):
        ms.reconstruct(views, cfg, psf=bank, method="wave")


def test_psf_bank_zernike_attribute_is_what_zernike_npy_records(files, tmp_path):
    src = files / "psf.h5"
    bank_file = tmp_path / "psf_z.h5"
    with h5py.File(src, "r") as f, h5py.File(bank_file, "w") as g:
        g.create_dataset("psf", data=f["psf"][...])
        g.attrs["config"] = f.attrs["config"]
        g.attrs["zernike"] = np.array([0, 0, 0, 0.3])
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--psf",
                                   str(bank_file), "--iterations", "1", "--out",
                                   str(tmp_path / "r")])
    assert res.exit_code == 0, res.output
    np.testing.assert_allclose(np.load(tmp_path / "r" / "zernike.npy"), [[[0, 0, 0, 0.3]]])


def test_config_that_resamples_the_stored_views_is_refused(files, tmp_path):
    # views stored with scan 5; a --config with scan 1 would reconstruct another grid silently
    CFG.replace(scan=1).to_toml(tmp_path / "scan1.toml")
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--config",
                                   str(tmp_path / "scan1.toml"), "--out", str(tmp_path / "r")])
    assert res.exit_code != 0 and "scan" in str(res.exception)
    # another difference (the NA) is the user's to make: it runs and names it
    CFG.replace(na=0.04).to_toml(tmp_path / "na.toml")
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--config",
                                   str(tmp_path / "na.toml"), "--iterations", "1", "--out",
                                   str(tmp_path / "r2")])
    assert res.exit_code == 0, res.output


def test_psf_bank_of_another_nnum_is_named(files, tmp_path):
    # a bank made for nnum 3 against nnum-5 views: used to read "scan period 5 does not divide
    # nnum 3"
    bank_file = tmp_path / "psf3.h5"
    with h5py.File(bank_file, "w") as f:
        f.create_dataset("psf", data=gaussian_psfs(nnum=3, radius=2))
        f.attrs["config"] = SystemConfig(nnum=3, scan=3).to_json()
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--psf",
                                   str(bank_file), "--out", str(tmp_path / "r")])
    assert res.exit_code != 0
    assert "made for nnum 3" in str(res.exception) and "nnum 5" in str(res.exception)


def test_quality_fast_is_a_richardson_lucy_preview_without_an_estimate(files, tmp_path):
    # --quality fast: Richardson-Lucy (its default 5 iterations) and --dao auto estimates
    # nothing; with --solver hqs it contradicts itself and is refused, naming the option.
    from metasensor.recon.commands import ReconstructArgs

    args = ReconstructArgs(views=files / "views.tif", out=tmp_path, quality="fast")
    assert args.dao == "none" and args.isa_solver == "rl"
    assert ReconstructArgs(views=files / "views.tif", out=tmp_path, quality="fast",
                           method="wave").dao == "wave"
    assert ReconstructArgs(views=files / "views.tif", out=tmp_path).isa_solver is None
    out = tmp_path / "fast"
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--psf",
                                   str(files / "psf.h5"), "--quality", "fast", "--workers", "2",
                                   "--blocks", "2x1", "--overlap", "6", "--out", str(out)])
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["solver"] == "rl" and len(summary["history"][0][0]) == 5
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--quality", "fast",
                                   "--solver", "hqs", "--out", str(tmp_path / "x")])
    assert res.exit_code != 0 and "--quality fast" in str(res.exception)


def test_reconstruct_runs_a_block_per_thread_unless_told(files, tmp_path, monkeypatch):
    # Without --workers the command asks for num_workers="auto": local_workers for its blocks
    # and the largest block window's bytes (float32); --workers overrides it.
    from metasensor.recon import parallel

    seen = []

    def counting(n, device=None, window_bytes=None):
        seen.append((n, window_bytes))
        return 2

    monkeypatch.setattr(parallel, "local_workers", counting)
    base = ["reconstruct", str(files / "views.tif"), "--psf", str(files / "psf.h5"),
            "--quality", "fast", "--blocks", "2x1", "--overlap", "6"]
    res = CliRunner().invoke(app, [*base, "--out", str(tmp_path / "auto")])
    assert res.exit_code == 0, res.output
    views = tifffile.imread(files / "views.tif")
    assert len(seen) == 1 and seen[0][0] == 2
    assert 0 < seen[0][1] < views.size * 4  # one block's window, float32
    res = CliRunner().invoke(app, [*base, "--workers", "1", "--out", str(tmp_path / "one")])
    assert res.exit_code == 0, res.output
    assert len(seen) == 1


def test_prior_option_runs_the_given_prior_and_refuses_what_it_cannot_run(files, tmp_path,
                                                                           monkeypatch):
    # --prior bm3d: HQS with the plug-and-play prior of metasensor.priors.external (here a
    # stand-in denoiser, so that the test needs no optional package); without the package, an
    # unknown prior, or with Richardson-Lucy: a ValueError (the command's exit 2), no work.
    from metasensor.priors import external
    from metasensor.recon.commands import ReconstructArgs
    from metasensor.solvers.hqs_options import HQSOptions

    calls = []

    def smooth(img, sigma):
        calls.append(sigma)
        return img

    args = ReconstructArgs(views=files / "views.tif", out=tmp_path)
    assert args.prior == "hyper-laplacian" and args.hqs_options is None
    monkeypatch.setattr(external, "require_bm3d", lambda: None)  # the package "present"
    monkeypatch.setattr(external, "bm3d_options", lambda **k: HQSOptions(
        prior=external.FunctionPrior(smooth), lam_scale=2.0))
    for bad, says in ((["--prior", "tv"], "--prior must be one of"),
                      (["--prior", "bm3d", "--quality", "fast"], "not with Richardson-Lucy")):
        res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), *bad,
                                       "--out", str(tmp_path / "x")])
        assert res.exit_code != 0 and says in str(res.exception), res.output
    out = tmp_path / "bm3d"
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--psf",
                                   str(files / "psf.h5"), "--prior", "bm3d", "--workers", "1",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    summary = json.loads((out / "summary.json").read_text())
    assert calls and summary["provenance"]["settings"]["prior"] == "bm3d"

    def missing():
        raise ImportError(external.BM3D_INSTALL)

    monkeypatch.setattr(external, "require_bm3d", missing)
    res = CliRunner().invoke(app, ["reconstruct", str(files / "views.tif"), "--prior", "bm3d",
                                   "--out", str(tmp_path / "x")])
    assert res.exit_code != 0 and "pip install 'metasensor[bm3d]'" in str(res.exception)
    assert not (tmp_path / "x").exists()
