"""Training of the learned edge refiner (:mod:`metasensor.depth.learned`,
``scripts/train_depth_refiner.py``).

Training scenes (:func:`training_scene`): random layered scenes rendered as
:func:`metasensor.depth.scenes.benchmark_scene` renders (scan 1, 5 x 5 or 9 x 9 views, additive
noise at 30-40 dB, disparities within ±3 view px per view step): a slanted textured background
and two to five objects in front of it, each a rotated ellipse, a rotated bar 1.2-5 view px
wide or a random polygon, at random places (every sub-pixel edge position), textured by
band-limited random noise of random grain, by textured dead leaves
(:func:`metasensor.priors.deadleaves.dead_leaves`: natural-image statistics without a
photograph) or by flat paint; photographs in front of a photograph
(:func:`photo_scene`, as :func:`metasensor.depth.scenes.natural_scene` builds them, but with
the bundled scikit-image photographs of ``TRAINING_PHOTOS``, none of which the evaluation
family ``natural_scene`` uses); plus the benchmark's own kinds at other seeds
and sizes (``TRAINING_KINDS``; the benchmark's evaluation scenes are seed 1 at 192 px and are
never used). Each scene is run through :func:`metasensor.estimate_depth` with the settings of
:data:`TRAINED_ON` (otherwise its defaults) but the refiner itself, and every two-layer
edge pixel of the result (as the estimator leaves it: before the refiner's own removal of weak
speckles, ``EdgeRefiner.clean``, which came after the shipped weights) whose coverage the views
measure gives a sample: its evidence
(:func:`metasensor.depth.edgefeatures.edge_samples`), whether the front's value is nearer the
truth than the background's, and as its weight what the wrong choice adds to the squared
error, ``|(front − t)² − (back − t)²|`` (the loss is then the expected squared error of the
choices, the benchmark's MSE, up to a constant).

Reproducible: fixed seeds, one CPU thread, deterministic algorithms; the same call on the same
PyTorch version gives the same weights. Optimiser: Adam (Kingma & Ba 2015), learning rate 2e-3
with cosine decay, binary cross-entropy, a random rotation / mirror of each batch.
"""

from __future__ import annotations

import time

import numpy as np
import torch

from metasensor.depth.edgefeatures import edge_samples
from metasensor.depth.learned import EdgeNet
from metasensor.depth.scenes import _render_grid, benchmark_scene, random_ramp
from metasensor.depth.synthetic import Layer, SyntheticViews, random_texture, render_views
from metasensor.priors.deadleaves import dead_leaves

__all__ = ["TRAINED_ON", "TRAINING_KINDS", "TRAINING_PHOTOS", "TRAINING_SCENES",
           "held_out_seeds", "photo_scene", "scene_record", "samples", "train",
           "training_scene", "training_specs", "validate"]

TRAINING_KINDS = ("occluders", "thin", "mixed")
TRAINING_SCENES = 150  # scenes of the shipped weights' training set (the script's default)
# bundled scikit-image photographs (nothing downloaded), none of them in scenes.PHOTOS
TRAINING_PHOTOS = ("grass", "coins", "moon", "hubble_deep_field", "immunohistochemistry",
                   "retina", "clock", "page")


def _shape_alpha(kind: str, shape, rng, d: int) -> np.ndarray:
    """Opacity of one random object on the image grid ``shape`` (``d`` image px per view px)."""
    from skimage.draw import polygon

    h, w = shape
    cy, cx = rng.uniform(0.1, 0.9) * h, rng.uniform(0.1, 0.9) * w
    yy, xx = np.mgrid[0:h, 0:w]
    ang = rng.uniform(0, np.pi) if rng.uniform() < 0.6 else rng.integers(0, 2) * np.pi / 2
    ca, sa = np.cos(ang), np.sin(ang)
    along = (xx - cx) * ca + (yy - cy) * sa
    across = -(xx - cx) * sa + (yy - cy) * ca
    if kind == "ellipse":
        a, b = rng.uniform(0.05, 0.25, 2) * min(h, w)
        return ((along / a) ** 2 + (across / b) ** 2 <= 1).astype(np.float64)
    if kind == "bar":
        half_w = 0.5 * rng.uniform(1.2, 5.0) * d
        half_l = 0.5 * rng.uniform(0.3, 0.9) * min(h, w)
        return ((np.abs(across) <= half_w) & (np.abs(along) <= half_l)).astype(np.float64)
    k = int(rng.integers(4, 9))
    t = np.sort(rng.uniform(0, 2 * np.pi, k))
    rad = rng.uniform(0.05, 0.25, k) * min(h, w)
    alpha = np.zeros(shape)
    rr, cc = polygon(cy + rad * np.sin(t), cx + rad * np.cos(t), shape)
    alpha[rr, cc] = 1.0
    return alpha


