"""HQS's noise for its data weight: the second differences against the views' fitted
Poisson–Gaussian model, and the scan factor (d / 3)^e of λ."""

import warnings

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
from metasensor.simulation.scenes import resolution_chart
from metasensor.solvers.hqs import HQSOptions, estimate_noise
from metasensor.solvers.noise_fit import fitted_noise_rms
from metasensor.solvers.noise_model import PoissonGaussian
from recon_standin import one_torch_thread  # noqa: F401


@pytest.fixture(scope="module")
def chart_3x3():
    """A chart through a 3 x 3 scan (5-px samples), 30 dB per frame: the used views and the
    r.m.s. of the noise the simulator drew."""
    cfg = ms.SystemConfig(scan=3)
    cap = ms.simulate(resolution_chart(10 * 15 + 14), cfg, snr_db=30.0, seed=0,
                      comparison=False)
    m = cfg.view_mask()
    views = cap.views[m].astype(np.float32)
    drawn = float(np.sqrt(np.mean((views.astype(np.float64) - cap.views_clean[m]) ** 2)))
    return views, drawn


def test_the_fitted_model_reads_the_drawn_noise_where_the_differences_read_the_scene(chart_3x3):
    # Coarse samples of a chart: its edges fill the second differences (2.7 x the drawn noise
    # measured), while the fit reads smooth samples only (1.28 x measured at these 30-sample
    # views; within 10 % on the 80-sample views of a 5 x 5 scan of the same field)
    views, drawn = chart_3x3
    full = torch.ones(views.shape[1:], dtype=torch.bool)
    differences = estimate_noise(torch.from_numpy(views), full) / drawn
    fitted = fitted_noise_rms(views) / drawn
    assert differences > 2.0, differences
    assert 0.9 < fitted < 1.4, fitted
    assert fitted < 0.6 * differences


def test_model_noise_is_the_model_at_the_observed_mean_level():
    y = torch.full((3, 4, 5), 100.0)
    y[:, :, -1] = 1e6  # unobserved: left out
    y[:, 0, 0] = -50.0  # below the zero level: no negative variance
    mask = torch.ones((4, 5), dtype=torch.bool)
    mask[:, -1] = False
    model = PoissonGaussian(a=2.0, b=25.0)
    expect = np.sqrt((15 * (2.0 * 100 + 25) + 25) / 16)  # 16 observed positions per view
    assert model.rms(y, mask) == pytest.approx(expect, rel=1e-6)
    with pytest.raises(ValueError, match="observed"):
        model.rms(y, torch.zeros((4, 5), dtype=torch.bool))
    with pytest.raises(ValueError, match="V, My, Mx"):
        model.rms(y[0])


