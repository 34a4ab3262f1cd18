"""The reconstruction's DAO default (``method="auto"``, the command line's ``--dao auto``): wave
DAO where nothing says what the aberration is, the given aberration or bank used as is, and a
block whose estimate is negligible keeps the aberration-free bank (the plain ISA image)."""

import numpy as np
import pytest

import metasensor as ms
from metasensor.recon.dao_choice import DAO_CHOICES, NEGLIGIBLE_RMS, choose_dao
from metasensor.simulation.scenes import load_scene


@pytest.mark.parametrize(("mode", "aberration", "bank", "method", "negligible"), [
    ("auto", False, False, "wave", NEGLIGIBLE_RMS),  # nothing known: estimate it
    ("auto", True, False, "isa", 0.0),  # a calibration / --zernike: used as is
    ("auto", False, True, "isa", 0.0),  # a complete PSF bank: used as is
    ("none", False, False, "isa", 0.0),  # the fast path
    ("isa", True, False, "isa", 0.0),
    ("wave", True, False, "wave", 0.0),  # explicit DAO: always applied, from the given start
    ("geometric", False, False, "geometric", 0.0),
])
def test_choose_dao(mode, aberration, bank, method, negligible):
    choice = choose_dao(mode, aberration_given=aberration, bank_given=bank)
    assert (choice.method, choice.negligible) == (method, negligible)
    assert choice.reason and "\n" not in choice.reason


def test_auto_without_views_to_estimate_from_says_so_and_runs_plain_isa():
    from metasensor.dao.estimate import dao_unavailable
    from metasensor.recon.api import _resolve_method
    from metasensor.recon.options import ReconOptions

    small = ms.SystemConfig(nnum=5, scan=5, na=0.02)  # one view in the default mask
    assert dao_unavailable(ms.SystemConfig()) is None
    reason = dao_unavailable(small)
    assert reason and "views" in reason
    choice = choose_dao("auto", aberration_given=False, bank_given=False, unavailable=reason)
    assert choice.method == "isa" and reason in choice.reason
    with pytest.warns(UserWarning, match="not estimated"):
        assert _resolve_method("auto", small, None, None, ReconOptions())[0] == "isa"


def test_choose_dao_refuses_an_unknown_mode_naming_the_choices():
    with pytest.raises(ValueError, match="auto, none, isa, wave, geometric.*'fast'"):
        choose_dao("fast", aberration_given=False, bank_given=False)
    assert set(DAO_CHOICES) == {"auto", "none", "isa", "wave", "geometric"}


def test_reconstruct_auto_keeps_the_plain_image_of_an_aberration_free_capture(capsys):
    cap = ms.simulate(load_scene("chart", 60), ms.SystemConfig(), snr_db=30, seed=0,
                      comparison=False)
    plain = ms.reconstruct(cap.views, cap.config, method="none")
    auto = ms.reconstruct(cap.views, cap.config, method="auto", progress=True)
    assert auto.method == "wave" and auto.dao_applied == [[False]]
    assert len(auto.dao_history[0][0]) == 1  # one probing update, no full estimate
    assert float(np.abs(auto.dao_zernike[0, 0]).max()) < NEGLIGIBLE_RMS
    assert not np.any(auto.zernike)  # the bank used: aberration-free
    np.testing.assert_array_equal(auto.image, plain.image)
    assert plain.method == "isa" and plain.dao_applied == [[None]] and plain.dao_zernike is None
    line = next(ln for ln in capsys.readouterr().err.replace("\r", "\n").splitlines()
                if ln.startswith("block (0, 0)"))
    assert "not applied" in line and f"under {NEGLIGIBLE_RMS:g} λ" in line


@pytest.mark.parametrize(("zernike", "field", "psf", "method"), [
    (None, None, None, "wave"), ([0, 0, 0, 0], None, None, "wave"),
    ([0, 0, 0, 0.2], None, None, "isa"), (None, np.zeros((2, 2, 4)), None, "isa"),
    (None, None, np.ones((15, 15, 3, 3), np.float32), "isa")])
def test_reconstruct_auto_uses_a_given_aberration_or_bank_as_is(zernike, field, psf, method):
    from metasensor.recon.api import _resolve_method
    from metasensor.recon.options import ReconOptions

    cfg = ms.SystemConfig()
    run, opts = _resolve_method("auto", cfg, zernike, field, ReconOptions(psf=psf))
    assert run == method
    assert opts.dao_negligible == (NEGLIGIBLE_RMS if method == "wave" else 0.0)
    run, opts = _resolve_method("auto", cfg, None, None, ReconOptions(dao_negligible=0.3))
    assert (run, opts.dao_negligible) == ("wave", 0.3)  # a given threshold is kept


