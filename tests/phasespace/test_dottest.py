"""One dot-product test for every linear operator of the reconstruction: ⟨A x, y⟩ = ⟨x, Aᵀ y⟩.

Reference: exact adjoint pairs; tolerance 1e-7 of the Cauchy–Schwarz scale ``‖A x‖·‖y‖``
(float32 operators, float64 inner products). On these operators ``|⟨A x, y⟩|`` is about 1e-2 of
that scale, so the bound is the old 1e-5 relative to the inner product for a typical draw, without
its unlucky ones (measured: round-off 1e-11 to 2.7e-8 over eight seeds on one and two threads,
where the inner-product measure read up to 2.5e-5); a wrong adjoint reads 1.3e-2 to 4e-2.
"""

import math

import numpy as np
import pytest
import torch

from metasensor.phasespace.dottest import dot_test
from metasensor.phasespace.masked_normal import BandNormal, masked_normal
from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry
from metasensor.phasespace.space_variant import SpaceVariantOperator, corner_weights
from metasensor.solvers.krishnan_fergus import psf2otf
from metasensor.solvers.priors import GRADIENT, IDENTITY
from recon_standin import one_torch_thread  # noqa: F401


def _op(pad=True, d=3, window=(9, 8), v=7, k=11, seed=0):
    psf = np.random.default_rng(seed).random((v, k, k)).astype(np.float32)
    return PhaseSpaceOperator(psf, make_geometry(window, d, k // 2, pad=pad), device="cpu",
                              chunk=3)


def _rect_mask(op):
    mask = torch.zeros(op.geometry.grid, dtype=torch.bool)
    mask[op.geometry.sample_slices()] = True
    return mask


def _phasespace(pad, d):
    op = _op(pad=pad, d=d)
    return op.forward, op.adjoint, op.domain_shape, op.range_shape


def _normal():
    op = _op(pad=False)
    nm = op.normal()
    return nm.apply, nm.apply, op.domain_shape, op.domain_shape


def _band_normal():
    op = _op()
    band = masked_normal(op, op.normal(), _rect_mask(op), max_fraction=math.inf)
    assert isinstance(band, BandNormal)
    return band, band, op.domain_shape, op.domain_shape


def _masked_direct():
    op = _op()
    holed = _rect_mask(op)
    sy, sx = op.geometry.sample_slices()
    holed[sy.start + 1, sx.start + 2] = False
    direct = op.masked_normal(holed)
    return direct, direct, op.domain_shape, op.domain_shape


def _space_variant(normal: bool = False):
    g = make_geometry((9, 8), 3, 5)
    banks = [np.random.default_rng(s).random((7, 11, 11)).astype(np.float32) for s in range(4)]
    w = corner_weights(g, (0, 0), (3, 24, 3, 21))
    op = SpaceVariantOperator(banks, w, g, device="cpu", chunk=3)
    if not normal:
        return op.forward, op.adjoint, op.domain_shape, op.range_shape
    direct = op.masked_normal(_rect_mask(op))
    return direct, direct, op.domain_shape, op.domain_shape


def _gradient():
    return GRADIENT.forward, GRADIENT.adjoint, (3, 12, 10), (2, 3, 12, 10)


def _identity():
    return IDENTITY.forward, IDENTITY.adjoint, (12, 10), (12, 10)


def _convolution():
    # the single-kernel circular convolution of Krishnan-Fergus (psf2otf spectra)
    kernel = torch.from_numpy(np.random.default_rng(2).random((2, 7, 7)).astype(np.float32))
    otf = psf2otf(kernel, (20, 18))

    def forward(x):
        return torch.fft.irfft2(otf * torch.fft.rfft2(x), s=(20, 18))

    def adjoint(y):
        return torch.fft.irfft2(otf.conj() * torch.fft.rfft2(y), s=(20, 18))

    return forward, adjoint, (2, 20, 18), (2, 20, 18)


OPERATORS = {
    "phasespace padded d=3": lambda: _phasespace(True, 3),
    "phasespace circular d=3": lambda: _phasespace(False, 3),
    "phasespace padded d=1": lambda: _phasespace(True, 1),
    "phasespace padded d=5": lambda: _phasespace(True, 5),
    "folded normal": _normal,
    "band normal": _band_normal,
    "masked normal (direct)": _masked_direct,
    "space-variant phasespace": _space_variant,
    "space-variant masked normal": lambda: _space_variant(True),
    "gradient stencil": _gradient,
    "identity": _identity,
    "single-kernel convolution": _convolution,
}


@pytest.mark.parametrize("name", list(OPERATORS))
def test_every_operator_passes_the_dot_test(name):
    forward, adjoint, dom, rng_shape = OPERATORS[name]()
    for seed in (0, 1, 2, 3):
        assert dot_test(forward, adjoint, dom, rng_shape, seed=seed) < 1e-7


def test_dot_test_detects_a_wrong_adjoint():
    op = _op()
    for wrong in (lambda y: 2 * op.adjoint(y), lambda y: op.adjoint(y).flip(-1)):
        for seed in (0, 1):
            err = dot_test(op.forward, wrong, op.domain_shape, op.range_shape, seed=seed)
            assert err > 1e-2
    with pytest.raises(ValueError, match="shape"):
        dot_test(op.forward, op.adjoint, op.domain_shape, (1, 2, 3))


def test_operator_norm_is_the_largest_singular_value():
    # reference: the largest eigenvalue of the folded AᵀA (exact, per view frequency), sqrt;
    # power iteration from a seeded image, 1e-3 relative
    op = _op(pad=False)
    exact = math.sqrt(float(op.normal().eigenvalues().max()))
    assert op.norm(iterations=60) == pytest.approx(exact, rel=1e-3)