def _weight(options: HQSOptions, d: int, side: int = 24):
    from metasensor.solvers.hqs import INIT_CG, REG_FLOOR, FoldedXStep, _data_weight, _noise
    from metasensor.solvers.priors import GRADIENT

    cfg = ms.SystemConfig()
    bank = np.asarray(ms.view_psfs(cfg), np.float32)[cfg.view_mask()][::4]
    g = make_geometry((side, side), d, bank.shape[-1] // 2)
    op = PhaseSpaceOperator(bank, g, device="cpu")
    truth = torch.from_numpy(resolution_chart(g.domain[0]))
    clean = op.forward(truth)
    gen = torch.Generator().manual_seed(0)
    y = clean + 0.05 * float(clean.mean()) * torch.randn(clean.shape, generator=gen)
    m = torch.ones(g.grid, dtype=torch.bool)
    unit = 2 * float(y.sum()) / float(op.sensitivity(m.float()).sum())
    nm = op.normal()
    smooth = FoldedXStep(nm, op.masked_normal(m, nm), m, GRADIENT, REG_FLOOR, INIT_CG, True)
    aty = op.adjoint(y / unit)
    return _data_weight(op, smooth, aty, y, m, unit, options), _noise(y, m, options)[0]


def test_the_scan_exponent_scales_the_data_weight_by_d_over_3():
    lam2, sigma = _weight(HQSOptions(noise=3.0), d=5)
    lam_half, _ = _weight(HQSOptions(noise=3.0, scan_exponent=0.5), d=5)
    assert sigma == 3.0
    assert lam_half / lam2 == pytest.approx((5 / 3) ** (0.5 - 2), rel=1e-6)
    lam3, _ = _weight(HQSOptions(noise=3.0), d=3)
    lam3_half, _ = _weight(HQSOptions(noise=3.0, scan_exponent=0.5), d=3)
    assert lam3_half == pytest.approx(lam3, rel=1e-9)  # the 5 x 5 scan's step: no factor


def test_a_given_model_sets_the_noise_and_a_refused_fit_falls_back_with_a_warning():
    model = PoissonGaussian(a=0.0, b=4.0)
    _, sigma = _weight(HQSOptions(noise_estimate=model), d=3)
    assert sigma == pytest.approx(2.0, rel=1e-6)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _, fell_back = _weight(HQSOptions(noise_estimate="poisson-gaussian"), d=3, side=6)
    _, differences = _weight(HQSOptions(), d=3, side=6)
    assert fell_back == differences  # 29 views of 6 x 6 samples: too few smooth ones
    assert any("second-difference" in str(w.message) for w in caught)


@pytest.mark.parametrize("bad", [{"noise_estimate": "mad"}, {"noise_estimate": None},
                                 {"scan_exponent": -1.0}, {"scan_exponent": float("nan")},
                                 {"scan_exponent": True}])
def test_bad_noise_settings_are_named(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        HQSOptions(**bad)


def test_reconstruct_fits_the_model_once_on_the_whole_capture(monkeypatch):
    import metasensor.solvers.noise_fit as nf
    from metasensor.recon.noise import capture_noise

    calls = []
    real = nf.fit_poisson_gaussian
    monkeypatch.setattr(nf, "fit_poisson_gaussian", lambda v, *a: calls.append(v.shape)
                        or real(v, *a))
    cfg = ms.SystemConfig()
    cap = ms.simulate(resolution_chart(10 * 15 + 14), cfg, snr_db=30.0, seed=0,
                      comparison=False)
    opts = capture_noise(HQSOptions(noise_estimate="poisson-gaussian"), cap.views)
    assert isinstance(opts.noise_estimate, PoissonGaussian) and opts.noise_estimate.a > 0
    assert calls == [cap.views.shape]
    # the default: fitted only to find whether the views carry noise; these do, so untouched
    assert capture_noise(HQSOptions(), cap.views) == HQSOptions()
    assert calls == [cap.views.shape] * 2
    given = HQSOptions(noise_estimate="poisson-gaussian", noise=1.0)
    assert capture_noise(given, cap.views) is given
    weighted = HQSOptions(noise_estimate="poisson-gaussian", noise_model=PoissonGaussian(1, 1))
    assert capture_noise(weighted, cap.views) is weighted
    assert calls == [cap.views.shape] * 2  # neither of the last two fitted


def test_reconstruct_hands_every_block_the_capture_model(monkeypatch):
    # blocks of 2 x 2 on a 164-px capture: each block's own samples could not carry a fit (no
    # fallback warning), and every solve's noise is the capture model's r.m.s. over its samples
    import metasensor.solvers.hqs as hqs_module

    cfg = ms.SystemConfig()
    cap = ms.simulate(resolution_chart(10 * 15 + 14), cfg, snr_db=30.0, seed=0,
                      comparison=False)
    seen = []
    real = hqs_module._noise
    monkeypatch.setattr(hqs_module, "_noise", lambda y, m, o: seen.append(o.noise_estimate)
                        or real(y, m, o))
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        rec = ms.reconstruct(cap.views, cfg, blocks=(2, 2), solver_options=HQSOptions(
            noise_estimate="poisson-gaussian"))
    assert np.isfinite(rec.image).all() and rec.image.shape == cap.truth.shape
    assert len(seen) >= 4 and all(isinstance(n, PoissonGaussian) for n in seen)
    assert len({(n.a, n.b) for n in seen}) == 1  # one model, fitted once


def test_auto_settings_follow_the_noise_measurement():
    from metasensor.solvers.hqs_options import ESTIMATE_SETTINGS

    auto = HQSOptions()
    assert auto.data_weight_settings("differences") == ESTIMATE_SETTINGS["differences"] == (2.0,
                                                                                            1.1)
    assert auto.data_weight_settings("poisson-gaussian") == (0.5, 0.95)
    fixed = HQSOptions(scan_exponent=1.0, misfit_weights=None)
    assert fixed.data_weight_settings("poisson-gaussian") == (1.0, None)
    # a given model's σ takes the Poisson-Gaussian exponent 0.5, a given noise the
    # differences' 2: the same σ (3) weighs (5/3)^(0.5 - 2) as much at d = 5, alike at d = 3
    model = PoissonGaussian(a=0.0, b=9.0)
    lam5, sigma = _weight(HQSOptions(noise_estimate=model), d=5)
    lam5_given, _ = _weight(HQSOptions(noise=3.0), d=5)
    assert sigma == pytest.approx(3.0, rel=1e-6)
    assert lam5 / lam5_given == pytest.approx((5 / 3) ** (0.5 - 2), rel=1e-6)
    lam3, _ = _weight(HQSOptions(noise_estimate=model), d=3)
    lam3_given, _ = _weight(HQSOptions(noise=3.0), d=3)
    assert lam3 == pytest.approx(lam3_given, rel=1e-6)


@pytest.fixture(scope="module")
def chart_5x5_noisy_and_clean():
    cfg = ms.SystemConfig()
    scene = resolution_chart(10 * 15 + 14)
    return [ms.simulate(scene, cfg, snr_db=snr, seed=0, comparison=False).views
            for snr in (30.0, None)]


def test_auto_fits_noisy_views_and_falls_back_on_views_without_noise(chart_5x5_noisy_and_clean):
    from metasensor.recon.noise import capture_noise
    from metasensor.solvers.noise_fit import MAX_LACK_OF_FIT, fit_poisson_gaussian

    noisy, clean = chart_5x5_noisy_and_clean
    fit = fit_poisson_gaussian(noisy)
    assert fit.holds() and fit.lack_of_fit < MAX_LACK_OF_FIT / 10
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        quantised = fit_poisson_gaussian(clean)  # the scene's structure, not noise
    assert not quantised.holds() and quantised.lack_of_fit > 2 * MAX_LACK_OF_FIT
    opts = capture_noise(HQSOptions(noise_estimate="auto"), noisy)
    assert isinstance(opts.noise_estimate, PoissonGaussian)
    assert opts.noise_estimate == fit.model
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # quietly
        back = capture_noise(HQSOptions(noise_estimate="auto"), clean)
    assert back == HQSOptions(noise_estimate="differences", cg_tol=1e-5)  # a precise solve
    exact = capture_noise(HQSOptions(noise_estimate="auto", cg_tol=0.0), clean)
    assert exact.cg_tol == 0.0  # a tighter tolerance given is kept


def test_the_default_solves_views_without_noise_precisely(chart_5x5_noisy_and_clean):
    # the second differences stay the noise measure; only the x-steps' tolerance follows the fit
    from metasensor.recon.noise import capture_noise

    noisy, clean = chart_5x5_noisy_and_clean
    assert capture_noise(HQSOptions(), noisy) == HQSOptions()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # quietly
        assert capture_noise(HQSOptions(), clean) == HQSOptions(cg_tol=1e-5)
    assert capture_noise(HQSOptions(cg_tol=0.0), clean).cg_tol == 0.0
    given = HQSOptions(noise=1.0)
    assert capture_noise(given, clean) is given  # a given noise: nothing measured
    # and so does "poisson-gaussian" (its model kept: it asked for one)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        pg_clean = capture_noise(HQSOptions(noise_estimate="poisson-gaussian"), clean)
    pg_noisy = capture_noise(HQSOptions(noise_estimate="poisson-gaussian"), noisy)
    assert isinstance(pg_clean.noise_estimate, PoissonGaussian) and pg_clean.cg_tol == 1e-5
    assert isinstance(pg_noisy.noise_estimate, PoissonGaussian)
    assert pg_noisy.cg_tol == HQSOptions().cg_tol
