"""The folded normal operator: AᵀA through per-frequency d² x d² matrices, and what it says about
the scan period (aliases vs views)."""

import numpy as np
import pytest
import torch

import metasensor as ms
from metasensor.phasespace import normal as normal_module
from metasensor.phasespace.normal import FoldedNormal
from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
from metasensor.solvers.tikhonov import difference_weights, tikhonov


def _normal(scan: int, side: int, pad: bool = False, zernike=None):
    cfg = ms.SystemConfig(scan=scan)
    psf = np.asarray(ms.view_psfs(cfg, zernike=zernike), np.float32)[cfg.view_mask()]
    g = make_geometry((side, side), cfg.scan_step_px, psf.shape[-1] // 2, pad=pad)
    op = PhaseSpaceOperator(psf, g, device="cpu")
    return op, FoldedNormal(op)


@pytest.fixture(scope="module")
def five():
    return _normal(5, 20)


def test_folded_matrix_equals_adjoint_of_forward(five):
    # G applied in the Fourier domain == op.adjoint(op.forward(x)) (float32: < 1e-5 relative;
    # measured 1.6e-7); on a padded domain too.
    op, nm = five
    x = torch.from_numpy(np.random.default_rng(0).random(op.geometry.domain, np.float32))
    ref = op.adjoint(op.forward(x))
    assert float((nm.apply(x) - ref).norm() / ref.norm()) < 1e-5
    op2, nm2 = _normal(5, 8, pad=True)
    x2 = torch.rand(op2.geometry.domain, generator=torch.Generator().manual_seed(1))
    ref2 = op2.adjoint(op2.forward(x2))
    assert float((nm2.apply(x2) - ref2).norm() / ref2.norm()) < 1e-5


def test_solve_inverts_the_regularised_system(five):
    # solve(factor(lam, R)) applied to (AᵀA + lam·scale·R) x returns x, identity R and the
    # smoothness weights, lam 1e-2: measured 1.0e-5 relative (the float32 right-hand side times
    # the condition number ~1e2), bound 1e-4. At lam 1e-4 it is as accurate as two triangular
    # solves with the Cholesky factor of every view frequency: against the float64 solve of the
    # same right-hand side both err by 4.97e-4 (the float32 right-hand side times the condition
    # number ~1e4; the solve 4.97486e-4, the triangular solves 4.97498e-4: the solve works on
    # the Hermitian half of the frequencies, its right-hand side made exactly Hermitian).
    op, nm = five
    x = torch.from_numpy(np.random.default_rng(2).random(op.geometry.domain, np.float32))
    scale = float(nm.matrix.diagonal(dim1=-2, dim2=-1).real.max())
    lap = torch.zeros(op.geometry.domain)
    lap[0, 0], lap[0, 1], lap[1, 0], lap[0, -1], lap[-1, 0] = 4.0 + 1e-3, -1, -1, -1, -1
    smooth = torch.fft.ifft2(torch.fft.fft2(x) * torch.fft.fft2(lap)).real
    for weights, rx in ((None, x), (difference_weights(nm), smooth)):
        rhs = nm.apply(x) + 1e-2 * scale * rx
        inv = nm.factor(1e-2, weights)
        my, mx = op.geometry.grid  # the view frequencies q < Mx//2+1: the rest conjugates
        assert inv.dtype == torch.complex128 and inv.shape == (my, mx // 2 + 1, 9, 9)
        assert float((nm.solve(rhs, inv) - x).norm() / x.norm()) < 1e-4
    rhs = nm.apply(x) + 1e-4 * scale * x
    chol = torch.linalg.cholesky(nm.matrix.to(torch.complex128)
                                 + 1e-4 * scale * torch.eye(9, dtype=torch.complex128))
    b = nm.fold(torch.fft.fft2(rhs)).to(torch.complex128).unsqueeze(-1)
    ref = torch.fft.ifft2(nm.unfold(torch.cholesky_solve(b, chol).squeeze(-1)
                                    .to(torch.complex64))).real
    b64 = nm.fold(torch.fft.fft2(rhs.double())).unsqueeze(-1)
    exact = torch.fft.ifft2(nm.unfold(torch.cholesky_solve(b64, chol).squeeze(-1))).real
    err = float((nm.solve(rhs, nm.factor(1e-4)).double() - exact).norm() / exact.norm())
    assert err <= float((ref.double() - exact).norm() / exact.norm()) * (1 + 1e-4)


def test_matrix_is_hermitian_positive_semidefinite(five):
    _, nm = five
    g = nm.matrix
    assert float((g - g.conj().transpose(-1, -2)).abs().max()) <= 1e-5 * float(g.abs().max())
    ev = nm.eigenvalues()
    assert float(ev.min()) >= -1e-5 * float(ev.max())


def test_scan_period_rank():
    # A 1x1 scan (d = 15) aliases 225 frequencies onto each view frequency but has 113 views:
    # at least 112 null directions per frequency (measured 137-138). A 5x5 scan (d = 3, 9
    # aliases) has none: smallest eigenvalue > 1e-7 of the largest (measured 1.4e-6).
    _, n1 = _normal(1, 4)
    ev1 = n1.eigenvalues()
    assert int((ev1 / ev1.max() < 1e-6).sum(-1).min()) >= 225 - 113
    _, n5 = _normal(5, 20)
    ev5 = n5.eigenvalues()
    assert float((ev5 / ev5.max()).min()) > 1e-7


def test_defocus_parallax_unmixes_the_aliases_of_a_5x5_scan(five):
    # On the MLA's conjugate plane every view samples the field at the same positions, so the 9
    # aliases of a 5x5 scan differ only through the views' PSF shapes: 70 % of AᵀA's eigenvalues
    # lie below 1e-4 of the largest (measured 0.700). A quarter wave r.m.s. of defocus (Z4) shifts
    # each view by its parallax, a different sampling phase per view, and that fraction falls to
    # 0.294 (0.1 λ: 0.437); the smallest eigenvalue rises 10x (1.4e-6 -> 1.5e-5). Much more
    # defocus blurs the views instead (1 λ: 0.727). bench_scan_period shows what this does to SSIM.
    def weak(nm):
        ev = nm.eigenvalues()
        r = ev / ev.max()
        return float((r < 1e-4).float().mean()), float(r.min())

    focus, focus_min = weak(five[1])
    off, off_min = weak(_normal(5, 20, zernike=[0.0, 0.0, 0.0, 0.25])[1])
    assert focus > 0.6 and off < 0.4
    assert off_min > 5 * focus_min


def test_noise_free_exact_recovery_at_5x5_not_at_1x1(five):
    # White-noise image (the hardest case), data y = A x on the circular domain: the regularised
    # least-squares solution recovers x to < 3 % (measured 1.2 %, float32 against eigenvalues of
    # 1e-6) at 5x5; at 1x1 the null space leaves an error > 50 % of |x|.
    op, nm = five
    x = torch.from_numpy(np.random.default_rng(2).random(op.geometry.domain, np.float32))
    full = torch.ones(op.geometry.grid, dtype=torch.bool)
    xr = tikhonov(nm, op.forward(x), full, 1e-8, smooth=False)
    assert float((xr - x).norm() / x.norm()) < 0.03
    op1, n1 = _normal(1, 4)
    x1 = torch.from_numpy(np.random.default_rng(3).random(op1.geometry.domain, np.float32))
    xr1 = tikhonov(n1, op1.forward(x1), torch.ones(op1.geometry.grid, dtype=torch.bool), 1e-7,
                   smooth=False)
    assert float((xr1 - x1).norm() / x1.norm()) > 0.5


def test_tikhonov_with_unobserved_margins_converges_to_masked_solution():
    # Padded domain, data only in the window: the completed-data iteration decreases the masked
    # residual and matches the window's data to < 5 % for a smooth image (noise-free).
    op, nm = _normal(5, 12, pad=True)
    g = op.geometry
    yy, xx = np.mgrid[:g.domain[0], :g.domain[1]]
    x = torch.from_numpy((1.5 + np.sin(yy / 7.0) * np.cos(xx / 5.0)).astype(np.float32))
    mask = torch.zeros(g.grid, dtype=torch.bool)
    mask[g.sample_slices()] = True
    y = op.forward(x) * mask
    res = []
    for outer in (1, 10):
        xr = tikhonov(nm, y, mask, 1e-6, outer=outer)
        res.append(float(((op.forward(xr) - y) * mask).norm() / y.norm()))
    assert res[1] < res[0] and res[1] < 0.05


def test_weights_and_bad_input(five):
    op, nm = five
    w = difference_weights(nm)
    assert w.shape == nm.matrix.shape[:-1] and float(w.min()) > 0
    with pytest.raises(ValueError, match="data must have shape"):
        tikhonov(nm, torch.zeros(3, 2, 2), torch.ones(2, 2, dtype=torch.bool), 1e-3)
    with pytest.raises(ValueError, match="lam must be > 0"):
        tikhonov(nm, torch.zeros(op.n_views, *op.geometry.grid),
                 torch.ones(op.geometry.grid, dtype=torch.bool), 0.0)
    # built from the operator's own bank (no second bank to mismatch): op.normal() is the same
    assert torch.equal(op.normal().matrix, nm.matrix)


def test_mask_shape_is_checked(five):
    op, nm = five
    with pytest.raises(ValueError, match="mask must have shape"):
        tikhonov(nm, torch.zeros(op.n_views, *op.geometry.grid), torch.ones(3, 3, dtype=torch.bool),
                 1e-3)


@pytest.mark.parametrize(("d", "grid"), [(3, (20, 31)), (3, (21, 30)), (5, (12, 13))])
def test_the_half_of_the_view_frequencies_gives_the_whole(d, grid):
    """G, AᵀA and the solves from the frequencies q < Mx//2+1 (the rest by conjugate symmetry)
    equal the direct products on every parity of the sample grid."""
    from metasensor.phasespace.operator import Geometry

    rng = np.random.default_rng(3)
    geometry = Geometry(grid, d, (0, 0), grid)
    op = PhaseSpaceOperator(rng.random((6, 5, 5), np.float32), geometry)
    nm = FoldedNormal(op)
    ny, nx = geometry.domain
    full = torch.fft.fft2(torch.roll(torch.nn.functional.pad(op.psf, (0, nx - 5, 0, ny - 5)),
                                     (-2, -2), (-2, -1)))
    h = nm.fold(full)
    direct = torch.einsum("vpqi,vpqj->pqij", h.conj(), h) / (d * d)
    assert float((nm.matrix - direct).abs().max()) <= 1e-6 * float(direct.abs().max())
    x = torch.from_numpy(rng.random(geometry.domain, np.float32)).to(op.device)
    ref = op.adjoint(op.forward(x))
    assert float((nm.apply(x) - ref).norm() / ref.norm()) < 1e-5
    assert float((nm.solve(nm.apply(x) + 1e-2 * nm.scale * x, nm.factor(1e-2)) - x).norm()
                 / x.norm()) < 1e-4


@pytest.mark.parametrize("scan, side, pad, slab", [(5, 20, False, None), (5, 9, True, None),
                                                   (3, 7, True, None), (5, 20, False, 1),
                                                   (3, 7, True, 1)])
def test_half_matrix_equals_the_fold_of_full_spectra(scan, side, pad, slab, monkeypatch):
    # G(p, q) = Σ_v h_vᴴ h_v / d² with h_v the view's full-spectrum OTF at the d² aliases of
    # (p, q): the build reads the aliases out of the half spectra (the others as conjugates),
    # a slab of frequency rows at a time (slab 1 byte: one row at a time); reference: full
    # FFTs of the zero-padded PSFs, folded (float32 sums: < 1e-5 relative).
    if slab is not None:
        monkeypatch.setattr(normal_module, "SLAB_BYTES", slab)
    op, nm = _normal(scan, side, pad)
    ny, nx = op.geometry.domain
    r = op.radius
    full = torch.zeros((op.n_views, ny, nx))
    full[:, :op.k, :op.k] = op.psf
    spec = torch.fft.fft2(torch.roll(full, shifts=(-r, -r), dims=(-2, -1)))
    h = nm.fold(spec)[:, :, :nm.half.shape[1]]
    ref = torch.einsum("vpqi,vpqj->pqij", h.conj(), h) / op.geometry.d ** 2
    assert float((nm.half - ref).abs().max() / ref.abs().max()) < 1e-5