def test_reconstruct_refuses_a_negative_negligible_threshold():
    with pytest.raises(ValueError, match="dao_negligible"):
        ms.reconstruct(np.ones((15, 15, 8, 8), np.float32), ms.SystemConfig(), method="auto",
                       dao_negligible=-0.1)


@pytest.mark.slow
def test_reconstruct_auto_corrects_half_a_wave_that_plain_isa_leaves():
    z = np.array([0, 0, 0, 0.35, 0.3, 0, 0.2])  # 0.50 λ r.m.s.
    cap = ms.simulate(load_scene("chart", 90), ms.SystemConfig(), zernike=z, snr_db=30, seed=0,
                      comparison=False)
    plain = ms.reconstruct(cap.views, cap.config, method="none")
    auto = ms.reconstruct(cap.views, cap.config, method="auto")
    before = ms.metrics.ssim(truth=cap.truth, image=plain.image)
    after = ms.metrics.ssim(truth=cap.truth, image=auto.image)
    assert auto.dao_applied == [[True]]
    np.testing.assert_allclose(auto.zernike[0, 0, 3:7], z[3:7], atol=0.05)
    assert after > before + 0.2, (before, after)


def test_cli_dao_option_names_its_choices_and_says_what_it_does(tmp_path):
    from typer.testing import CliRunner

    from metasensor.cli import app
    from recon_standin import gaussian_psfs, synth_views

    cfg = ms.SystemConfig(nnum=5, scan=5)
    bank = gaussian_psfs(nnum=5, radius=4)
    views, _ = synth_views(0.5 + np.random.default_rng(0).random((40, 40)).astype(np.float32),
                           bank, 1, border=5)
    ms.write_views(tmp_path / "views.tif", views, cfg)
    import h5py

    with h5py.File(tmp_path / "psf.h5", "w") as f:
        f.create_dataset("psf", data=bank)
        f.attrs["config"] = cfg.to_json()
    res = CliRunner().invoke(app, ["reconstruct", str(tmp_path / "views.tif"), "--dao", "fast",
                                   "-o", str(tmp_path / "r")])
    assert res.exit_code != 0
    assert "--dao must be one of auto, none, isa, wave, geometric" in str(res.exception)
    res = CliRunner().invoke(app, ["reconstruct", str(tmp_path / "views.tif"), "--psf",
                                   str(tmp_path / "psf.h5"), "--iterations", "1", "-o",
                                   str(tmp_path / "r")])
    assert res.exit_code == 0, res.output
    assert "aberration: the given PSF bank is used as is" in res.output


@pytest.mark.slow
def test_cli_plain_reconstruct_estimates_half_a_wave(tmp_path):
    """``metasensor reconstruct views.tif -o out`` (the default, ``--dao auto``) against the
    plain ISA it ran before (``--dao none``) on a 0.5 λ capture."""
    import json

    import tifffile
    from typer.testing import CliRunner

    from metasensor.cli import app

    z = np.array([0, 0, 0, 0.35, 0.3, 0, 0.2])  # 0.50 λ r.m.s.
    cap = ms.simulate(load_scene("chart", 90), ms.SystemConfig(), zernike=z, snr_db=30, seed=0,
                      comparison=False)
    ms.write_views(tmp_path / "views.tif", cap.views, cap.config)
    ssim = {}
    for name, extra in (("before", ["--dao", "none"]), ("after", [])):
        res = CliRunner().invoke(app, ["reconstruct", str(tmp_path / "views.tif"), *extra,
                                       "-o", str(tmp_path / name)])
        assert res.exit_code == 0, res.output
        image = tifffile.imread(tmp_path / name / "image.tif")
        ssim[name] = ms.metrics.ssim(truth=cap.truth, image=image)
    summary = json.loads((tmp_path / "after" / "summary.json").read_text())
    assert summary["method"] == "wave" and summary["dao_applied"] == [[True]]
    from metasensor.recon.dao_fit import FIT_WARN_PX  # one wavefront explains this block

    assert 0 < summary["dao_fit_px_per_block"][0][0] < FIT_WARN_PX, summary
    assert summary["provenance"]["settings"]["method"] == "auto"
    assert ssim["after"] > ssim["before"] + 0.2, ssim
