"""A small noise-level-conditioned CNN denoiser (DnCNN-like) and its shipped weights.

The network follows DnCNN (Zhang et al., IEEE TIP 2017: 3 × 3 convolutions, ReLU, residual
learning: it predicts the noise and subtracts it) with the noise level given as a second input
channel, a constant map of sigma, as in FFDNet (Zhang, Zuo & Zhang, IEEE TIP 2018), so one
network serves every noise level of a plug-and-play schedule (Zhang et al., "Plug-and-play image
restoration with deep denoiser prior", IEEE TPAMI 2022). It is trained on textured dead-leaves
images only (:mod:`metasensor.priors.deadleaves`) by ``scripts/train_denoiser.py``, with a fixed
seed; no natural photograph is in its training set. The weights ship as package data
(``metasensor/priors/data/denoiser.npz``, float32 NumPy arrays, no pickle).

The denoiser works on images in [0, 1] with additive white Gaussian noise of standard deviation
``sigma`` (same units); :meth:`CNNDenoiser.denoise` normalises other ranges by a given scale.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

__all__ = ["DnCNN", "CNNDenoiser", "WEIGHTS", "load_denoiser"]

WEIGHTS = "denoiser.npz"


class DnCNN(nn.Module):
    """DnCNN with a noise-level input channel: ``x − f([x, sigma])``.

    Parameters
    ----------
    depth : int
        Number of 3 × 3 convolution layers (>= 3).
    features : int
        Channels of the hidden layers.
    """

    def __init__(self, depth: int = 8, features: int = 32):
        super().__init__()
        if depth < 3 or features < 1:
            raise ValueError(f"need depth >= 3 and features >= 1, got {depth}, {features}")
        layers: list[nn.Module] = [nn.Conv2d(2, features, 3, padding=1), nn.ReLU()]
        for _ in range(depth - 2):
            layers += [nn.Conv2d(features, features, 3, padding=1), nn.ReLU()]
        layers.append(nn.Conv2d(features, 1, 3, padding=1))
        self.body = nn.Sequential(*layers)
        self.depth, self.features = int(depth), int(features)

    def forward(self, x: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        """x: (N, 1, H, W) noisy images in [0, 1]; sigma: (N,) noise r.m.s. -> denoised."""
        smap = sigma.reshape(-1, 1, 1, 1).to(x.dtype).expand_as(x)
        return x - self.body(torch.cat([x, smap], dim=1))


def save_weights(model: DnCNN, path: Path) -> None:
    """Write ``model``'s parameters as float32 arrays (``.npz``, no pickle) atomically
    (:func:`metasensor.io.weights.save_state`)."""
    from metasensor.io.weights import save_state

    save_state(model, path, depth=model.depth, features=model.features)


def load_denoiser(path: str | Path | None = None) -> DnCNN:
    """The network with weights from ``path`` (default: the shipped :data:`WEIGHTS`), in eval
    mode, float32, on the CPU."""
    from metasensor.io.weights import packaged_file, read_state

    if path is None:
        with packaged_file("metasensor.priors", WEIGHTS) as p:
            return load_denoiser(p)
    sizes, state = read_state(path)
    model = DnCNN(sizes["depth"], sizes["features"])
    model.load_state_dict(state)
    return model.eval().float()


class CNNDenoiser:
    """Callable wrapper of the shipped network: ``denoise(image, sigma)`` on tensors or arrays.

    Parameters
    ----------
    model : DnCNN, optional
        The network (default: :func:`load_denoiser`).
    device : str or torch.device, optional
        Where it runs (default CPU).
    """

    def __init__(self, model: DnCNN | None = None, device=None):
        self.device = torch.device(device or "cpu")
        self.model = (model or load_denoiser()).to(self.device)

    def denoise(self, image, sigma: float, scale: float = 1.0):
        """Denoise a 2-D image with white noise of r.m.s. ``sigma`` (same units as ``image``).

        ``scale`` maps the image to the network's [0, 1] range (``image / scale``); the result
        comes back in the input's units and type (tensor in, tensor out on the same device).
        """
        if not (np.isfinite(sigma) and sigma >= 0):
            raise ValueError(f"sigma must be a finite number >= 0, got {sigma!r}")
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"scale must be a positive number, got {scale!r}")
        is_tensor = isinstance(image, torch.Tensor)
        x = image if is_tensor else torch.as_tensor(np.asarray(image, np.float32))
        if x.ndim != 2:
            raise ValueError(f"image must be 2-D (H, W), got shape {tuple(x.shape)}")
        dev, dtype = x.device, x.dtype
        xin = (x.to(self.device, torch.float32) / scale)[None, None]
        with torch.no_grad():
            out = self.model(xin, torch.tensor([sigma / scale], device=self.device))[0, 0]
        out = (out * scale).to(dev, dtype)
        return out if is_tensor else out.numpy()
