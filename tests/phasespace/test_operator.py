"""Phase-space forward operator: against direct convolution, adjoint (dot-product), geometry."""

import numpy as np
import pytest
import scipy.signal
import torch

from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry, smooth_size
from recon_standin import one_torch_thread  # noqa: F401


def _bank(rng, v=5, k=9):
    return rng.random((v, k, k)).astype(np.float32)


@pytest.mark.parametrize("d", [1, 3, 5])
def test_forward_equals_direct_linear_convolution(rng, d):
    # Reference: scipy's direct 2-D convolution (float64), sampled every d-th pixel of the domain.
    # Tolerance 1e-5 relative (float32 FFTs).
    psf = _bank(rng)
    g = make_geometry((7, 6), d, psf.shape[-1] // 2)
    op = PhaseSpaceOperator(psf, g, device="cpu")
    img = rng.random(g.domain).astype(np.float32)
    out = op.forward(torch.from_numpy(img)).double().numpy()
    sy, sx = g.sample_slices()
    for i, p in enumerate(psf):
        ref = scipy.signal.convolve2d(img.astype(np.float64), p.astype(np.float64), mode="same")
        ref = ref[::d, ::d]
        np.testing.assert_allclose(out[i, sy, sx], ref[sy, sx], rtol=0, atol=1e-5 * ref.max())


@pytest.mark.parametrize("pad", [True, False])
def test_adjoint_dot_product(rng, pad):
    # <A x, y> = <x, Aᵀ y>; relative error < 1e-5 (float32 operator, float64 inner products).
    psf = _bank(rng, v=7, k=11)
    g = make_geometry((9, 8), 3, 5, pad=pad)
    op = PhaseSpaceOperator(psf, g, device="cpu", chunk=3)
    x = rng.random(g.domain)
    y = rng.standard_normal((7, *g.grid))
    ax = op.forward(torch.tensor(x, dtype=torch.float32)).double().numpy()
    aty = op.adjoint(torch.tensor(y, dtype=torch.float32)).double().numpy()
    lhs, rhs = float((ax * y).sum()), float((x * aty).sum())
    assert abs(lhs - rhs) / abs(lhs) < 1e-5


def test_view_sample_sits_at_pixel_Yd_plus_half_d():
    # conventions.md: view sample (Y, X) of a window sits at window pixel (Y·d + d//2, X·d + d//2).
    # With a delta PSF, a point at that pixel shows up in sample (Y, X) only, with value 1.
    d = 3
    g = make_geometry((6, 5), d, 2)
    psf = np.zeros((1, 5, 5), np.float32)
    psf[0, 2, 2] = 1.0
    op = PhaseSpaceOperator(psf, g, device="cpu")
    window = np.zeros(g.pixels, np.float32)
    window[4 * d + d // 2, 2 * d + d // 2] = 1.0
    dom = np.zeros(g.domain, np.float32)
    oy, ox = g.offset
    dom[oy:oy + g.pixels[0], ox:ox + g.pixels[1]] = window
    out = op.forward(torch.from_numpy(dom))[0].numpy()
    sy, sx = g.sample_slices()
    samples = out[sy, sx]
    assert samples[4, 2] == pytest.approx(1.0, abs=1e-6)
    assert np.abs(samples).sum() == pytest.approx(1.0, abs=1e-5)
    # the crop of the domain returns the window pixels
    assert np.array_equal(g.crop(torch.from_numpy(dom)).numpy(), window)


def test_padding_prevents_wraparound(rng):
    # A bright point just outside the window's left edge must not appear at the right edge.
    d, k = 3, 9
    psf = np.ones((1, k, k), np.float32) / k**2
    g = make_geometry((10, 10), d, k // 2)
    op = PhaseSpaceOperator(psf, g, device="cpu")
    dom = np.zeros(g.domain, np.float32)
    oy, ox = g.offset
    dom[oy + 15, ox - 2] = 1.0
    out = op.forward(torch.from_numpy(dom))[0].numpy()
    sy, sx = g.sample_slices()
    assert out[sy, sx][:, -3:].max() < 1e-6
    assert out[sy, sx][:, 0].max() == pytest.approx(1 / k**2, rel=1e-4)


def test_smooth_size():
    assert smooth_size(97, 3) == 98  # 98 = 2·7², 294 = 2·3·7²
    assert smooth_size(1) == 1


def test_bad_psf_raises():
    g = make_geometry((4, 4), 3, 1)
    with pytest.raises(ValueError, match="psf must have shape"):
        PhaseSpaceOperator(np.ones((2, 4, 4)), g, device="cpu")
    bad = np.ones((1, 3, 3))
    bad[0, 1, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        PhaseSpaceOperator(bad, g, device="cpu")
    with pytest.raises(ValueError, match="window"):
        make_geometry((0, 4), 3, 1)


def test_embed_places_window_samples_and_mask(rng):
    # Geometry.embed puts window sample (i, j) at domain sample m0 + (i, j), zero elsewhere; the
    # mask is True exactly there; a sample stack of another shape is refused
    g = make_geometry((4, 5), 3, 7)
    s = torch.tensor(rng.random((2, 4, 5)), dtype=torch.float32) + 1.0
    data, mask = g.embed(s)
    sy, sx = g.sample_slices()
    assert data.shape == (2, *g.grid) and mask.shape == g.grid
    assert torch.equal(data[:, sy, sx], s)
    assert int(mask.sum()) == 20 and bool(mask[sy, sx].all())
    outside = data.clone()
    outside[:, sy, sx] = 0.0
    assert not bool(outside.any())
    with pytest.raises(ValueError, match="window"):
        g.embed(s[:, :3])


def test_dropped_spectra_are_remade_the_same_and_hqs_drops_them_after_its_set_up(rng):
    from metasensor.solvers.hqs import HQSOptions, hqs
    from metasensor.solvers.splitting import Continuation

    psf = _bank(rng, v=6, k=9)
    g = make_geometry((40, 44), 3, 4)
    op = PhaseSpaceOperator(psf, g, device="cpu")
    x = torch.from_numpy(rng.random(g.domain).astype(np.float32))
    before = op.forward(x)
    op.drop_spectra()
    assert op._otf is None
    torch.testing.assert_close(op.forward(x), before, rtol=0, atol=0)
    data, mask = g.embed(torch.from_numpy(rng.random((6, 40, 44)).astype(np.float32) + 1))
    opts = HQSOptions(continuation=Continuation(beta_max=4.0))
    first = hqs(op, data, mask, opts).estimate
    assert op._otf is None  # the loop applied the folded AᵀA and the bands only
    torch.testing.assert_close(hqs(op, data, mask, opts).estimate, first, rtol=0, atol=0)
    torch.testing.assert_close(op.forward(x), before, rtol=0, atol=0)
