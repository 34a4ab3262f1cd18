"""Row-chunked MFT widefield PSF (bounded memory for strongly aberrated lenses)."""

import numpy as np
import pytest
import torch

import metasensor.optics.psf as psf_mod
import metasensor.optics.widefield as wf_mod
from metasensor.config import SystemConfig
from metasensor.optics.coherent import (
    binned_intensity_mft,
    plan_field,
    point_field,
    pupil_samples,
)

CFG = SystemConfig()


def test_chunked_intensity_equals_direct_field():
    # 303² grid, 3x3 bins, chunks of 48 rows: identical to |point_field|² binned (measured 1e-15)
    n, dx, k = 303, CFG.pixel_pitch / 9, 3
    z = np.zeros(12)
    z[4], z[7] = 0.8, 0.5
    plan = plan_field(CFG, n, dx, 20.0, method="mft")
    a, w, norm = pupil_samples(CFG, plan, z)
    u = point_field(CFG, plan, a, w, norm, n, dx, "cpu", dtype=torch.complex128)
    ref = psf_mod._bin(u.real.square() + u.imag.square(), k)
    got = binned_intensity_mft(CFG, plan, a, w, norm, n, dx, k, "cpu", rows=50)
    assert float((got - ref).abs().max() / ref.max()) < 1e-12
    with pytest.raises(ValueError, match="MFT plan"):
        binned_intensity_mft(CFG, plan_field(CFG, n, dx, 0.0, method="fft"), a, w, norm, n, dx,
                             k, "cpu")
    with pytest.raises(ValueError, match="multiple of the bin"):
        binned_intensity_mft(CFG, plan, a, w, norm, n, dx, 2, "cpu")


def test_widefield_psf_takes_the_chunked_path_above_the_memory_limit(monkeypatch):
    # With the limit lowered below this grid's size the result is unchanged (< 1e-6 relative)
    z = np.zeros(12)
    z[4] = 0.6
    ref = wf_mod.widefield_psf(CFG, z, size=41, cache=False)
    monkeypatch.setattr(wf_mod, "WIDEFIELD_FFT_BYTES", 1024)
    calls = []

    def spy(*args, **kw):
        calls.append(args[-2])
        return binned_intensity_mft(*args, **kw)

    monkeypatch.setattr(wf_mod, "binned_intensity_mft", spy)
    got = wf_mod.widefield_psf(CFG, z, size=41, cache=False)
    assert len(calls) == 1
    assert np.abs(got - ref).max() < 1e-6 * ref.max()
