"""The learned denoiser: deterministic training and inference, and what the shipped weights do."""

import numpy as np
import pytest
import torch

from metasensor.priors.deadleaves import dead_leaves
from metasensor.priors.denoiser import CNNDenoiser, DnCNN, load_denoiser, save_weights
from metasensor.priors.training import train


def test_dead_leaves_are_seeded_and_in_range():
    a, b, c = dead_leaves(64, seed=3), dead_leaves(64, seed=3), dead_leaves(64, seed=4)
    assert a.dtype == np.float32 and a.shape == (64, 64)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert 0.0 <= a.min() and a.max() <= 1.0 and a.std() > 0.05
    with pytest.raises(ValueError, match="r_min"):
        dead_leaves(64, r_min=5, r_max=2)


def test_training_is_reproducible_and_leaves_torch_settings(tmp_path):
    threads = torch.get_num_threads()
    kw = dict(steps=3, images=4, size=32, batch=2, patch=16, depth=3, features=4, seed=7,
              log=lambda _: None)
    a, b = train(**kw), train(**kw)
    for (ka, va), (kb, vb) in zip(a.state_dict().items(), b.state_dict().items(), strict=True):
        assert ka == kb and torch.equal(va, vb)
    assert not torch.equal(a.state_dict()["body.0.weight"], DnCNN(3, 4).state_dict()
                           ["body.0.weight"])  # it trained
    assert torch.get_num_threads() == threads and not torch.are_deterministic_algorithms_enabled()
    save_weights(a, tmp_path / "w.npz")
    c = load_denoiser(tmp_path / "w.npz")
    x = torch.rand(1, 1, 20, 20)
    with torch.no_grad():
        assert torch.equal(a(x, torch.tensor([0.05])), c(x, torch.tensor([0.05])))


def test_shipped_denoiser_is_deterministic_and_denoises():
    den = CNNDenoiser()
    clean = dead_leaves(96, seed=123456789)  # not a training seed
    noisy = clean + np.random.default_rng(0).normal(0, 0.05, clean.shape).astype(np.float32)
    noisy_in = noisy.copy()
    out1, out2 = den.denoise(noisy, 0.05), den.denoise(noisy, 0.05)
    assert np.array_equal(out1, out2) and np.array_equal(noisy, noisy_in)
    assert out1.dtype == np.float32 and out1.shape == clean.shape
    gain = 10 * np.log10(np.mean((noisy - clean) ** 2) / np.mean((out1 - clean) ** 2))
    assert gain > 4.0
    # scale equivariance of the wrapper: an image in other units gives the same result scaled
    np.testing.assert_allclose(den.denoise(noisy * 300, 15.0, scale=300.0), out1 * 300,
                               rtol=1e-4, atol=1e-3)
    with pytest.raises(ValueError, match="sigma"):
        den.denoise(noisy, -1.0)
