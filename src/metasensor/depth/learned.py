"""A small learned re-decision of depth-edge pixels between their two candidate layers.

After the coverage re-decision (:mod:`metasensor.depth.edges`), every pixel of a two-layer depth
edge whose front coverage the views measure still has to be given one of two layers: the front
(the lowest disparity of its 3 x 3 neighbourhood) or the background (the highest); the truth is
the layer at the pixel centre. A tiny convolutional network (:class:`EdgeNet`: two valid 3 x 3
convolutions over a 7 x 7 patch of the evidence of :mod:`metasensor.depth.edgefeatures`, then
two fully connected layers; ReLU; about 23 k parameters, float32) gives the probability that the
pixel belongs to the front, averaged over the eight rotations and mirrors of its patch. A pixel
is moved to the other layer (the mean of its neighbours on that layer) only where that layer's
probability reaches ``EdgeRefiner.probability``, in ``EdgeRefiner.passes`` rounds (each on the
map the previous one left); it chooses between values the map already holds and never invents
a depth. On long straight edges the pixels of one run take the mean of their run's logits
(:func:`metasensor.depth.edgeruns.pool_along_runs`, ``EdgeRefiner.run_length``). Before the
first round the map's weak speckles are removed (``EdgeRefiner.clean``,
:func:`metasensor.depth.speckle.remove_speckles` restricted to pixels of low confidence): a lone
wrong pixel next to an edge sets its neighbours' candidate layers (the 3 x 3 lowest and highest
disparity) or, as a third value, keeps them out of the two-layer set.

The weights ship as package data (``metasensor/depth/data/edge_refiner.npz``, float32 NumPy
arrays, no pickle): two fits of the network on the same samples with other seeds
(:class:`EdgeEnsemble`, their probabilities averaged), trained by
``scripts/train_depth_refiner.py``
(:mod:`metasensor.depth.refiner_training`) on rendered scenes other than the benchmark's
evaluation scenes.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from metasensor.depth.edgefeatures import CHANNELS, PATCH, edge_samples
from metasensor.depth.edgeruns import pool_along_runs
from metasensor.depth.edges import two_layer_pixels
from metasensor.depth.speckle import Speckles, remove_speckles

__all__ = ["WEIGHTS", "EdgeEnsemble", "EdgeNet", "EdgeRefiner", "load_refiner", "refine_edges",
           "save_refiner"]

WEIGHTS = "edge_refiner.npz"


@dataclass(frozen=True)
class EdgeRefiner:
    """Settings of :func:`refine_edges`.

    probability : a pixel is moved to the other layer where the network gives that layer at
        least this probability (in [0.5, 1)).
    jump : smallest depth edge handled [outermost-view px], as :class:`EdgeSnap`'s.
    passes : rounds of choices (a pixel moved to the other layer changes its neighbours'
        evidence); each round re-reads the evidence of the map the previous one left.
    weights : path of a weights file (``.npz`` written by :func:`save_refiner`); None: the
        shipped :data:`WEIGHTS`.
    run_length : ``L`` of :func:`metasensor.depth.edgeruns.pool_along_runs`: samples on a
        straight run of the edge at least ``2 L + 1`` px long take the mean logit of the run
        within ``±2 L`` px; 0: every pixel decided on its own patch.
    clean : :class:`metasensor.depth.speckle.Speckles` of the speckles removed from the map
        before the first round (module docstring; by default only pixels of confidence below
        0.2), or None: the map as given.
    """

    probability: float = 0.5
    jump: float = 1.5
    passes: int = 2
    weights: str | None = None
    run_length: int = 24
    clean: Speckles | None = Speckles(confidence=0.2)

    def __post_init__(self) -> None:
        p = self.probability
        if not (isinstance(p, int | float) and 0.5 <= p < 1):
            raise ValueError(f"probability must be a number in [0.5, 1), got {p!r}")
        if not (isinstance(self.jump, int | float) and 0 < self.jump < float("inf")):
            raise ValueError(f"jump must be a positive number, got {self.jump!r}")
        if not (isinstance(self.passes, int) and 1 <= self.passes <= 8):
            raise ValueError(f"passes must be an integer in [1, 8], got {self.passes!r}")
        if not (isinstance(self.run_length, int) and 0 <= self.run_length <= 64):
            raise ValueError(f"run_length must be an integer in [0, 64], got {self.run_length!r}")
        if self.weights is not None and not isinstance(self.weights, str | Path):
            raise TypeError(f"weights must be a path or None, got {type(self.weights).__name__}")
        if self.clean is not None and not isinstance(self.clean, Speckles):
            raise TypeError(f"clean must be Speckles or None, got {type(self.clean).__name__}")


class EdgeNet(nn.Module):
    """``(M, CHANNELS, PATCH, PATCH)`` evidence -> ``(M,)`` logit of "the pixel is the front".

    The inputs are standardised by the per-channel ``mean`` / ``scale`` buffers (set from the
    training set) before two valid 3 x 3 convolutions (``features`` channels) and two fully
    connected layers.
    """

    def __init__(self, features: int = 32, hidden: int = 32):
        super().__init__()
        if features < 1 or hidden < 1:
            raise ValueError(f"need features >= 1 and hidden >= 1, got {features}, {hidden}")
        self.features, self.hidden = int(features), int(hidden)
        side = PATCH - 4
        self.body = nn.Sequential(
            nn.Conv2d(CHANNELS, features, 3), nn.ReLU(),
            nn.Conv2d(features, features, 3), nn.ReLU(), nn.Flatten(),
            nn.Linear(features * side * side, hidden), nn.ReLU(), nn.Linear(hidden, 1))
        self.register_buffer("mean", torch.zeros(CHANNELS))
        self.register_buffer("scale", torch.ones(CHANNELS))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = (x - self.mean[:, None, None]) / self.scale[:, None, None]
        return self.body(x)[:, 0]

    def probability(self, x: torch.Tensor) -> torch.Tensor:
        """Front probability averaged over the eight rotations and mirrors of the patches."""
        total = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
        for flip in (False, True):
            y = x.flip(-1) if flip else x
            for k in range(4):
                total += torch.sigmoid(self(torch.rot90(y, k, dims=(-2, -1))))
        return total / 8


class EdgeEnsemble(nn.Module):
    """Several :class:`EdgeNet` fits of the same samples (other seeds): their probabilities
    averaged, which removes part of the spread between equally good fits."""

    def __init__(self, members: list[EdgeNet]):
        super().__init__()
        if not members:
            raise ValueError("an ensemble needs at least one member")
        self.members = nn.ModuleList(members)
        self.features, self.hidden = members[0].features, members[0].hidden

    def probability(self, x: torch.Tensor) -> torch.Tensor:
        """The members' :meth:`EdgeNet.probability`, averaged."""
        return sum(m.probability(x) for m in self.members) / len(self.members)


