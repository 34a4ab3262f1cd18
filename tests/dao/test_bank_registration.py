"""View registration before ISA (dao.bank_registration): PSF translation, shift recovery, and its
effect
on the sparse-gradient solver under a PSF-bank error."""

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.dao.bank_registration import register_views, translate_psfs
from metasensor.metrics import ssim
from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
from metasensor.simulation.scenes import load_scene, resolution_chart
from recon_standin import one_torch_thread  # noqa: F401


def _gauss(k=15, sigma=2.0):
    r = torch.arange(k, dtype=torch.float32) - k // 2
    g = torch.exp(-(r[:, None] ** 2 + r[None, :] ** 2) / (2 * sigma**2))
    return g / g.sum()


def _centroid(h):
    k = h.shape[-1]
    r = torch.arange(k, dtype=torch.float64) - k // 2
    h = h.double()
    e = h.sum(dim=(-2, -1))
    return torch.stack([(h.sum(-1) * r).sum(-1) / e, (h.sum(-2) * r).sum(-1) / e], dim=-1)


def test_translate_psfs_moves_centroids_and_keeps_energy():
    psf = torch.stack([_gauss(), 2.0 * _gauss(sigma=1.5)])
    shifts = torch.tensor([[0.3, -1.7], [2.25, 0.0]], dtype=torch.float64)
    out = translate_psfs(psf, shifts)
    assert out.shape[-1] % 2 == 1 and out.shape[-1] == out.shape[-2] > psf.shape[-1]
    # a band-limited Gaussian moves by the Fourier shift exactly (tolerance: 0.01 px)
    assert torch.allclose(_centroid(out), shifts, atol=1e-2)
    assert torch.allclose(out.sum(dim=(-2, -1)), psf.sum(dim=(-2, -1)), rtol=1e-5)
    assert float(out.min()) >= 0.0
    with pytest.raises(ValueError, match="shifts must have shape"):
        translate_psfs(psf, torch.zeros(3, 2))
    with pytest.raises(ValueError, match="K odd"):
        translate_psfs(torch.zeros(2, 4, 4), torch.zeros(2, 2))


@pytest.fixture(scope="module")
def bank():
    cfg = ms.SystemConfig()
    return torch.from_numpy(np.asarray(ms.view_psfs(cfg), np.float32)[cfg.view_mask()])


