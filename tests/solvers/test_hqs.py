"""ISA with the sparse-gradient prior (solvers.hqs) on data that follow the model (and, once, not).

Scenes: the built-in chart on a 120 x 120 px circular domain (5 x 5 scan, 113 views, library
PSFs), white Gaussian noise at the simulator's SNR definition (mean square / noise power).
SSIM = skimage's, data range 1 (the chart spans 0.05-0.95).
"""

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
from metasensor.simulation.scenes import resolution_chart
from metasensor.solvers.hqs import HQSOptions, estimate_noise, hqs
from metasensor.solvers.priors import HyperLaplacian
from metasensor.solvers.richardson_lucy import richardson_lucy
from metasensor.solvers.splitting import Continuation
from recon_standin import one_torch_thread  # noqa: F401

S = 40  # view samples per side


def _ssim(a, b):
    from metasensor.metrics import ssim

    return ssim(truth=np.asarray(a), image=np.asarray(b), data_range=1.0)


@pytest.fixture(scope="module")
def bank():
    cfg = ms.SystemConfig()
    return np.asarray(ms.view_psfs(cfg), np.float32)[cfg.view_mask()]


def _problem(bank, pad, snr_db=30.0, seed=0):
    g = make_geometry((S, S), 3, bank.shape[-1] // 2, pad=pad)
    op = PhaseSpaceOperator(bank, g, device="cpu")
    truth = torch.from_numpy(resolution_chart(g.domain[0]))
    clean = op.forward(truth)
    sigma = float(torch.sqrt((clean**2).mean() / 10 ** (snr_db / 10)))
    gen = torch.Generator().manual_seed(seed)
    return g, op, truth, clean, clean + sigma * torch.randn(clean.shape, generator=gen), sigma


def test_noise_estimate_is_exact_on_flat_views_and_never_low(bank):
    # Second-difference MAD. Flat scene: 1.002 x sigma at 20-50 dB. Chart (dense edges on this
    # small domain): 1.10 / 1.75 / 4.2 / 12.9 x sigma at 20 / 30 / 40 / 50 dB: the edges add,
    # never subtract, so the data weight errs on the safe (over-regularised) side.
    for snr in (20.0, 30.0, 40.0, 50.0):
        g, op, _, _, y, sigma = _problem(bank, False, snr)
        full = torch.ones(g.grid, dtype=torch.bool)
        flat = op.forward(torch.full(g.domain, 0.5))
        gen = torch.Generator().manual_seed(1)
        noisy_flat = flat + sigma * torch.randn(flat.shape, generator=gen)
        assert abs(estimate_noise(noisy_flat, full) / sigma - 1) < 0.02
        ratio = estimate_noise(y, full) / sigma
        assert ratio >= 0.98
        if snr <= 30:
            assert ratio < 2.0


def test_prior_beats_richardson_lucy_and_the_linear_limit(bank):
    # 30 dB: the prior recovers what RL cannot (RL and the best linear reconstruction stop near
    # SSIM 0.55 on this chart; bench_isa_limit.py). Measured: HQS 0.81 with the estimated noise
    # (1.75 x sigma on this dense chart, see above), RL 0.54.
    g, op, truth, _, y, _ = _problem(bank, False)
    full = torch.ones(g.grid, dtype=torch.bool)
    x = hqs(op, y, full).estimate
    rl = richardson_lucy(op, torch.clamp(y, min=0), full).estimate
    s_hqs, s_rl = _ssim(truth, x), _ssim(truth, rl)
    assert s_hqs >= 0.78 and s_hqs > s_rl + 0.2, (s_hqs, s_rl)
    assert torch.isfinite(x).all() and float(x.min()) >= 0
    assert abs(float(x.sum() / truth.sum()) - 1) < 0.01  # flux within 1 %


def test_noise_free_data_are_recovered(bank):
    # Noise-free model-exact data with a small stated noise: SSIM >= 0.98 (measured 0.99).
    g, op, truth, clean, _, sigma = _problem(bank, False)
    x = hqs(op, clean, torch.ones(g.grid, dtype=torch.bool),
            HQSOptions(noise=sigma / 30)).estimate
    assert _ssim(truth, x) >= 0.98


def test_unobserved_margins_cost_little(bank):
    # Padded domain, views observed only on the window: the masked x-steps (preconditioned CG)
    # reach the quality of the fully observed problem on the window (measured 0.917 vs 0.920;
    # without CG, filling the margins with the prediction once per beta gave 0.650).
    g, op, truth, _, y, sigma = _problem(bank, True)
    mask = torch.zeros(g.grid, dtype=torch.bool)
    mask[g.sample_slices()] = True
    oy, ox = g.offset
    win = (slice(oy, oy + 3 * S), slice(ox, ox + 3 * S))
    masked = hqs(op, y * mask, mask, HQSOptions(noise=sigma)).estimate
    full = hqs(op, y, torch.ones_like(mask), HQSOptions(noise=sigma)).estimate
    s_m, s_f = _ssim(truth[win], masked[win]), _ssim(truth[win], full[win])
    assert s_m >= s_f - 0.02, (s_m, s_f)


def test_inputs_are_not_modified_and_bad_parameters_are_named(bank):
    g, op, _, _, y, _ = _problem(bank, False)
    full = torch.ones(g.grid, dtype=torch.bool)
    before = y.clone()
    hqs(op, y, full, HQSOptions(continuation=Continuation(beta_max=4.0)))
    assert torch.equal(y, before)
    with pytest.raises(ValueError, match="alpha"):
        hqs(op, y, full, HQSOptions(prior=HyperLaplacian(alpha=0.5)))
    with pytest.raises(ValueError, match="lam"):
        hqs(op, y, full, HQSOptions(lam=-1.0))
    with pytest.raises(ValueError, match="inner"):
        hqs(op, y, full, HQSOptions(inner=0))
    zero = hqs(op, torch.zeros_like(y), full)
    assert not zero.estimate.any()


def _mismatched_bank(bank):
    """The used views' bank of 0.6 λ defocus and 0.4 λ coma (Noll 4 and 7), ``bank``'s size: a
    bank that does not fit data made with ``bank``."""
    cfg = ms.SystemConfig()
    z = np.zeros(11)
    z[3], z[6] = 0.6, 0.4
    return np.asarray(ms.view_psfs(cfg, zernike=z, size=bank.shape[-1]),
                      np.float32)[cfg.view_mask()]


def test_model_error_bounds_the_data_weight(bank):
    # Data made with a defocused, comatic bank (0.6 / 0.4 waves), reconstructed with the ideal
    # one on a padded window at 30 dB. A data weight from the noise alone explodes (measured
    # r.m.s. error 5.5 on the 0-1 chart, max 33); bounded by the misfit of the nearly
    # unregularised fit (the default) it does not (0.283), and beats Richardson-Lucy (0.298).
    wrong = _mismatched_bank(bank)
    g = make_geometry((S, S), 3, bank.shape[-1] // 2, pad=True)
    truth = torch.from_numpy(resolution_chart(g.domain[0]))
    clean = PhaseSpaceOperator(wrong, g, device="cpu").forward(truth)
    sigma = float(torch.sqrt((clean**2).mean() / 1e3))
    gen = torch.Generator().manual_seed(0)
    mask = torch.zeros(g.grid, dtype=torch.bool)
    mask[g.sample_slices()] = True
    y = (clean + sigma * torch.randn(clean.shape, generator=gen)) * mask
    op = PhaseSpaceOperator(bank, g, device="cpu")
    oy, ox = g.offset
    win = (slice(oy, oy + 3 * S), slice(ox, ox + 3 * S))

    def err(x):
        return float(torch.sqrt(((x[win] - truth[win]) ** 2).mean()))

    samples, m = op.samples_and_mask(y, mask)
    unit = 2 * float(samples.sum()) / float(op.sensitivity(m.float()).sum())  # image mean 0.5
    noise_only = hqs(op, y, mask, HQSOptions(lam=0.3 / (sigma / unit) ** 2,
                                             misfit_weights=None)).estimate  # one weight
    default = hqs(op, y, mask).estimate
    rl = richardson_lucy(op, y, mask).estimate
    assert err(default) < err(rl) < 0.5
    assert err(noise_only) > 3.0


def test_carried_normal_products_equal_direct_ones(bank):
    # The x-step carries AᵀMA x along its CG iterations instead of recomputing it at the next
    # call, and the residual history is formed from it: both must equal the direct products.
    from metasensor.solvers.hqs import FoldedXStep, _residual_norm
    from metasensor.solvers.priors import GRADIENT

    g, op, _, _, y, sigma = _problem(bank, True)
    mask = torch.zeros(g.grid, dtype=torch.bool)
    mask[g.sample_slices()] = True
    yn = y * mask / float(y.mean())
    nm = op.normal()
    data_normal = op.masked_normal(mask, nm)
    step = FoldedXStep(nm, data_normal, mask, GRADIENT, 1e-4, 3)
    aty = op.adjoint(yn)
    solve = step.at(0.05 * step.scale)
    x = solve(aty, None)
    x = solve(aty * 1.1, x)  # a second call starts from the carried product
    ax = step.data_product(x)
    direct = data_normal(x)
    assert ax is not None and float((ax - direct).norm() / direct.norm()) < 1e-4
    assert step.data_product(x.clone()) is None  # only for the iterate it returned
    mf = mask.to(torch.float32)
    ref = float(torch.linalg.vector_norm((op.forward(x) - yn) * mf))
    assert abs(_residual_norm(op, x, ax, aty, yn, mf) - ref) < 1e-3 * ref
    assert _residual_norm(op, x, None, aty, yn, mf) == pytest.approx(ref, rel=1e-6)


def _masked_setup(bank, y_bank=None, snr_db=30.0):
    """A padded window (margins unobserved) as hqs sets it up: the operator, mask, normalised
    data, folded and masked normal products, the smooth x-step and Aᵀy."""
    from metasensor.solvers.hqs import INIT_CG, REG_FLOOR, FoldedXStep
    from metasensor.solvers.priors import GRADIENT

    g = make_geometry((S, S), 3, bank.shape[-1] // 2, pad=True)
    truth = torch.from_numpy(resolution_chart(g.domain[0]))
    clean = PhaseSpaceOperator(bank if y_bank is None else y_bank, g, device="cpu").forward(truth)
    sigma = float(torch.sqrt((clean**2).mean() / 10 ** (snr_db / 10)))
    mask = torch.zeros(g.grid, dtype=torch.bool)
    mask[g.sample_slices()] = True
    gen = torch.Generator().manual_seed(0)
    y = (clean + sigma * torch.randn(clean.shape, generator=gen)) * mask
    op = PhaseSpaceOperator(bank, g, device="cpu")
    unit = 2 * float(y.sum()) / float(op.sensitivity(mask.float()).sum())
    nm = op.normal()
    calls = []

    def data_normal(v, inner=op.masked_normal(mask, nm)):
        calls.append(1)
        return inner(v)

    smooth = FoldedXStep(nm, data_normal, mask, GRADIENT, REG_FLOOR, INIT_CG, True)
    return op, mask, y, unit, smooth, op.adjoint(y / unit), calls


def test_cg_stops_once_the_residual_is_under_its_tolerance(bank):
    # An x-step's PCG stops after the iteration that brings ‖r‖ under cg_tol·‖rhs‖ (r the
    # residual of its own system), else runs its cg iterations; tolerance 0: always all of them.
    _, _, _, _, step, aty, calls = _masked_setup(bank)
    mu = 1e-2 * step.scale
    system = step.system(mu)
    x0 = step.nm.solve(aty, step.nm.factor(mu / step.scale, step.reg_fold))
    for tol in (0.0, 1e-3):
        step.tol = tol
        del calls[:]
        x = step.at(mu)(aty, x0)
        n = len(calls)
        rel = float(torch.linalg.vector_norm(aty - system(x)) / torch.linalg.vector_norm(aty))
        if tol == 0.0:
            assert n == 1 + step.cg  # the start's product, then one per iteration
            full_rel = rel
        else:
            assert 2 <= n < 1 + step.cg and rel <= 1.01 * tol, (n, rel)
            assert full_rel < rel
    with pytest.raises(ValueError, match="cg_tol"):
        HQSOptions(cg_tol=-1e-4)


def test_data_weight_fit_is_skipped_only_where_the_start_fits_within_the_noise(bank):
    # λ from max(noise, misfit of the 1e-4-smoothness fit): the fit is skipped where the smooth
    # start's misfit is already under the noise (a weaker smoothness fits at least as closely),
    # so λ is the same with and without the start; with a bank that does not fit the data
    # (0.6 λ defocus, 0.4 λ coma) the misfit exceeds the noise and the fit is made.
    from metasensor.solvers.hqs import _data_weight

    wrong = _mismatched_bank(bank)
    for y_bank, fits in ((None, True), (wrong, False)):
        op, mask, y, unit, smooth, aty, calls = _masked_setup(bank, y_bank)
        opts = HQSOptions()
        start = smooth.at(opts.init_reg * smooth.scale)(aty, None)
        del calls[:]
        lam_start = _data_weight(op, smooth, aty, y, mask, unit, opts, start=start)
        skipped = not calls
        smooth.at(opts.init_reg * smooth.scale)(aty, None)  # the start's product carried again
        lam_fit = _data_weight(op, smooth, aty, y, mask, unit, opts)
        assert skipped == fits
        assert lam_start == pytest.approx(lam_fit, rel=1e-9)


def _jittered_views(bank, g, truth, rms_px: float, seed: int = 0):
    """Views in which every view of every scan position (frame) has its own PSF shift (normal,
    ``rms_px`` pixels per axis): the sub-aperture tilts of turbulence that changes during the
    scan, which the static bank does not hold."""
    from scipy.ndimage import shift

    rows = torch.arange(g.grid[0])[:, None] % 5
    cols = torch.arange(g.grid[1])[None, :] % 5
    rng = np.random.default_rng(seed)
    clean = torch.zeros((bank.shape[0], *g.grid))
    for a in range(5):
        for b in range(5):
            offsets = rng.normal(0.0, rms_px, (bank.shape[0], 2))
            moved = np.stack([shift(p, s, order=1) for p, s in zip(bank, offsets, strict=True)])
            frame = (rows == a) & (cols == b)
            clean[:, frame] = PhaseSpaceOperator(moved.astype(np.float32), g,
                                                 device="cpu").forward(truth)[:, frame]
    return clean


def test_misfit_weights_only_where_the_model_does_not_fit(bank, monkeypatch):
    # Default misfit_weights 1.1: where the nearly unregularised fit is within 1.1 x the noise
    # (data that follow the bank) the solve is the global weight's, bit for bit; where it is
    # not, the data term is weighted by the local misfit: a bank 0.6 / 0.4 λ off (model error
    # on every edge) reads as the global weight (measured r.m.s. error 0.2871 vs 0.2879), and
    # the Moon with every view of every frame moved by its own 3 px (turbulence that changes
    # during the scan) gains (measured 0.0421 vs 0.0429; beta_max 64 here, to be quick).
    import metasensor.solvers.hqs as hqs_module
    from metasensor.simulation.scenes import natural_image

    calls = []
    real = hqs_module.misfit_weights
    monkeypatch.setattr(hqs_module, "misfit_weights",
                        lambda *a: calls.append(a) or real(*a))
    quick = Continuation(beta_max=64.0)
    g = make_geometry((30, 30), 3, bank.shape[-1] // 2, pad=True)
    mask = torch.zeros(g.grid, dtype=torch.bool)
    mask[g.sample_slices()] = True
    oy, ox = g.offset
    win = (slice(oy, oy + 90), slice(ox, ox + 90))
    chart = torch.from_numpy(resolution_chart(g.domain[0]))
    moon = torch.from_numpy(natural_image("moon", g.domain[0]).astype(np.float32))
    moon = moon * (0.5 / float(moon.mean()))
    op = PhaseSpaceOperator(bank, g, device="cpu")
    cases = [(chart, op.forward(chart), False),
             (chart, PhaseSpaceOperator(_mismatched_bank(bank), g, device="cpu").forward(chart),
              True),
             (moon, _jittered_views(bank, g, moon, 3.0), True)]
    errors = []
    for truth, clean, weighted in cases:
        sigma = float(torch.sqrt((clean**2).mean() / 1e3))
        gen = torch.Generator().manual_seed(0)
        y = (clean + sigma * torch.randn(clean.shape, generator=gen)) * mask
        del calls[:]
        x = hqs(op, y, mask, HQSOptions(continuation=quick)).estimate
        assert bool(calls) == weighted
        if calls:  # floored at the fit's r.m.s. misfit: no position above the global weight
            resid, m = calls[0][0], calls[0][1]
            rms = float(torch.sqrt((resid[:, m] ** 2).mean()))
            assert calls[0][2] == pytest.approx(rms, rel=1e-4) and calls[0][3] == 3
        one = hqs(op, y, mask, HQSOptions(continuation=quick, misfit_weights=None)).estimate
        assert torch.equal(x, one) != weighted
        errors.append([float(torch.sqrt(((v - truth)[win] ** 2).mean())) for v in (x, one)])
    assert abs(errors[1][0] - errors[1][1]) < 0.005, errors
    assert errors[2][0] < errors[2][1] - 0.0004, errors
    for bad in (0.0, -1.0, True, float("nan"), "1.1"):
        with pytest.raises(ValueError, match="misfit_weights"):
            HQSOptions(misfit_weights=bad)
    for bad in (0, 2, True, 3.0):
        with pytest.raises(ValueError, match="misfit_pool"):
            HQSOptions(misfit_pool=bad)


def test_progress_says_when_the_set_up_is_done_then_ticks_once_per_beta(bank):
    # 0 once, before the first β (a caller's set-up gate opens there), then 1 after each β
    g, op, _, _, y, _ = _problem(bank, True)
    mask = torch.zeros(g.grid, dtype=torch.bool)
    mask[g.sample_slices()] = True
    calls = []
    betas = Continuation(beta0=1.0, beta_max=16.0, beta_rate=4.0)
    res = hqs(op, y * mask, mask, HQSOptions(continuation=betas), progress=calls.append)
    assert calls == [0] + [1] * len(betas.betas()) == [0] + [1] * len(res.history)