def save_refiner(model: EdgeNet | EdgeEnsemble, path: Path) -> None:
    """Write ``model``'s parameters and buffers as float32 arrays (``.npz``, no pickle),
    atomically (:func:`metasensor.io.weights.save_state`)."""
    from metasensor.io.weights import save_state

    sizes = {"features": model.features, "hidden": model.hidden}
    if isinstance(model, EdgeEnsemble):
        sizes["members"] = len(model.members)
    save_state(model, path, **sizes)


_CACHE: dict[tuple[str, str], EdgeNet | EdgeEnsemble] = {}


def load_refiner(path: str | Path | None = None,
                 device: str | torch.device = "cpu") -> EdgeNet | EdgeEnsemble:
    """The network (or ensemble of networks) with the weights in ``path`` (default: the shipped
    :data:`WEIGHTS`), in eval mode, float32, on ``device`` (one cached copy per file and device;
    callers must not move it)."""
    from metasensor.io.weights import packaged_file, read_state

    if path is None:
        with packaged_file("metasensor.depth", WEIGHTS) as p:
            return load_refiner(p, device)
    key = (str(Path(path).resolve()), str(torch.device(device)))
    if key not in _CACHE:
        sizes, state = read_state(path)
        if "members" in sizes:
            model = EdgeEnsemble([EdgeNet(sizes["features"], sizes["hidden"])
                                  for _ in range(sizes["members"])])
        else:
            model = EdgeNet(sizes["features"], sizes["hidden"])
        model.load_state_dict(state)
        _CACHE[key] = model.eval().float().to(device)
    return _CACHE[key]


def refine_edges(views: torch.Tensor, au, av, disparity: torch.Tensor,
                 confidence: torch.Tensor, options: EdgeRefiner = EdgeRefiner(),
                 model: EdgeNet | EdgeEnsemble | None = None) -> torch.Tensor:
    """Give each two-layer depth-edge pixel the layer the network prefers (module docstring).

    Parameters
    ----------
    views : ``(N, H, W)`` float32 tensor, the views used (normalised as for the sweep).
    au, av : view offsets ``u − c``, ``v − c`` ``(N,)``, the centre view (0, 0) among them.
    disparity : ``(H, W)`` disparity map [view px per view step] (not modified).
    confidence : ``(H, W)`` confidence of the estimator in [0, 1].
    options : :class:`EdgeRefiner`.
    model : the network or ensemble (default: :func:`load_refiner` of ``options.weights``).

    Returns
    -------
    torch.Tensor ``(H, W)``: the disparity, edge pixels possibly moved to the mean of their
    neighbours on the other layer, weak speckles (``options.clean``) replaced by their
    neighbours' median; other pixels unchanged.
    """
    amax = float(max(np.abs(np.asarray(au)).max(), np.abs(np.asarray(av)).max()))
    if options.clean is not None:
        out = remove_speckles(disparity, amax, options.clean, confidence)
    else:
        out = disparity.clone()
    if model is None:
        net = load_refiner(options.weights, views.device)
    elif next(model.parameters()).device != views.device:
        net = copy.deepcopy(model).to(views.device)  # the caller's model is not moved
    else:
        net = model
    for _ in range(options.passes):
        samples = edge_samples(views, au, av, out, confidence, jump=options.jump)
        if samples is None:
            break
        with torch.no_grad():
            p = net.probability(samples.features).clamp(1e-6, 1 - 1e-6)
            if options.run_length > 0:
                _, lo, hi, _ = two_layer_pixels(out, options.jump, amax)
                logit = pool_along_runs(out, lo, hi, samples.ys, samples.xs,
                                        torch.log(p / (1 - p)), options.run_length,
                                        step=options.jump / (2 * amax))
                p = torch.sigmoid(logit)
        to_front = ~samples.on_front & (p >= options.probability)
        to_back = samples.on_front & (1 - p >= options.probability)
        if not bool((to_front | to_back).any()):
            break
        old = out[samples.ys, samples.xs]
        out[samples.ys, samples.xs] = torch.where(to_front, samples.front,
                                                  torch.where(to_back, samples.back, old))
    return out
