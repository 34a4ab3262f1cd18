"""Any denoiser as a plug-and-play prior; BM3D through the optional package."""

import builtins

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

import metasensor as ms
from metasensor.priors.external import BM3D_INSTALL, FunctionPrior, bm3d_denoise, bm3d_options
from metasensor.simulation.scenes import load_scene
from metasensor.solvers.hqs_options import HQSOptions
from metasensor.solvers.priors import Identity, Prior
from metasensor.solvers.splitting import Continuation


def _gauss(img, sigma):
    """A denoiser whose width follows the noise level (a Wiener-like smoother)."""
    return gaussian_filter(img, 10.0 * sigma, mode="reflect")


def test_prior_contract_and_noise_levels():
    asked = []

    def spy(img, sigma):
        asked.append(sigma)
        return img * 0.5

    prior = FunctionPrior(spy, strength=2.0, sigma_min=0.01, sigma_max=0.1)
    assert isinstance(prior, Prior) and isinstance(prior.transform, Identity)
    z = torch.from_numpy(np.random.default_rng(0).random((2, 3, 16, 16)).astype(np.float32))
    keep = z.clone()
    out = prior.prox(z, 1e-4)
    assert out.shape == z.shape and out.dtype == z.dtype and out.device == z.device
    assert torch.equal(z, keep)  # the input is untouched
    torch.testing.assert_close(out, z * 0.5)
    assert asked == [pytest.approx(0.02)] * 6  # 2·sqrt(1e-4), once per image
    assert prior.sigma(1e-8) == 0.01 and prior.sigma(100.0) == 0.1  # clamped


def test_a_denoiser_may_not_modify_the_solver_image():
    def rude(img, sigma):
        img[:] = 0.0
        return img

    z = torch.ones(8, 8)
    out = FunctionPrior(rude).prox(z, 1e-3)
    assert torch.equal(z, torch.ones(8, 8)) and torch.equal(out, torch.zeros(8, 8))


def test_prior_options_and_outputs_are_checked():
    with pytest.raises(TypeError, match="denoise must be callable"):
        FunctionPrior(0.5)
    with pytest.raises(ValueError, match="strength"):
        FunctionPrior(_gauss, strength=0.0)
    with pytest.raises(ValueError, match="sigma_min"):
        FunctionPrior(_gauss, sigma_min=1.0)
    with pytest.raises(ValueError, match="weight"):
        FunctionPrior(_gauss).prox(torch.zeros(8, 8), -1.0)
    with pytest.raises(ValueError, match=r"returned shape \(4, 4\)"):
        FunctionPrior(lambda img, s: img[:4, :4]).prox(torch.zeros(8, 8), 1e-3)


def test_a_function_prior_reconstructs_a_capture_deterministically():
    cfg = ms.SystemConfig()
    cap = ms.simulate(load_scene("camera", 96), cfg, snr_db=30.0, seed=0)
    opts = HQSOptions(prior=FunctionPrior(_gauss), lam_scale=2.0,
                      continuation=Continuation(beta0=25.0, beta_max=400.0, beta_rate=2.0))
    a = ms.reconstruct(cap.views, cfg, solver_options=opts).image
    b = ms.reconstruct(cap.views, cfg, solver_options=opts).image
    np.testing.assert_array_equal(a, b)
    truth = cap.truth
    # it solves the problem: far closer to the truth than the views' mean level alone
    flat = np.full_like(truth, truth.mean())
    assert np.mean((a - truth) ** 2) < 0.25 * np.mean((flat - truth) ** 2)


def test_bm3d_without_its_package_names_the_extra(monkeypatch):
    real = builtins.__import__

    def no_bm3d(name, *args, **kwargs):
        if name == "bm3d":
            raise ImportError("No module named 'bm3d'")
        return real(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_bm3d)
    with pytest.raises(ImportError, match=r"metasensor\[bm3d\]") as err:
        bm3d_options()
    assert str(err.value) == BM3D_INSTALL
    with pytest.raises(ImportError, match="non-commercial"):
        bm3d_denoise(np.zeros((8, 8)), 0.1)


def test_bm3d_is_called_by_one_thread_at_a_time(monkeypatch):
    # its binary aborts the process when two blocks' solvers call it at once
    import sys
    import threading
    import time
    import types

    inside, overlaps = [], []

    def fake_bm3d(img, sigma):
        overlaps.append(len(inside))
        inside.append(1)
        time.sleep(0.02)
        inside.pop()
        return img

    monkeypatch.setitem(sys.modules, "bm3d", types.SimpleNamespace(bm3d=fake_bm3d))
    threads = [threading.Thread(target=bm3d_denoise, args=(np.zeros((8, 8)), 0.1))
               for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert overlaps == [0, 0, 0, 0]


def test_bm3d_denoises_where_installed():
    pytest.importorskip("bm3d")
    rng = np.random.default_rng(1)
    clean = np.kron(rng.random((6, 6)), np.ones((8, 8)))
    noisy = clean + rng.normal(0.0, 0.1, clean.shape)
    den = bm3d_denoise(noisy, 0.1)
    assert np.mean((den - clean) ** 2) < 0.25 * np.mean((noisy - clean) ** 2)
    opts = bm3d_options()
    assert isinstance(opts.prior, FunctionPrior) and opts.lam_scale == 2.0
