"""The learned denoiser as a plug-and-play prior of the HQS solvers."""

import numpy as np
import pytest
import torch

from metasensor.priors.denoiser import CNNDenoiser
from metasensor.priors.pnp import DenoiserPrior
from metasensor.solvers.priors import Identity, Prior


@pytest.fixture(scope="module")
def prior():
    return DenoiserPrior()


def test_prior_contract(prior):
    assert isinstance(prior, Prior) and isinstance(prior.transform, Identity)
    z = torch.from_numpy(np.random.default_rng(0).random((2, 24, 24)).astype(np.float32))
    keep = z.clone()
    a, b = prior.prox(z, 1e-3), prior.prox(z, 1e-3)
    assert a.shape == z.shape and a.dtype == z.dtype and a.device == z.device
    assert torch.equal(a, b) and torch.equal(z, keep)  # deterministic, input untouched
    den = CNNDenoiser()
    np.testing.assert_array_equal(a[1].numpy(), den.denoise(z[1].numpy(), np.sqrt(1e-3)))
    # noise levels beyond the trained range are clamped to it
    np.testing.assert_array_equal(prior.prox(z, 100.0)[0].numpy(),
                                  den.denoise(z[0].numpy(), prior.sigma_max))


def test_prior_options_are_checked():
    with pytest.raises(ValueError, match="strength"):
        DenoiserPrior(strength=0.0)
    with pytest.raises(ValueError, match="sigma_min"):
        DenoiserPrior(sigma_min=1.0)
    with pytest.raises(ValueError, match="weight"):
        DenoiserPrior().prox(torch.zeros(8, 8), -1.0)