def training_scene(nnum: int = 9, size: int = 96, max_disparity: float = 3.0,
                   snr_db: float | None = 40.0, seed: int = 0) -> SyntheticViews:
    """One random training scene (module docstring); arguments and result as for
    :func:`metasensor.depth.scenes.benchmark_scene`."""
    cfg, d, shape = _render_grid(nnum, size, max_disparity)
    rng = np.random.default_rng(seed)
    span = float(max_disparity)

    def texture() -> np.ndarray:
        kind = rng.uniform()
        if kind < 0.1:
            return np.full(shape, rng.uniform(0.2, 0.9))
        if kind < 0.55:
            return random_texture(shape, seed=int(rng.integers(2**31)),
                                  scale_px=float(rng.uniform(1.0, 3.5) * d))
        leaves = dead_leaves(max(shape), seed=int(rng.integers(2**31)), r_min=0.5 * d,
                             r_max=float(rng.uniform(4, 16)) * d, leaves=2000)
        return 0.1 + 0.9 * leaves[:shape[0], :shape[1]].astype(np.float64)

    ramp = random_ramp(shape, rng)
    back = span * (rng.uniform(0.2, 0.8) + rng.uniform(0.0, 0.3) * ramp)
    layers = [Layer(np.ones(shape), back * d, texture())]
    count = int(rng.integers(2, 6))
    disparities = np.sort(rng.uniform(-1.0, 0.4, count))[::-1] * span
    for dv in disparities:
        kind = ("ellipse", "bar", "polygon")[int(rng.integers(3))]
        slant = rng.uniform(-0.1, 0.1) * span * ramp if rng.uniform() < 0.3 else 0.0
        layers.append(Layer(_shape_alpha(kind, shape, rng, d), (dv + slant) * d, texture()))
    return render_views(np.full(shape, 0.5), layers, cfg, snr_db=snr_db, seed=seed,
                        view_mask=np.ones((nnum, nnum), bool))


def photo_scene(nnum: int = 9, size: int = 96, max_disparity: float = 3.0,
                snr_db: float | None = 40.0, seed: int = 0) -> SyntheticViews:
    """Photographs in front of a photograph (module docstring): a slanted background and two to
    four objects (ellipses, bars, polygons as in :func:`training_scene`), each textured by a
    crop of one of :data:`TRAINING_PHOTOS`, at random disparities within ``±max_disparity``
    behind-to-front as :func:`metasensor.depth.scenes.natural_scene` draws them; arguments and
    result as for :func:`metasensor.depth.scenes.benchmark_scene`."""
    from metasensor.depth.scenes import _photo

    cfg, d, shape = _render_grid(nnum, size, max_disparity)
    rng = np.random.default_rng(seed)
    names = rng.permutation(TRAINING_PHOTOS)
    span = float(max_disparity)
    ramp = random_ramp(shape, rng)
    back = span * (rng.uniform(0.3, 0.8) + rng.uniform(0.0, 0.3) * ramp)
    layers = [Layer(np.ones(shape), back * d, _photo(names[0], shape, rng,
                                                     zoom=float(rng.uniform(1.0, 3.0))))]
    count = int(rng.integers(2, 5))
    for k, dv in enumerate(np.sort(rng.uniform(-1.0, 0.3, count))[::-1] * span):
        kind = ("ellipse", "bar", "polygon")[int(rng.integers(3))]
        tex = _photo(names[k + 1], shape, rng, zoom=float(rng.uniform(1.0, 3.0)))
        layers.append(Layer(_shape_alpha(kind, shape, rng, d), float(dv) * d, tex))
    return render_views(np.full(shape, 0.5), layers, cfg, snr_db=snr_db, seed=seed,
                        view_mask=np.ones((nnum, nnum), bool))


