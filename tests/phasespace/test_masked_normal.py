"""AᵀMA through the folded normal and two margin bands equals the direct product (exact)."""

import math

import numpy as np
import pytest
import torch

from metasensor.phasespace.masked_normal import BandNormal, masked_normal
from metasensor.phasespace.normal import FoldedNormal
from metasensor.phasespace.operator import PhaseSpaceOperator, make_geometry


def _problem(window=(20, 26), d=3, k=9, views=5, seed=0):
    rng = np.random.default_rng(seed)
    psf = rng.random((views, k, k)).astype(np.float32)
    psf /= psf.sum(axis=(1, 2), keepdims=True)
    geom = make_geometry(window, d, k // 2)
    op = PhaseSpaceOperator(psf, geom)
    _, mask = geom.embed(torch.zeros((views, *window)))
    return op, FoldedNormal(op), psf, mask


def _direct(op, mask, v):
    return op.adjoint(op.forward(v) * mask.to(op.device, torch.float32))


@pytest.mark.parametrize("window,d,k", [((20, 26), 3, 9), ((11, 9), 5, 13), ((30, 7), 3, 15)])
def test_band_normal_equals_direct_product(window, d, k):
    # float32 FFTs on both sides: relative difference at rounding level (tolerance 1e-5)
    op, nm, psf, mask = _problem(window, d, k)
    band = masked_normal(op, nm, mask, max_fraction=math.inf)
    assert isinstance(band, BandNormal)
    v = torch.randn(op.geometry.domain, generator=torch.Generator().manual_seed(1))
    ref = _direct(op, mask, v)
    got = band(v)
    assert float((got - ref).norm() / ref.norm()) < 1e-5


def test_band_normal_is_self_adjoint():
    # dot-product test <u, N v> = <N u, v>, relative tolerance 1e-5
    op, nm, psf, mask = _problem()
    band = masked_normal(op, nm, mask, max_fraction=math.inf)
    g = torch.Generator().manual_seed(2)
    u = torch.randn(op.geometry.domain, generator=g, dtype=torch.float32).to(op.device)
    v = torch.randn(op.geometry.domain, generator=g, dtype=torch.float32).to(op.device)
    a = float(torch.vdot(u.flatten(), band(v).flatten()))
    b = float(torch.vdot(band(u).flatten(), v.flatten()))
    assert abs(a - b) <= 1e-5 * max(abs(a), abs(b))


def test_masked_normal_falls_back_where_bands_do_not_pay():
    op, nm, psf, mask = _problem()
    v = torch.randn(op.geometry.domain, generator=torch.Generator().manual_seed(3))
    # bands over the allowed share of the domain: the direct product
    small = masked_normal(op, nm, mask, max_fraction=0.0)
    assert not isinstance(small, BandNormal)
    assert torch.allclose(small(v), _direct(op, mask, v), rtol=0, atol=1e-6)
    # a mask that is not one rectangle: the direct product
    holed = mask.clone()
    sy, sx = op.geometry.sample_slices()
    holed[sy.start + 2, sx.start + 3] = False
    fallback = masked_normal(op, nm, holed, max_fraction=math.inf)
    assert not isinstance(fallback, BandNormal)
    assert torch.allclose(fallback(v), _direct(op, holed, v), rtol=0, atol=1e-6)
    # everything observed: the circular normal operator itself
    full = torch.ones_like(mask)
    assert masked_normal(op, nm, full) == nm.apply


def test_band_normal_rejects_a_foreign_normal_operator():
    op, _, psf, mask = _problem()
    _, nm_other, _, _ = _problem(seed=1)
    with pytest.raises(ValueError, match="folded normal operator of op"):
        BandNormal(op, nm_other, (1, 3, 1, 3))
