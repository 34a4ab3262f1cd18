"""Hard depth scenes with ground truth, in the manner of the 4D light-field benchmark (Honauer et
al., ACCV 2016): plain light-field cameras (``scan = 1``, 5 x 5 to 9 x 9 views), disparities of
several view pixels per view step, occluding textured objects, thin structures, textureless
patches and noise. Rendered by :func:`metasensor.depth.synthetic.render_views` (geometric
parallax, lenslet-aperture blur, "over" compositing), so the estimator never meets its own
discretisation.

Every disparity here is in VIEW pixels per view step (the unit of
:func:`metasensor.estimate_depth`); the layers are drawn ``d = nnum`` times finer.
"""

from __future__ import annotations

import numpy as np

from metasensor.config import SystemConfig
from metasensor.depth.synthetic import Layer, SyntheticViews, random_texture, render_views

__all__ = ["SCENES", "benchmark_scene", "natural_scene"]

SCENES = ("planes", "slanted", "occluders", "thin", "textureless", "mixed")


def _disc(shape, cy: float, cx: float, r: float) -> np.ndarray:
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    return (np.hypot(yy - cy, xx - cx) <= r).astype(np.float64)


def _box(shape, y0: float, y1: float, x0: float, x1: float) -> np.ndarray:
    a = np.zeros(shape)
    a[int(y0):int(y1), int(x0):int(x1)] = 1.0
    return a


def _layers(kind: str, shape, span: float, d: int, seed: int) -> list[Layer]:
    """Layers back to front; disparities in view px per view step (converted by the caller)."""
    h, w = shape
    rng = np.random.default_rng(seed)

    def tex(k: int) -> np.ndarray:
        return random_texture(shape, seed=seed * 31 + k, scale_px=float(rng.uniform(1.5, 3.0) * d))

    ramp_x = np.linspace(-1.0, 1.0, w)[None, :] * np.ones((h, 1))
    ramp_y = np.linspace(-1.0, 1.0, h)[:, None] * np.ones((1, w))
    if kind == "planes":
        return [Layer(np.ones(shape), 0.8 * span, tex(0)),
                Layer(_box(shape, h / 4, 3 * h / 4, w / 4, 3 * w / 4), -0.8 * span, tex(1))]
    if kind == "slanted":
        return [Layer(np.ones(shape), span * (0.9 * ramp_x + 0.1 * ramp_y), tex(0))]
    back = Layer(np.ones(shape), span * (0.6 + 0.3 * ramp_y), tex(0))
    if kind == "occluders":
        layers = [back]
        for k, (cy, cx, r, dv) in enumerate(((0.3, 0.3, 0.16, 0.1), (0.65, 0.6, 0.2, -0.4),
                                             (0.4, 0.7, 0.12, -1.0))):
            alpha = _disc(shape, cy * h, cx * w, r * min(h, w))
            layers.append(Layer(alpha, span * (dv + 0.1 * ramp_x), tex(k + 1)))
        return layers
    if kind == "thin":
        layers = [back]
        for k, x in enumerate(np.linspace(0.2, 0.8, 4)):
            width = (1.5 + k) * d  # 1.5 to 4.5 view px wide
            alpha = _box(shape, 0.1 * h, 0.9 * h, x * w - width / 2, x * w + width / 2)
            layers.append(Layer(alpha, -span * (0.9 - 0.3 * k), tex(k + 1)))
        alpha = _box(shape, 0.5 * h - 1.5 * d, 0.5 * h + 1.5 * d, 0.05 * w, 0.95 * w)
        layers.append(Layer(alpha, -span, tex(9)))
        return layers
    if kind == "textureless":
        flat = np.full(shape, 0.55)
        patch = _disc(shape, 0.35 * h, 0.35 * w, 0.12 * min(h, w))  # flat paint on the back
        obj = _box(shape, 0.55 * h, 0.8 * h, 0.5 * w, 0.8 * w)      # a textured object
        spot = _box(shape, 0.62 * h, 0.72 * h, 0.6 * w, 0.7 * w)    # with a flat spot
        obj_tex = np.where(spot > 0, 0.45, tex(2))
        return [back, Layer(patch, back.disparity, flat),
                Layer(obj, -0.7 * span, obj_tex)]
    if kind == "mixed":
        layers = [Layer(np.ones(shape), span * (0.7 - 0.3 * ramp_x), tex(0))]
        slab = _box(shape, 0.15 * h, 0.45 * h, 0.1 * w, 0.55 * w)
        layers.append(Layer(slab, span * (0.1 * ramp_x - 0.2 * ramp_y), tex(1)))
        layers.append(Layer(_disc(shape, 0.65 * h, 0.35 * w, 0.17 * min(h, w)), -0.5 * span,
                            tex(2)))
        layers.append(Layer(_box(shape, 0.05 * h, 0.95 * h, 0.72 * w - d, 0.72 * w + 1.5 * d),
                            -0.85 * span, tex(3)))
        layers.append(Layer(_disc(shape, 0.3 * h, 0.78 * w, 0.1 * min(h, w)), -span, tex(4)))
        return layers
    raise ValueError(f"scene must be one of {SCENES}, got {kind!r}")