def test_register_views_recovers_defocus_like_shifts(bank):
    # data made with every view translated in proportion to its pupil position (as defocus does,
    # 0.7 px r.m.s.); registering against the untranslated bank recovers them (30 dB)
    cfg = ms.SystemConfig()
    u, v = np.nonzero(cfg.view_mask())
    c = cfg.nnum // 2
    true = torch.tensor(np.stack([u - c, v - c], axis=1) * 0.18, dtype=torch.float64)
    s = 40
    moved = translate_psfs(bank, true)
    g = make_geometry((s, s), 3, moved.shape[-1] // 2, pad=True)
    op = PhaseSpaceOperator(moved, g, device="cpu")
    truth = torch.from_numpy(resolution_chart(g.domain[0]))  # the scene continues past the window
    clean = op.forward(truth)
    gen = torch.Generator().manual_seed(0)
    sigma = float(torch.sqrt((clean**2).mean() / 1e3))
    noisy = clean + sigma * torch.randn(clean.shape, generator=gen)
    oy, ox = g.m0
    window = noisy[:, oy:oy + s, ox:ox + s]
    reg = register_views(bank, window, 3, device="cpu")
    err = (reg.shifts - true).pow(2).sum(dim=1).mean().sqrt()
    assert float(err) < 0.1, float(err)  # of 0.70 px r.m.s.
    assert reg.history[0] > 0.4 and reg.history[-1] < 0.05, reg.history


@pytest.fixture(scope="module")
def capture():
    cfg = ms.SystemConfig()
    return ms.simulate(load_scene("chart", 150), cfg, snr_db=30.0, seed=0, comparison=False)


def test_registration_rescues_hqs_from_a_defocus_error(capture):
    # the bank assumes 0.1 λ r.m.s. of defocus the capture does not have (outer views ~1.6 px
    # off). Measured at 150 px (2026-11-26): HQS SSIM 0.828 with the right bank; with the wrong
    # one 0.361 unregistered (the default) and 0.786 registered.
    cap = capture
    t = cap.truth
    rng = float(t.max() - t.min())
    z = np.zeros(15)
    z[3] = 0.1
    right = ms.reconstruct(cap.views, cap.config, register=True)
    wrong = ms.reconstruct(cap.views, cap.config, zernike=z)  # the default: no registration
    fixed = ms.reconstruct(cap.views, cap.config, zernike=z, register=True)
    s_right, s_wrong, s_fixed = (ssim(truth=t, image=r.image, data_range=rng)
                                 for r in (right, wrong, fixed))
    assert s_fixed > s_wrong + 0.2, (s_wrong, s_fixed)
    assert s_fixed > s_right - 0.06, (s_right, s_fixed)
    assert right.registration[0][0][0] < 0.05  # the right bank: nothing to register
    assert fixed.registration[0][0][0] > 0.4 and fixed.registration[0][0][-1] < 0.1
    assert wrong.registration == [[[]]] and wrong.registration_zernike is None
    # the fit names the bank's error: 0.1 λ too much defocus reads Z4 ~ -0.1 λ
    assert -0.12 < fixed.registration_zernike[0, 0, 3] < -0.08, fixed.registration_zernike[0, 0]


def test_registration_rejects_shifts_that_do_not_lower_the_misfit(bank, monkeypatch):
    # the views follow the bank exactly; a (forced) wrong shift measurement of 2 px per view
    # raises the misfit, so the candidate is rejected and the bank kept
    import metasensor.dao.bank_registration as reg_mod

    s = 30
    g = make_geometry((s, s), 3, bank.shape[-1] // 2, pad=True)
    op = PhaseSpaceOperator(bank, g, device="cpu")
    clean = op.forward(torch.from_numpy(resolution_chart(g.domain[0])))
    oy, ox = g.m0
    window = clean[:, oy:oy + s, ox:ox + s]
    gen = torch.Generator().manual_seed(1)
    wrong = 2.0 / 3.0 * torch.randn((bank.shape[0], 2), generator=gen, dtype=torch.float64)
    monkeypatch.setattr(reg_mod, "measure_shifts_torch", lambda *a, **k: wrong)
    reg = register_views(bank, window, 3, device="cpu", rounds=3)
    assert len(reg.history) == 1 and len(reg.misfits) == 2
    assert reg.misfits[1] > reg.misfits[0]
    assert float(torch.linalg.vector_norm(reg.shifts)) == 0.0
    assert torch.equal(reg.psf, bank)


def _shifted_window(bank, true, s=40, seed=0):
    moved = translate_psfs(bank, true)
    g = make_geometry((s, s), 3, moved.shape[-1] // 2, pad=True)
    op = PhaseSpaceOperator(moved, g, device="cpu")
    clean = op.forward(torch.from_numpy(resolution_chart(g.domain[0])))
    gen = torch.Generator().manual_seed(seed)
    sigma = float(torch.sqrt((clean**2).mean() / 1e3))
    noisy = clean + sigma * torch.randn(clean.shape, generator=gen)
    oy, ox = g.m0
    return noisy[:, oy:oy + s, ox:ox + s]


def test_wavefront_registration_applies_a_gradient_field_and_names_the_bank_error(bank):
    # shifts in proportion to the pupil position are a defocus error's: with the system given,
    # the fit explains them (> 0.95), applies its gradient field, and reports the error as Z4.
    # Expected Z4: the view at pupil edge (7, 13) moves by 0.18 * 6 = 1.08 px, and one wave of
    # Z4 moves it by -12.65 px (wavefront.predicted_shifts): about -0.085 λ.
    from metasensor.dao.wavefront import predicted_shifts

    cfg = ms.SystemConfig()
    u, v = np.nonzero(cfg.view_mask())
    c = cfg.nnum // 2
    true = torch.tensor(np.stack([u - c, v - c], axis=1) * 0.18, dtype=torch.float64)
    window = _shifted_window(bank, true)
    reg = register_views(bank, window, 3, device="cpu", cfg=cfg, uv=list(zip(u, v, strict=True)))
    err = (reg.shifts - true).pow(2).sum(dim=1).mean().sqrt()
    assert float(err) < 0.1, float(err)
    assert reg.explained[0] > 0.95, reg.explained
    per_wave = -predicted_shifts(np.array([0, 0, 0, 1.0]), cfg)[7, 13, 1]
    assert abs(reg.zernike[3] + 1.08 / per_wave) < 0.015, reg.zernike[3]
    others = np.delete(reg.zernike, 3)
    assert np.abs(others).max() < 0.01, others
    with pytest.raises(ValueError, match="cfg and uv"):
        register_views(bank, window, 3, device="cpu", cfg=cfg)


def test_wavefront_registration_stops_at_shifts_no_wavefront_explains(bank, monkeypatch):
    # a (forced) measurement of random shifts, 0.7 px r.m.s. per view: no wavefront error makes
    # them (the fit explains ~0.15 of them), so the round ends the registration before any fit
    import metasensor.dao.bank_registration as reg_mod

    cfg = ms.SystemConfig()
    u, v = np.nonzero(cfg.view_mask())
    window = _shifted_window(bank, torch.zeros(bank.shape[0], 2, dtype=torch.float64), s=30)
    gen = torch.Generator().manual_seed(2)
    wrong = 0.5 / 3.0 * torch.randn((bank.shape[0], 2), generator=gen, dtype=torch.float64)
    monkeypatch.setattr(reg_mod, "measure_shifts_torch", lambda *a, **k: wrong)
    reg = register_views(bank, window, 3, device="cpu", cfg=cfg, uv=list(zip(u, v, strict=True)))
    assert len(reg.explained) == 1 and reg.explained[0] < reg_mod.MIN_EXPLAINED
    assert len(reg.misfits) == 1  # no candidate was fitted
    assert torch.equal(reg.psf, bank) and float(reg.shifts.abs().sum()) == 0.0


def test_few_views_register_without_the_wavefront_fit(bank):
    # 9 views cannot fit 18 modes: the shifts are used as measured (no error)
    from metasensor.dao.bank_registration import MIN_FIT_VIEWS

    cfg = ms.SystemConfig()
    u, v = np.nonzero(cfg.view_mask())
    keep = np.argsort((u - 7) ** 2 + (v - 7) ** 2, kind="stable")[:9]
    assert keep.size < MIN_FIT_VIEWS
    sub = bank[torch.from_numpy(keep)]
    true = torch.tensor(np.stack([u[keep] - 7, v[keep] - 7], axis=1) * 0.3, dtype=torch.float64)
    window = _shifted_window(sub, true, s=30)
    reg = register_views(sub, window, 3, device="cpu", cfg=cfg,
                         uv=list(zip(u[keep], v[keep], strict=True)))
    assert reg.zernike is None and reg.explained == [] and reg.history[0] > 0.1
