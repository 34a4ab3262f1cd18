"""Dead-leaves images with textured leaves: the training scenes of the learned denoiser.

The dead-leaves model (Matheron 1968; Lee, Mumford & Huang, IJCV 2001) drops occluding disks
with a power-law radius distribution, ``p(r) ∝ r^-3`` between ``r_min`` and ``r_max``, which
gives scale-invariant statistics close to those of natural images. Plain dead leaves are
piecewise constant; following Achddou, Gousseau & Ladjal (J. Math. Imaging Vis. 2023, "Fully
synthetic training for image restoration tasks"), every leaf here carries a texture (a grating,
band-limited noise, or stripes) so that a denoiser trained on them keeps texture instead of
flattening it. Finally the image is blurred with a random Gaussian (sigma 0-1.5 px) with
probability 1/2, as optical images are.

Hand-written: no maintained library generates textured dead-leaves images.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["dead_leaves"]


def _texture(rng: np.random.Generator, yy: np.ndarray, xx: np.ndarray) -> np.ndarray:
    """A zero-mean texture on the pixel grid ``(yy, xx)`` (one of four kinds, amplitude ≤ 0.3)."""
    kind = rng.integers(4)
    amp = rng.uniform(0.02, 0.3)
    if kind == 0:
        return np.zeros_like(yy)
    theta = rng.uniform(0, math.pi)
    u = math.cos(theta) * xx + math.sin(theta) * yy
    if kind == 1:  # grating, period 2.2-24 px
        return amp * np.sin(2 * math.pi * u / rng.uniform(2.2, 24.0) + rng.uniform(0, 6.3))
    if kind == 2:  # stripes (square wave), period 3-20 px
        period = rng.uniform(3.0, 20.0)
        return amp * np.sign(np.sin(2 * math.pi * u / period + rng.uniform(0, 6.3)))
    # band-limited noise: white noise smoothed by a Gaussian of 0.5-3 px
    from scipy.ndimage import gaussian_filter

    noise = gaussian_filter(rng.standard_normal(yy.shape), rng.uniform(0.5, 3.0))
    return amp * noise / max(float(noise.std()), 1e-6)


def dead_leaves(size: int = 96, seed: int = 0, r_min: float = 1.5, r_max: float = 48.0,
                leaves: int = 400) -> np.ndarray:
    """One textured dead-leaves image (float32, shape ``(size, size)``, values in [0, 1]).

    Parameters
    ----------
    size : int
        Side [px], at least 8.
    seed : int
        Seed of all randomness (same seed, same image).
    r_min, r_max : float
        Radius range of the leaves [px], ``0 < r_min < r_max``; radii follow ``p(r) ∝ r^-3``.
    leaves : int
        Number of leaves dropped (later leaves lie under earlier ones: the first drops are on
        top), at least 1.

    Returns
    -------
    numpy.ndarray
        float32 image in [0, 1].
    """
    if int(size) < 8:
        raise ValueError(f"size must be at least 8 px, got {size!r}")
    if not (0 < r_min < r_max):
        raise ValueError(f"need 0 < r_min < r_max, got r_min={r_min!r}, r_max={r_max!r}")
    if int(leaves) < 1:
        raise ValueError(f"leaves must be >= 1, got {leaves!r}")
    size = int(size)
    rng = np.random.default_rng(seed)
    img = np.full((size, size), np.nan)
    # inverse-CDF sampling of p(r) ∝ r^-3 on [r_min, r_max]
    u = rng.uniform(size=int(leaves))
    a, b = r_min ** -2, r_max ** -2
    radii = (a - u * (a - b)) ** -0.5
    for r in radii:
        cy, cx = rng.uniform(-r, size + r, 2)
        y0, y1 = max(int(cy - r), 0), min(int(cy + r) + 2, size)
        x0, x1 = max(int(cx - r), 0), min(int(cx + r) + 2, size)
        if y0 >= y1 or x0 >= x1:
            rng.uniform(size=2)  # keep the stream aligned whatever the geometry
            continue
        yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
        inside = ((yy - cy) ** 2 + (xx - cx) ** 2 <= r * r) & np.isnan(img[y0:y1, x0:x1])
        value = rng.uniform(0.05, 0.95) + _texture(rng, yy, xx)
        patch = img[y0:y1, x0:x1]
        patch[inside] = value[inside]
        if not np.isnan(img).any():
            break
    img = np.where(np.isnan(img), rng.uniform(0.05, 0.95), img)
    if rng.uniform() < 0.5:
        from scipy.ndimage import gaussian_filter

        img = gaussian_filter(img, rng.uniform(0.0, 1.5), mode="reflect")
    return np.clip(img, 0.0, 1.0).astype(np.float32)