def training_specs(scenes: int, seed: int = 0) -> list[tuple]:
    """``scenes`` scene specifications ``(source, nnum, size, snr_db, scene seed)``: in turn a
    random scene (:func:`training_scene`), photographs (:func:`photo_scene`) and a benchmark
    kind at a seed >= 2 and a size other than 192 px; views per side, size and SNR alternate
    and vary."""
    rng = np.random.default_rng(seed)
    specs = []
    for i in range(scenes):
        nnum, snr = ((9, 40.0), (5, 30.0))[i % 2]
        snr = float(snr - rng.uniform(0, 4) if nnum == 9 else snr + rng.uniform(0, 4))
        s = int(seed * 10**6 + 2 + i)
        if i % 3 == 2:
            kind = TRAINING_KINDS[(i // 3) % len(TRAINING_KINDS)]
            specs.append((kind, nnum, int(rng.choice((96, 112, 128))), snr, s))
        elif i % 3 == 1:
            specs.append(("photo", nnum, int(rng.choice((96, 112, 128))), snr, s))
        else:
            specs.append(("random", nnum, int(rng.choice((80, 96, 112))), snr, s))
    return specs


def held_out_seeds(count: int, scenes: int = TRAINING_SCENES, seed: int = 0) -> tuple:
    """The first ``count`` scene seeds >= 2 at which no benchmark kind enters
    :func:`training_specs` ``(scenes, seed)``: seeds whose benchmark scenes
    (:func:`metasensor.depth.scenes.benchmark_scene`) are held out from the refiner's training
    at every size (seed 1 is the benchmark's own)."""
    used = {spec[4] for spec in training_specs(scenes, seed) if spec[0] in TRAINING_KINDS}
    out, s = [], 2
    while len(out) < count:
        if s not in used:
            out.append(s)
        s += 1
    return tuple(out)


def render_spec(spec) -> SyntheticViews:
    """The scene of one specification of :func:`training_specs`."""
    source, nnum, size, snr, s = spec
    if source == "random":
        return training_scene(nnum, size, 3.0, snr, s)
    if source == "photo":
        return photo_scene(nnum, size, 3.0, snr, s)
    return benchmark_scene(source, nnum, size, 3.0, snr, seed=s)


TRAINED_ON: dict = {}
"""Settings of :func:`metasensor.estimate_depth` that replace its defaults while the shipped
refiner's samples are collected: none (it was trained on the defaults' output, the maps it
sees at run time). Where a default changes later, its old value goes here, so that the training
script keeps reproducing the shipped weights until they are retrained."""


def scene_record(sv: SyntheticViews, estimator: dict | None = None):
    """Run the estimator (default settings but the learned refiner and the speckle removal
    after it, every view; ``estimator``: keyword settings of
    :func:`metasensor.estimate_depth` that replace its defaults, e.g. :data:`TRAINED_ON`) on
    ``sv``: ``(views (N, H, W) as the estimator normalises them, au, av, disparity,
    confidence)`` as tensors / arrays, what the refiner sees."""
    import warnings

    from metasensor.depth.estimate import _prepared_stack, estimate_depth

    n = sv.config.nnum
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = estimate_depth(sv.views, sv.config, view_mask=np.ones((n, n), bool), refiner=None,
                             speckles=None, **(estimator or {}))
    uu, vv = np.divmod(np.arange(n * n), n)
    stack = _prepared_stack(sv.views, uu, vv, None, True, torch.device("cpu"))
    stack -= stack.mean()
    c = n // 2
    return (stack, uu - c, vv - c, torch.from_numpy(res.disparity),
            torch.from_numpy(res.confidence))


def samples(record, truth: np.ndarray, jump: float = 1.5):
    """``(features (M, C, P, P) float16, label (M,) 1 = front, weight (M,))`` of one scene's
    edge pixels (module docstring); None without any."""
    stack, au, av, disp, conf = record
    s = edge_samples(stack, au, av, disp, conf, jump=jump)
    if s is None:
        return None
    t = torch.from_numpy(np.asarray(truth, np.float32))[s.ys, s.xs]
    gain = (s.back - t) ** 2 - (s.front - t) ** 2          # > 0: the front is the better choice
    return (s.features.numpy().astype(np.float16), (gain > 0).numpy().astype(np.float32),
            gain.abs().numpy().astype(np.float32))


def train(features: np.ndarray, labels: np.ndarray, weights: np.ndarray, steps: int = 8000,
          batch: int = 512, seed: int = 0, log=print, width: int = 32) -> EdgeNet:
    """Train an :class:`EdgeNet` on samples of :func:`samples` (module docstring: the
    cross-entropy of each sample weighted by ``weights``) on one thread with deterministic
    algorithms (the caller's settings and random state come back); ``width``: the network's
    convolution channels. Returns it in eval mode."""
    if not (len(features) == len(labels) == len(weights) > 0):
        raise ValueError(f"need as many labels and weights as samples (> 0), got "
                         f"{len(features)}, {len(labels)}, {len(weights)}")
    from metasensor.backend import reproducible

    with reproducible(seed):
        return _fit(features, labels, weights, steps, batch, seed, log, width)


def _fit(features, labels, weights, steps: int, batch: int, seed: int, log,
         width: int) -> EdgeNet:
    # the pixels the refiner acts on: coverage measured (samples of older collections may
    # hold others)
    c = features.shape[-1] // 2
    measured = np.asarray(features[:, 4, c, c]) > 0
    features, labels, weights = features[measured], labels[measured], weights[measured]
    rng = np.random.default_rng(seed)
    model = EdgeNet(features=width)
    x_all = torch.from_numpy(np.ascontiguousarray(features))
    y_all = torch.from_numpy(np.ascontiguousarray(labels, np.float32))
    w_all = torch.from_numpy(np.ascontiguousarray(weights, np.float32))
    w_all = w_all / w_all.mean()
    probe = x_all[torch.from_numpy(rng.integers(0, len(y_all), min(len(y_all), 20000)))].float()
    model.mean.copy_(probe.mean((0, 2, 3)))
    model.scale.copy_(probe.std((0, 2, 3)).clamp(min=1e-3))
    opt = torch.optim.Adam(model.parameters(), lr=2e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(steps, 1), eta_min=2e-5)
    loss_fn = torch.nn.BCEWithLogitsLoss(reduction="none")
    t0 = time.perf_counter()
    model.train()
    for step in range(steps):
        idx = torch.from_numpy(rng.integers(0, len(y_all), batch))
        x = x_all[idx].float()
        x = torch.rot90(x.flip(-1) if rng.uniform() < 0.5 else x, int(rng.integers(4)),
                        dims=(-2, -1))
        loss = (loss_fn(model(x), y_all[idx]) * w_all[idx]).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if log is not None and (step + 1) % max(1, steps // 10) == 0:
            log(f"step {step + 1}/{steps}: loss {float(loss.detach()):.4f} "
                f"({time.perf_counter() - t0:.0f} s)")
    return model.eval()


def validate(model: EdgeNet, specs, border: int = 10) -> list[tuple]:
    """``(spec, MSE x 100 without, with the refiner)`` per held-out scene specification (e.g.
    ``training_specs(n, seed + 1000)``), scored over the view minus ``border`` px."""
    from metasensor.depth.learned import EdgeRefiner, refine_edges

    rows = []
    for spec in specs:
        sv = render_spec(spec)
        record = scene_record(sv)
        new = refine_edges(*record, EdgeRefiner(), model=model)
        m = np.zeros(sv.disparity.shape, bool)
        m[border:-border, border:-border] = True
        before = 100 * float(np.mean((record[3].numpy()[m] - sv.disparity[m]) ** 2))
        after = 100 * float(np.mean((new.numpy()[m] - sv.disparity[m]) ** 2))
        rows.append((spec, before, after))
    return rows
