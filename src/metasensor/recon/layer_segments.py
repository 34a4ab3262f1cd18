"""The depth layers of a block decided by image segments (:func:`segment_layers`), not per pixel.

Behind a strong aberration the disparity of a block's views (its wavefront removed) is reliable
where the image has texture and a guess elsewhere: the flat parts of a nearer object read the
background's disparity, and a halo of wrong disparities surrounds its border, where the views
straddle a depth edge. An object's border is an edge of the image, though. So:

1. The block's reconstruction with one bank (its ``guide``, pooled onto the view grid,
   :func:`pool_to_views`) is cut into segments along its edges by Felzenszwalb and
   Huttenlocher's graph-based segmentation (:func:`skimage.segmentation.felzenszwalb`;
   Int. J. Comput. Vis. 59, 167, 2004).
2. Every segment votes as one (:func:`segment_votes`): the confidence-weighted share of its
   pixels whose disparity lies above the pixels' threshold (Otsu's over the block,
   :func:`metasensor.recon.layers.find_layers`).
3. Segments whose vote is clear (at least ``seed_vote`` one way or the other) seed their
   layer; the rest of the block (segments of mixed or no evidence) is labelled by the random
   walker on the guide (:func:`skimage.segmentation.random_walker`; Grady, IEEE Trans. PAMI
   28, 1768, 2006): a sample takes the layer a random walk from it most likely reaches first,
   the walk crossing the image's edges reluctantly, so a flat part of an object joins the
   object's textured part rather than the background across its border.
4. Each layer's disparity is the confidence-weighted median of its own pixels on its own side
   of the threshold (the pixels of a flat part that read the other layer's disparity are the
   guesses the image overruled).

Hand-written: the per-segment vote and its seeds (a few lines on scikit-image's segmentation
and random walker).
"""

from __future__ import annotations

import warnings

import numpy as np

__all__ = ["segment_layers", "segment_votes", "pool_to_views"]

SIGMA = 0.8  # Gaussian pre-smoothing of the guide (view samples) before the segmentation
MIN_SIZE = 8  # smallest segment (view samples)
MIN_VOTES = 3  # confident pixels a segment needs to vote
BETA = 130.0  # the random walker's edge penalty on the guide normalised to [0, 1] (its default)


def pool_to_views(image: np.ndarray, d: int) -> np.ndarray:
    """``(H, W)`` pixel-grid image → ``(H // d, W // d)`` means over each view sample's d x d
    pixels (sample Y covers pixels ``Y·d`` to ``Y·d + d − 1``)."""
    a = np.asarray(image, np.float64)
    h, w = a.shape[0] // d, a.shape[1] // d
    return a[:h * d, :w * d].reshape(h, d, w, d).mean(axis=(1, 3))


def _normalised(guide) -> np.ndarray:
    g = np.asarray(guide, np.float64)
    return (g - g.min()) / max(float(np.ptp(g)), 1e-12)


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, 0.5 * cum[-1])])


def segment_votes(side, weight, guide, scale: float) -> np.ndarray:
    """``(h, w)`` float: over each Felzenszwalb segment of ``guide`` (normalised to [0, 1],
    ``scale`` its scale), the ``weight``-weighted share of its pixels where ``side`` is True;
    NaN where a segment has fewer than :data:`MIN_VOTES` pixels of positive weight."""
    from skimage.segmentation import felzenszwalb

    seg = felzenszwalb(_normalised(guide), scale=scale, sigma=SIGMA, min_size=MIN_SIZE)
    w = np.asarray(weight, np.float64)
    side = np.asarray(side, bool)
    out = np.full(seg.shape, np.nan)
    for k in np.unique(seg):
        inside = seg == k
        if int((inside & (w > 0)).sum()) >= MIN_VOTES:
            out[inside] = float((w[inside] * side[inside]).sum() / w[inside].sum())
    return out


def segment_layers(disparity, confidence, valid, guide, use, threshold: float, settings):
    """Two layers of a block decided by the segments of ``guide`` (module docstring), or None.

    Parameters
    ----------
    disparity, confidence : (h, w) float
        The block window's disparity relative to its wavefront (view pixels per view step) and
        its confidence (:func:`metasensor.estimate_depth`).
    valid : (h, w) bool
        Where the disparity is supported by the data.
    guide : (h, w) float
        The block's image on the view grid (:func:`pool_to_views` of its one-bank
        reconstruction).
    use : (h, w) bool
        The samples the statistics are taken over (the block's region, edges left out).
    threshold : float
        The disparity that splits the layers (view pixels per view step).
    settings : DepthLayers
        ``segment_scale``, ``seed_vote``, ``min_separation``, ``min_fraction``.

    Returns
    -------
    LayerMap or None
        Layer 1 the higher disparity (the nearer); None where no segment clearly votes for one
        of the layers, or the layers fail ``min_separation`` or ``min_fraction``.
    """
    from skimage.segmentation import random_walker

    from metasensor.recon.layers import LayerMap

    disparity = np.asarray(disparity, np.float64)
    high = disparity > float(threshold)
    weight = np.where(valid, np.clip(confidence, 0.0, None), 0.0)
    votes = segment_votes(high, weight, guide, settings.segment_scale)
    seeds = np.zeros(high.shape, np.int32)
    seeds[np.isfinite(votes) & (votes >= settings.seed_vote)] = 2
    seeds[np.isfinite(votes) & (votes <= 1.0 - settings.seed_vote)] = 1
    if not ((seeds == 1).any() and (seeds == 2).any()):
        return None
    labels = seeds == 2
    if (seeds == 0).any():  # the walker labels what no clear vote seeded
        with warnings.catch_warnings():  # its probabilities' round-off beyond [0, 1]
            warnings.filterwarnings("ignore", "The probability range", UserWarning)
            labels = random_walker(_normalised(guide), seeds, beta=BETA, mode="cg_j") == 2
    inside = labels[use]
    if inside.size < 16:
        return None
    fraction = np.array([(~inside).sum(), inside.sum()], np.float64) / inside.size
    sides = [use & valid & ~labels & ~high, use & valid & labels & high]
    if min(int(s.sum()) for s in sides) < MIN_VOTES:
        return None
    w = weight + 1e-6
    medians = np.array([_weighted_median(disparity[s], w[s]) for s in sides])
    if medians[1] - medians[0] < settings.min_separation or fraction.min() < settings.min_fraction:
        return None
    return LayerMap(disparity=medians, labels=labels.astype(np.uint8), fraction=fraction)