def _render_grid(nnum, size, max_disparity):
    """Checked arguments of a rendered scene -> (config: scan 1, image pixels per view sample,
    image shape)."""
    if not (isinstance(nnum, int) and nnum % 2 == 1 and 5 <= nnum <= 15):
        raise ValueError(f"nnum must be an odd integer in [5, 15], got {nnum!r}")
    if not (isinstance(size, int) and size >= 32):
        raise ValueError(f"size must be an integer >= 32, got {size!r}")
    if not (np.isfinite(max_disparity) and max_disparity > 0):
        raise ValueError(f"max_disparity must be positive, got {max_disparity!r}")
    cfg = SystemConfig(nnum=nnum, scan=1)
    d = cfg.scan_step_px
    return cfg, d, (size * d, size * d)


def benchmark_scene(kind: str, nnum: int = 9, size: int = 128, max_disparity: float = 3.0,
                    snr_db: float | None = 40.0, seed: int = 0) -> SyntheticViews:
    """Render one hard scene for a plain light-field camera (``SystemConfig(nnum, scan=1)``).

    Parameters
    ----------
    kind : one of :data:`SCENES`: ``"planes"`` (two fronto-parallel planes), ``"slanted"`` (one
        slanted plane over the whole span), ``"occluders"`` (three textured discs in front of a
        slanted background), ``"thin"`` (bars 1.5-4.5 view px wide), ``"textureless"`` (flat
        patches on a textured background and object), ``"mixed"`` (all of them).
    nnum : views per side (odd, 5 to 15).
    size : view side [view px].
    max_disparity : the largest |disparity| in the scene [view px per view step].
    snr_db : additive Gaussian noise, signal power over noise power [dB]; None: none.
    seed : textures and noise.

    Returns
    -------
    SyntheticViews : views ``(nnum, nnum, size, size)`` (every view used: square pupil), their
    noise-free copy, and the true disparity ``(size, size)`` [view px per view step].
    """
    if kind not in SCENES:
        raise ValueError(f"scene must be one of {SCENES}, got {kind!r}")
    cfg, d, shape = _render_grid(nnum, size, max_disparity)
    layers = [Layer(lay.alpha, np.asarray(lay.disparity) * d if not np.isscalar(lay.disparity)
                    else float(lay.disparity) * d, lay.texture)
              for lay in _layers(kind, shape, float(max_disparity), d, seed)]
    return render_views(np.full(shape, 0.5), layers, cfg, snr_db=snr_db, seed=seed,
                        view_mask=np.ones((nnum, nnum), bool))


PHOTOS = ("camera", "astronaut", "coffee", "chelsea", "rocket", "brick", "gravel")


