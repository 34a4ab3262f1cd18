"""The prior seam of half-quadratic splitting: a new prior is one class with ``transform`` and
``prox(z, weight)``; the hyper-Laplacian prior is the built-in one."""

from dataclasses import dataclass

import numpy as np
import pytest
import torch

from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
from metasensor.solvers.hqs import REG_FLOOR, HQSOptions, hqs
from metasensor.solvers.hyper_laplacian import solve_w
from metasensor.solvers.priors import GRADIENT, IDENTITY, HyperLaplacian, Identity
from metasensor.solvers.splitting import Continuation
from recon_standin import one_torch_thread, standin_psfs  # noqa: F401


@dataclass(frozen=True)
class Tikhonov:
    """R(x) = (tau/2)·‖x‖² on the image: the whole of a test prior."""

    tau: float = 1.0
    transform: Identity = IDENTITY

    def prox(self, z, weight):
        return z / (1.0 + weight * self.tau)


def _problem():
    bank = standin_psfs(radius=6)
    mask = np.zeros((15, 15), bool)
    mask[4:11, 4:11] = True
    psf = bank[mask]
    g = make_geometry((16, 16), 3, psf.shape[-1] // 2, pad=False)
    op = PhaseSpaceOperator(psf, g, device="cpu")
    gen = torch.Generator().manual_seed(0)
    truth = 0.5 + 0.5 * torch.rand(g.domain, generator=gen)
    y = op.forward(truth)
    return op, y + 0.01 * float(y.mean()) * torch.randn(y.shape, generator=gen)


def test_a_tikhonov_prior_plugs_in_as_one_class():
    # At one fixed beta HQS converges to the joint minimiser of (λ/2)‖Ax − y‖² + R(w) +
    # (β/2)‖x − w‖² (+ the x-step's floor ε·μ‖x‖²), which for R = (τ/2)‖·‖² is the closed form
    # x = (AᵀA + μ(ε + τ/(τ+β)) I)⁻¹ Aᵀy, μ = β/λ (on the image normalised to mean 0.5).
    # 80 rounds contract the error by (β/(τ+β))^80 = 2^-80; tolerance 1e-4 of the image's range.
    op, y = _problem()
    full = torch.ones(op.geometry.grid, dtype=torch.bool)
    lam, tau, beta = 10.0, 1.0, 1.0
    options = HQSOptions(prior=Tikhonov(tau), lam=lam, inner=80,
                         continuation=Continuation(beta0=beta, beta_max=beta))
    x = hqs(op, y, full, options).estimate
    unit = 2.0 * float(y.sum()) / float(op.sensitivity(full.float()).sum())
    nm = op.normal()
    scale = float(nm.matrix.diagonal(dim1=-2, dim2=-1).real.max())
    mu = beta / lam
    inv = nm.factor(mu * (REG_FLOOR + tau / (tau + beta)) / scale)
    exact = torch.clamp(nm.solve(op.adjoint(y / unit), inv), min=0) * unit
    assert float((x - exact).abs().max()) < 1e-4 * float(exact.max() - exact.min())


def test_hyper_laplacian_prox_is_the_closed_form_w_step():
    # prox(z, 1/β) of Σ|w|^α = argmin |w|^α + (β/2)(w − z)² per element (solve_w), per component
    rng = np.random.default_rng(0)
    z = torch.from_numpy(rng.normal(0, 0.3, (2, 40, 30)))
    for alpha in (2 / 3, 1.0):
        prior = HyperLaplacian(alpha)
        assert prior.transform is GRADIENT
        got = prior.prox(z, 1 / 8.0)
        ref = solve_w(z, 8.0, alpha)
        assert float((got - ref).abs().max()) < 2e-4 * float(z.abs().max())
    with pytest.raises(ValueError, match="alpha"):
        HyperLaplacian(0.5)


def test_isotropic_prox_shrinks_the_gradient_magnitude_along_its_direction():
    # prox(z, 1/β) of Σ_p |∇x(p)|^α: alpha = 1 is the vector soft threshold exactly; 2/3 the
    # scalar closed form on |z(p)| with z(p)'s direction; both commute with rotations
    rng = np.random.default_rng(1)
    z = torch.from_numpy(rng.normal(0, 0.3, (2, 3, 40, 30)))  # a batch of three images
    rho = torch.sqrt(z[0] ** 2 + z[1] ** 2)
    tv = HyperLaplacian(1.0, isotropic=True).prox(z, 1 / 8.0)
    ref = z * torch.clamp(1 - 1 / (8.0 * rho), min=0)
    assert float((tv - ref).abs().max()) < 1e-12
    got = HyperLaplacian(isotropic=True).prox(z, 1 / 8.0)
    mag = torch.sqrt(got[0] ** 2 + got[1] ** 2)
    from metasensor.solvers.hyper_laplacian import _threshold_two_thirds

    vt = _threshold_two_thirds(8.0)
    for b in range(3):
        # the closed form jumps at the threshold: the table may put an element within one
        # table step of it on either side
        away = (rho[b] - vt).abs() > 2 * float(rho[b].max()) / (1 << 14)
        err = (mag[b] - solve_w(rho[b], 8.0, 2 / 3)).abs()[away]
        assert float(err.max()) < 2e-4 * float(rho[b].max())
    cross = got[0] * z[1] - got[1] * z[0]  # parallel to z
    assert float(cross.abs().max()) < 1e-9
    c, s_ = np.cos(0.6), np.sin(0.6)
    rot = torch.stack([c * z[0] - s_ * z[1], s_ * z[0] + c * z[1]])
    out = HyperLaplacian(isotropic=True).prox(rot, 1 / 8.0)
    back = torch.stack([c * got[0] - s_ * got[1], s_ * got[0] + c * got[1]])
    assert float((out - back).abs().max()) < 2e-3 * float(rho.max())
    aniso = HyperLaplacian().prox(rot, 1 / 8.0)
    assert float((aniso - back).abs().max()) > 0.05 * float(rho.max())  # it is not isotropic
    with pytest.raises(TypeError, match="isotropic"):
        HyperLaplacian(isotropic=1)


def test_solvers_default_to_the_isotropic_prior():
    from metasensor.solvers.krishnan_fergus import KFOptions

    assert HQSOptions().prior == HyperLaplacian(isotropic=True)
    assert KFOptions().isotropic is True


def test_options_refuse_what_is_not_a_prior():
    with pytest.raises(TypeError, match="prior"):
        HQSOptions(prior=object())
