"""``reconstruct``'s noise model: the views' stored gain and read noise on the command line."""

import json

import numpy as np
import pytest
import tifffile
from typer.testing import CliRunner

from metasensor.cli import app
from metasensor.config import SystemConfig
from metasensor.io.views import write_views
from recon_standin import gaussian_psfs, one_torch_thread, synth_views  # noqa: F401

CFG = SystemConfig(nnum=5, scan=5)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    import h5py

    tmp = tmp_path_factory.mktemp("noise")
    rng = np.random.default_rng(2)
    bank = gaussian_psfs(nnum=5, radius=4)
    views, _ = synth_views(100 + 200 * rng.random((60, 60)).astype(np.float32), bank, 1,
                           border=5)
    noisy = rng.poisson(views / 2.0) * 2.0 + rng.normal(0, 6.0, views.shape)
    noisy = np.clip(noisy, 0, None).astype(np.float32)
    write_views(tmp / "plain.tif", noisy, CFG)
    write_views(tmp / "stored.tif", noisy, CFG, extra={"gain": 2.0, "read_noise": 3.0,
                                                        "units": "DN"})
    with h5py.File(tmp / "psf.h5", "w") as f:
        f.create_dataset("psf", data=bank)
        f.attrs["config"] = CFG.to_json()
    return tmp


def _run(files, views, out, *extra):
    return CliRunner().invoke(app, ["reconstruct", str(files / views), "--psf",
                                    str(files / "psf.h5"), "--iterations", "2", "--out",
                                    str(files / out), *extra])


def test_noise_stored_uses_the_views_metadata(files):
    res = _run(files, "stored.tif", "global")
    assert res.exit_code == 0, res.output
    res = _run(files, "stored.tif", "stored", "--noise", "stored")
    assert res.exit_code == 0, res.output
    plain = tifffile.imread(files / "global" / "image.tif")
    shifted = tifffile.imread(files / "stored" / "image.tif")
    assert np.isfinite(shifted).all() and shifted.min() >= 0
    assert not np.array_equal(plain, shifted)  # RL's shifted-Poisson form (shift b/a = 18 DN)
    used = json.loads((files / "stored" / "summary.json").read_text())["noise_model"]
    assert used == {"a_dn_per_electron": 2.0, "b_dn2": 36.0 + 1.0 / 12.0, "source": "metadata"}
    # the default ("global") leaves Richardson-Lucy plain Poisson
    assert json.loads((files / "global" / "summary.json").read_text())["noise_model"] is None


def test_noise_option_errors_are_named(files):
    res = _run(files, "plain.tif", "none", "--noise", "stored")
    assert res.exit_code != 0 and "holds no gain" in str(res.exception)
    assert not (files / "none").exists()
    res = _run(files, "plain.tif", "bad", "--noise", "poisson")
    assert res.exit_code != 0 and "--noise" in str(res.exception)


def test_the_hqs_noise_estimate_flags_reach_the_solver_and_the_summary(files, monkeypatch):
    import metasensor.recon.api as api

    seen = []
    real = api._solver_options
    monkeypatch.setattr(api, "_solver_options", lambda *a, **k: seen.append(a[0].solver_options)
                        or real(*a, **k))
    args = ["reconstruct", str(files / "plain.tif"), "--psf", str(files / "psf.h5"), "--solver",
            "hqs", "--noise-estimate", "poisson-gaussian", "--scan-exponent", "0.5", "--out",
            str(files / "pg")]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 0, res.output
    assert seen and seen[0].noise_estimate == "poisson-gaussian" and seen[0].scan_exponent == 0.5
    settings = json.loads((files / "pg" / "summary.json").read_text())["provenance"]["settings"]
    assert settings["noise_estimate"] == "poisson-gaussian" and settings["scan_exponent"] == 0.5
    assert np.isfinite(tifffile.imread(files / "pg" / "image.tif")).all()


def test_the_hqs_noise_estimate_flags_are_refused_where_they_cannot_apply(files):
    res = _run(files, "plain.tif", "rl", "--noise-estimate", "poisson-gaussian")
    assert res.exit_code != 0 and "Richardson-Lucy" in str(res.exception)
    res = _run(files, "plain.tif", "mad", "--noise-estimate", "mad")
    assert res.exit_code != 0 and "--noise-estimate" in str(res.exception)
    assert not (files / "rl").exists() and not (files / "mad").exists()