def _photo(name: str, shape, rng, zoom: float = 2.0) -> np.ndarray:
    """A grey scikit-image sample photograph (bundled, nothing downloaded), enlarged ``zoom``
    times, mirrored to fill ``shape`` from a random offset and scaled to [0.1, 1]."""
    import skimage.data
    from skimage.color import rgb2gray
    from skimage.transform import resize

    img = np.asarray(getattr(skimage.data, name)(), dtype=np.float64)
    img = rgb2gray(img) if img.ndim == 3 else img / 255.0
    img = resize(img, (int(zoom * img.shape[0]), int(zoom * img.shape[1])), order=3,
                 anti_aliasing=False)
    reps = (-(-shape[0] // img.shape[0]) + 1, -(-shape[1] // img.shape[1]) + 1)
    tiled = np.pad(img, ((0, (reps[0] - 1) * img.shape[0]), (0, (reps[1] - 1) * img.shape[1])),
                   mode="symmetric")
    y0 = int(rng.integers(0, tiled.shape[0] - shape[0] + 1))
    x0 = int(rng.integers(0, tiled.shape[1] - shape[1] + 1))
    out = tiled[y0:y0 + shape[0], x0:x0 + shape[1]]
    return 0.1 + 0.9 * (out - out.min()) / (np.ptp(out) + 1e-12)


def _polygon(shape, rng) -> np.ndarray:
    """Opacity of a random simple polygon (5 to 8 vertices at sorted random angles)."""
    from skimage.draw import polygon

    h, w = shape
    k = int(rng.integers(5, 9))
    ang = np.sort(rng.uniform(0, 2 * np.pi, k))
    rad = rng.uniform(0.08, 0.22, k) * min(h, w)
    cy, cx = rng.uniform(0.25, 0.75) * h, rng.uniform(0.25, 0.75) * w
    alpha = np.zeros(shape)
    rr, cc = polygon(cy + rad * np.sin(ang), cx + rad * np.cos(ang), shape)
    alpha[rr, cc] = 1.0
    return alpha


def random_ramp(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A unit-slope ramp over ``shape`` in a random direction (one draw of ``rng``): the
    normalised coordinate, -1 to 1 along the longer side, projected on that direction; the
    slant of a scene's background plane."""
    theta = rng.uniform(0, 2 * np.pi)
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]] / max(shape) * 2 - 1
    return np.cos(theta) * xx + np.sin(theta) * yy


def natural_scene(nnum: int = 9, size: int = 128, max_disparity: float = 3.0,
                  snr_db: float | None = 40.0, seed: int = 0) -> SyntheticViews:
    """Photographs in front of a photograph: a scene family unlike :data:`SCENES` (natural
    texture, polygons with edges at every angle), for checking that what was tuned on those
    scenes holds elsewhere.

    A slanted background (a crop of one of :data:`PHOTOS`) and three random polygons, each
    textured by another photograph, at random disparities within ``±max_disparity`` (the
    background behind them all); rendered as :func:`benchmark_scene` renders (``nnum`` x
    ``nnum`` views, scan 1, additive noise at ``snr_db``). Parameters and return value as for
    :func:`benchmark_scene`; ``seed`` picks the photographs, shapes, disparities and noise.
    """
    cfg, d, shape = _render_grid(nnum, size, max_disparity)
    rng = np.random.default_rng(seed)
    names = rng.permutation(PHOTOS)
    span = float(max_disparity)
    ramp = random_ramp(shape, rng)
    layers = [Layer(np.ones(shape), span * (0.6 + 0.3 * ramp) * d, _photo(names[0], shape, rng))]
    disparities = np.sort(rng.uniform(-1.0, 0.3, 3))[::-1] * span   # back to front
    for k, dv in enumerate(disparities):
        layers.append(Layer(_polygon(shape, rng), float(dv) * d, _photo(names[k + 1], shape,
                                                                        rng)))
    return render_views(np.full(shape, 0.5), layers, cfg, snr_db=snr_db, seed=seed,
                        view_mask=np.ones((nnum, nnum), bool))
