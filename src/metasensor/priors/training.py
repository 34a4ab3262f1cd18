"""Training of the shipped CNN denoiser on textured dead leaves (``scripts/train_denoiser.py``).

Reproducible: fixed seed, one CPU thread, deterministic algorithms; the same call on the same
PyTorch version gives the same weights. The training set is textured dead-leaves images only
(:func:`metasensor.priors.deadleaves.dead_leaves`, seeds ``seed·10⁶ + i``); natural photographs
(the evaluation scenes) are never seen. Noise: additive white Gaussian, sigma drawn per patch as
``SIGMA_MAX · u²`` (u uniform) on [0, 1] images, so small noise levels, where a plug-and-play
schedule ends, get most of the samples. Optimiser: Adam (Kingma & Ba 2015), learning rate 1e-3
with cosine decay to 1e-5, mean squared error.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from metasensor.priors.deadleaves import dead_leaves
from metasensor.priors.denoiser import DnCNN

__all__ = ["SIGMA_MAX", "make_set", "batches", "train", "validate"]

#: Largest training noise r.m.s. (images in [0, 1]).
SIGMA_MAX = 0.2


def make_set(count: int, size: int, seed: int) -> np.ndarray:
    """``count`` dead-leaves images (count, size, size), seeds ``seed·10⁶ + i``."""
    return np.stack([dead_leaves(size, seed=seed * 10**6 + i) for i in range(count)])


def batches(images: np.ndarray, steps: int, batch: int, patch: int, seed: int):
    """Random augmented patches with their noise levels and noise, fully determined by seed."""
    rng = np.random.default_rng(seed)
    n, size = images.shape[0], images.shape[1]
    for _ in range(steps):
        idx = rng.integers(0, n, batch)
        oy, ox = rng.integers(0, size - patch + 1, (2, batch))
        clean = np.stack([images[i, y:y + patch, x:x + patch]
                          for i, y, x in zip(idx, oy, ox, strict=True)])
        k = rng.integers(0, 4)
        clean = np.rot90(clean, k, axes=(1, 2))
        if rng.uniform() < 0.5:
            clean = clean[:, :, ::-1]
        sigma = (SIGMA_MAX * rng.uniform(size=batch) ** 2).astype(np.float32)
        noise = rng.standard_normal(clean.shape).astype(np.float32) * sigma[:, None, None]
        yield (torch.from_numpy(np.ascontiguousarray(clean))[:, None],
               torch.from_numpy(sigma), torch.from_numpy(noise)[:, None])


def train(steps: int = 800, images: int = 400, size: int = 96, batch: int = 16,
          patch: int = 40, depth: int = 8, features: int = 32, seed: int = 0,
          log=print) -> DnCNN:
    """Train a :class:`DnCNN` (module docstring) and return it in eval mode.

    Parameters
    ----------
    steps : int
        Optimiser steps.
    images, size : int
        Training images and their side [px].
    batch, patch : int
        Patches per step and their side [px] (``patch <= size``).
    depth, features : int
        The network's layers and channels (:class:`DnCNN`).
    seed : int
        Seed of the images, the patches, the noise and the initial weights.
    log : callable
        Receives a progress line every 100 steps.

    Returns
    -------
    DnCNN
    """
    from metasensor.backend import reproducible

    with reproducible(seed):  # the caller's settings come back
        return _fit(make_set(images, size, seed), steps, batch, patch, DnCNN(depth, features),
                    seed, log)


def _fit(data: np.ndarray, steps: int, batch: int, patch: int, model: DnCNN, seed: int,
         log) -> DnCNN:
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(steps, 1), eta_min=1e-5)
    t0, running = time.perf_counter(), 0.0
    for step, (clean, sigma, noise) in enumerate(batches(data, steps, batch, patch, seed + 1)):
        out = model(clean + noise, sigma)
        loss = torch.mean((out - clean) ** 2)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        running += loss.item()
        if (step + 1) % 100 == 0:
            log(f"step {step + 1}/{steps}  mse {running / 100:.3e}  "
                f"{time.perf_counter() - t0:.0f} s")
            running = 0.0
    return model.eval()


def validate(model: DnCNN, seed: int = 999, count: int = 16) -> dict:
    """PSNR gain on held-out dead leaves (seed not used in training) at a few noise levels."""
    data = torch.from_numpy(make_set(count, 96, seed))[:, None]
    gen = torch.Generator().manual_seed(seed)
    out = {}
    for sigma in (0.01, 0.03, 0.1):
        noisy = data + sigma * torch.randn(data.shape, generator=gen)
        with torch.no_grad():
            den = model(noisy, torch.full((count,), sigma))
        mse_in = float(torch.mean((noisy - data) ** 2))
        mse_out = float(torch.mean((den - data) ** 2))
        out[f"gain_db_sigma_{sigma}"] = 10 * np.log10(mse_in / mse_out)
    return out
