"""The PSF bank's faster paths equal the plain computations they replace: the pupil FFT pruned
to the pupil's rows and the window's columns, the pupil sampled on its support only, and the
angular-spectrum propagation through scipy.fft on CPU (the band-limited bank's)."""

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.optics import psf as psf_mod
from metasensor.optics.coherent import (
    _centred_dft,
    plan_field,
    point_field,
    pupil_samples,
)
from metasensor.optics.pupil import disk_fraction, pupil_amplitude, pupil_grid, pupil_phase


def _full_centred_dft(p_full: torch.Tensor, n: int) -> torch.Tensor:
    m = p_full.shape[0]
    u = torch.fft.fftshift(torch.fft.fft2(torch.fft.ifftshift(p_full)))
    c, h = m // 2, n // 2
    return u[c - h:c + h + 1, c - h:c + h + 1]


@pytest.mark.parametrize("b, m, n", [(7, 31, 21), (31, 31, 31), (9, 45, 5), (5, 15, 15)])
def test_pruned_centred_dft_equals_the_full_transform(b, m, n):
    rng = np.random.default_rng(b + m + n)
    p = torch.as_tensor(rng.standard_normal((b, b)) + 1j * rng.standard_normal((b, b)))
    full = torch.zeros((m, m), dtype=p.dtype)
    c, h = m // 2, b // 2
    full[c - h:c + h + 1, c - h:c + h + 1] = p
    ref = _full_centred_dft(full, n)
    got = _centred_dft(p, n, m)
    assert got.shape == (n, n)
    assert torch.allclose(got, ref, rtol=0, atol=1e-12 * float(ref.abs().max()))


@pytest.mark.parametrize("method", ["fft", "mft"])
def test_point_field_from_the_pupil_support_equals_the_full_grid(method):
    cfg = ms.SystemConfig()
    z = np.zeros(11)
    z[3], z[4], z[7] = 0.8, -0.5, 0.3
    n, dx = 45, cfg.pixel_pitch / 3
    plan = plan_field(cfg, n, dx, grad_max=12.0, method=method)
    a, w, norm = pupil_samples(cfg, plan, z)
    assert a.shape[0] <= plan.pupil_n and a.shape[0] % 2 == 1
    got = point_field(cfg, plan, a, w, norm, n, dx, "cpu", dtype=torch.complex128)
    # the reference: the whole pupil_n² grid, as before the pupil was cut to its support
    m = plan.pupil_n
    rx, ry = pupil_grid(m, plan.radius)
    step = 1.0 / plan.radius
    af = pupil_amplitude(cfg, rx, ry, step)
    wf = np.where(af > 0, pupil_phase(cfg, rx, ry, z), 0.0)
    normf = float(np.sum(disk_fraction(rx, ry, step) ** 2))
    assert normf == pytest.approx(norm, rel=1e-12)
    assert np.sum(af**2) == pytest.approx(np.sum(a**2), rel=1e-12)
    if method == "fft":
        pf = torch.polar(torch.as_tensor(af), torch.as_tensor(2 * np.pi * wf))
        ref = _full_centred_dft(pf, n) / (m * np.sqrt(normf))
    else:
        ref = point_field(cfg, plan, af, wf, normf, n, dx, "cpu", dtype=torch.complex128)
    assert torch.allclose(got, ref, rtol=0, atol=1e-10 * float(ref.abs().max()))


def test_propagated_intensity_on_cpu_equals_torch_fft():
    rng = np.random.default_rng(3)
    n = 45
    u = torch.as_tensor((rng.standard_normal((4, n, n)) + 1j * rng.standard_normal((4, n, n)))
                        .astype(np.complex64))
    hz = torch.as_tensor(np.exp(2j * np.pi * rng.random((n, n))).astype(np.complex64))
    ref = torch.fft.ifft2(torch.fft.fft2(u) * hz).abs().square()
    for scipy_cpu in (True, False):
        got = psf_mod._propagated_intensity(u.clone(), hz, scipy_cpu=scipy_cpu)
        assert got.dtype == torch.float32 and got.shape == (4, n, n)
        assert torch.allclose(got, ref, rtol=0, atol=1e-5 * float(ref.max()))


def test_cache_counts_the_cpu_seconds_of_the_banks_it_computed(tmp_path):
    from metasensor.optics import cache as psf_cache

    cfg = ms.SystemConfig(nnum=3, mla_pitch=3 * 4.6e-6, mla_focal=3 * 46e-6, scan=3)
    stats = psf_cache.stats
    s0 = stats["compute_seconds"]
    psf_mod.view_psfs(cfg, [0, 0, 0, 0.4], size=9, subsample=3, cache=tmp_path)
    s1 = stats["compute_seconds"]
    assert s1 > s0
    psf_mod.view_psfs(cfg, [0, 0, 0, 0.4], size=9, subsample=3, cache=tmp_path)  # a hit
    assert stats["compute_seconds"] == s1


def test_banks_computed_at_once_count_their_cpu_seconds_once():
    """Two threads inside ``computing()`` at once: the CPU seconds added are the process's over
    that span, not each thread's view of the process's (which would count the span twice)."""
    import threading
    import time

    from metasensor.optics import cache as psf_cache

    def spin():
        with psf_cache.computing():
            t = time.process_time()
            while time.process_time() - t < 0.3:
                pass

    s0, p0 = psf_cache.stats["compute_seconds"], time.process_time()
    workers = [threading.Thread(target=spin) for _ in range(2)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    added, spent = psf_cache.stats["compute_seconds"] - s0, time.process_time() - p0
    assert 0.25 <= added <= spent + 1e-3


@pytest.mark.parametrize("z4, z7", [(0.0, 0.0), (0.6, 0.3)])
def test_band_limited_bank_equals_the_direct_one(z4, z7):
    """The bank from band_positions() positions per pitch, interpolated to the subsample-3 grid,
    against one propagation per output position (the residual: U0's light beyond its grid)."""
    from metasensor.optics import bank

    cfg = ms.SystemConfig(nnum=5, mla_pitch=23e-6, mla_focal=230e-6, scan=5)
    assert bank.band_positions(cfg) < 15  # the band-limited path is the one taken
    z = np.zeros(8)
    z[3], z[6] = z4, z7
    band = psf_mod.view_psfs(cfg, z, subsample=3, cache=False, band_limited=True)
    direct = psf_mod.view_psfs(cfg, z, subsample=3, cache=False)
    assert band.shape == direct.shape and band.dtype == np.float32
    assert np.abs(band - direct).max() <= 2e-4 * direct.max()
    assert band.sum() == pytest.approx(direct.sum(), rel=1e-5)
    with pytest.raises(TypeError, match="band_limited must be True or False"):
        psf_mod.view_psfs(cfg, z, subsample=3, cache=False, band_limited=1)


def test_band_positions_sample_the_intensity_band():
    from metasensor.optics.bank import band_positions

    cfg = ms.SystemConfig()
    nyquist = 4 * cfg.na * cfg.mla_pitch / cfg.wavelength  # 2 NA/λ, twice per cycle
    p = band_positions(cfg)
    assert p % 2 == 1 and nyquist < p <= 1.1 * nyquist + 2
