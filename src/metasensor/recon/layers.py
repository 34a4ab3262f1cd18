"""The depth-aware model of a block (``reconstruct(depth_layers="auto")``): one PSF bank per depth
layer, blended by the layers' soft masks inside the operator.

A block that holds two objects at different depths (a chart in focus and a card nearer the
camera) has two PSFs: every point is blurred by its own layer's. One bank per block (the
wavefront DAO estimates from all of the block's views, or the given aberration) is a compromise
between them, and deconvolution with it leaves both layers blurred. Here the block's views are
searched for two depth layers and, where they show them, each layer gets the block's wavefront
plus its own defocus, and the block is solved with the space-variant operator
(:class:`metasensor.phasespace.space_variant.SpaceVariantOperator`) whose weights are the
layers' smooth masks instead of field positions: ``A x = Σ_k A_k (w_k · x)``, ``Σ_k w_k = 1``,
so a point in layer k is blurred by bank k (the forward model of a scene of layers; the
simulator renders depth the same way).

1. :func:`find_layers`: the disparity of the block's window after removing the block's
   wavefront (:func:`metasensor.estimate_depth` with the wavefront's per-view shifts as its
   calibration, so the disparity left is each point's defocus relative to the wavefront),
   median-filtered; its confident values inside the block's region split in two by Otsu's
   threshold (Otsu, IEEE Trans. SMC 9, 62, 1979). Two layers when the halves' medians lie at
   least ``min_separation`` apart and each holds ``min_fraction`` of the values; else one
   layer, and the block is reconstructed exactly as without this model. Where they split,
   the layers are decided again on the block's one-bank reconstruction
   (:func:`metasensor.recon.layer_segments.segment_layers`: image segments with a clear
   confidence-weighted vote seed the layers, a random walker on the image labels the rest,
   so the split follows the image's edges), under the same two tests.
2. :func:`layer_zernikes`: the block's Noll vector plus the Noll-4 and Noll-11 projection of
   the angular-spectrum defocus (:func:`metasensor.optics.pupil.defocus_waves`) of each layer's
   image-side depth ``z = δ · d · mla_focal`` (:func:`metasensor.depth.geometry.
   disparity_to_image_depth`).
3. :func:`favour_sharper`: the layer whose wavefront is smaller (r.m.s. over Noll 4-45) grows
   by ``grow_samples`` view samples into the other (default none): where the split is
   uncertain at the border, a point deconvolved with a PSF narrower than its own comes out
   blurred, while one deconvolved with a wider PSF than its own rings; a split that follows
   the image's edges is better left as it is (docs/decisions.md, "the depth-aware block
   model" and "the depth-aware block model's layers decided on the image").
4. :func:`layer_weights`: each layer's indicator on the view grid, repeated onto the pixel grid,
   continued by its edge values over the operator's padded domain, feathered by a Gaussian and
   normalised to a partition of unity.
5. :func:`layers_fit_better`: the two-layer solve is kept only where its model explains the
   views of the layer it defocuses most (the larger disparity relative to the block's
   wavefront) better than the one-bank solve (the r.m.s. misfit over the views, over the
   layer's samples in the block's region); else the block keeps its one-bank image. A "layer"
   that is the disparity estimator's halo along a nearer object's border (the views there
   straddle the depth edge), not a depth of the scene, is given a defocus its points do not
   have, and its data are then fitted worse (model selection by the data misfit of the fitted
   models).

Hand-written (no library segments a light field's blocks into depth layers for a phase-space
operator); the disparity estimator and the operator are this package's.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from metasensor.config import SystemConfig

__all__ = ["DepthLayers", "LayerMap", "find_layers", "layer_zernikes", "favour_sharper",
           "layer_weights", "resolve_depth_layers", "layered_operator", "layers_fit_better"]


@dataclass(frozen=True)
class DepthLayers:
    """Settings of the depth-aware block model (frozen, validated).

    Attributes
    ----------
    min_separation : float
        Disparity between the two layers' medians (view pixels per view step) below which a
        block is one layer (default 0.25: 0.36 mm of image-side depth for the prototype,
        0.25 waves of defocus).
    min_fraction : float
        Share of the block's confident disparities each layer must hold (default 0.1).
    feather_px : float
        Standard deviation (image pixels) of the Gaussian that feathers the layer masks
        (default 0.5: the split follows the image's edges, so the masks stay nearly hard).
    median_samples : int
        Side (view samples, odd) of the median filter on the disparity (default 5).
    grow_samples : int
        View samples by which the sharper layer grows into the other (default 0: where the
        split follows the image's edges, a grown layer blurs the other's border).
    edge_samples : int
        View samples at the window's edges left out of the layer statistics (default 3: the
        disparity there sees past the window).
    segment_scale : float
        Scale of the Felzenszwalb segmentation of the block's one-bank image (normalised to
        [0, 1]) whose segments vote on the layers (default 100: larger, fewer and larger
        segments).
    seed_vote : float
        Confidence-weighted share of a segment's pixels that must read one layer's disparity
        for the segment to seed that layer (default 0.75; in (0.5, 1)); the random walker on
        the image labels the rest (:mod:`metasensor.recon.layer_segments`).
    misfit_ratio : float
        The two-layer solve is kept where, in the layer it defocuses most, its r.m.s. data
        misfit is at most this times the one-bank solve's (default 1.0;
        :func:`layers_fit_better`).
    """

    min_separation: float = 0.25
    min_fraction: float = 0.1
    feather_px: float = 0.5
    median_samples: int = 5
    grow_samples: int = 0
    edge_samples: int = 3
    segment_scale: float = 100.0
    seed_vote: float = 0.75
    misfit_ratio: float = 1.0

    def __post_init__(self) -> None:
        for name in ("min_separation", "feather_px", "segment_scale", "misfit_ratio"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, int | float) and math.isfinite(v)
                                           and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        f = self.min_fraction
        if isinstance(f, bool) or not (isinstance(f, int | float) and 0 < f < 0.5):
            raise ValueError(f"min_fraction must lie in (0, 0.5), got {f!r}")
        v = self.seed_vote
        if isinstance(v, bool) or not (isinstance(v, int | float) and 0.5 < v < 1):
            raise ValueError(f"seed_vote must lie in (0.5, 1), got {v!r}")
        m = self.median_samples
        if isinstance(m, bool) or not (isinstance(m, int) and m >= 1 and m % 2):
            raise ValueError(f"median_samples must be a positive odd integer, got {m!r}")
        for name in ("grow_samples", "edge_samples"):
            e = getattr(self, name)
            if isinstance(e, bool) or not (isinstance(e, int) and e >= 0):
                raise ValueError(f"{name} must be an integer >= 0, got {e!r}")


def resolve_depth_layers(value) -> DepthLayers | None:
    """``"off"`` → None, ``"auto"`` → ``DepthLayers()``, a :class:`DepthLayers` as given."""
    if isinstance(value, DepthLayers):
        return value
    if isinstance(value, str) and value in ("off", "auto"):
        return None if value == "off" else DepthLayers()
    raise ValueError(f"depth_layers must be 'off', 'auto' or DepthLayers, got {value!r}")


@dataclass(frozen=True)
class LayerMap:
    """Two depth layers of a block's window.

    disparity : (2,) float, each layer's median disparity relative to the block's wavefront
        (view pixels per view step; ascending: layer 1 is the nearer).
    labels : (h, w) uint8 on the window's view grid: 0 or 1.
    fraction : (2,) float, share of the region's confident disparities in each layer.
    """

    disparity: np.ndarray
    labels: np.ndarray
    fraction: np.ndarray


def _residual_disparity(window: np.ndarray, cfg: SystemConfig, zernike, device):
    """``estimate_depth`` of the window with the wavefront's per-view shifts removed."""
    from metasensor.dao.estimate import JMAX, gradient_shifts
    from metasensor.dao.wavefront import gradient_matrix
    from metasensor.depth.estimate import estimate_depth

    phi = np.zeros(JMAX)
    z = np.asarray(zernike, np.float64).ravel()[:JMAX]
    phi[:z.size] = z
    shifts = gradient_shifts(phi, gradient_matrix(cfg, jmax=JMAX))  # image pixels
    calibration = (shifts / cfg.scan_step_px).astype(np.float32)  # view pixels
    with warnings.catch_warnings():  # a small window's span warnings: the split decides
        warnings.simplefilter("ignore", RuntimeWarning)
        return estimate_depth(window, cfg, calibration=calibration, device=device)


def find_layers(window: np.ndarray, cfg: SystemConfig, zernike, region: tuple[slice, slice],
                settings: DepthLayers, device=None, guide: np.ndarray | None = None
                ) -> LayerMap | None:
    """Two depth layers of a block, or None (one layer).

    Parameters
    ----------
    window : numpy.ndarray
        ``(nnum, nnum, h, w)`` the block's views (scan-step grid).
    cfg : SystemConfig
    zernike : array_like
        The block's Noll vector (waves): DAO's estimate or the given aberration.
    region : (slice, slice)
        The block's region in the window's view samples (where the statistics are taken).
    settings : DepthLayers
    device : str, optional
    guide : numpy.ndarray, optional
        ``(h, w)`` the block's image on the view grid (its one-bank reconstruction pooled,
        :func:`metasensor.recon.layer_segments.pool_to_views`): where the pixels' split finds
        two layers, the layers are decided per segment of this image
        (:func:`metasensor.recon.layer_segments.segment_layers`). None: per pixel.

    Returns
    -------
    LayerMap or None
        None where the region's disparities do not split into two layers (module docstring).
    """
    from scipy.ndimage import median_filter
    from skimage.filters import threshold_otsu

    res = _residual_disparity(window, cfg, zernike, device)
    disp = median_filter(np.asarray(res.disparity, np.float64), settings.median_samples,
                         mode="nearest")
    use = np.zeros(disp.shape, bool)
    use[region] = True
    e = settings.edge_samples
    if e:
        use[:e] = use[-e:] = False
        use[:, :e] = use[:, -e:] = False
    valid = np.ones(disp.shape, bool) if res.valid is None else np.asarray(res.valid, bool)
    values = disp[use & valid]
    if values.size < 16 or np.ptp(values) < settings.min_separation:
        return None
    thr = float(threshold_otsu(values))
    low, high = values[values <= thr], values[values > thr]
    fraction = np.array([low.size, high.size], np.float64) / values.size
    medians = np.array([np.median(low), np.median(high)])
    if medians[1] - medians[0] < settings.min_separation or fraction.min() < settings.min_fraction:
        return None
    if guide is not None:
        from metasensor.recon.layer_segments import segment_layers

        return segment_layers(res.disparity, res.confidence, valid, guide, use, thr, settings)
    return LayerMap(disparity=medians, labels=(disp > thr).astype(np.uint8), fraction=fraction)


def layer_zernikes(cfg: SystemConfig, zernike, disparity) -> np.ndarray:
    """``(L, J)`` Noll vectors (waves): ``zernike`` plus the defocus of each layer's disparity
    (view pixels per view step) projected onto Noll 4 and 11 (module docstring)."""
    from metasensor.depth.geometry import disparity_to_image_depth
    from metasensor.optics.pupil import defocus_waves
    from metasensor.optics.zernike import fit_zernike

    z = np.asarray(zernike, np.float64).ravel()
    out = np.zeros((len(disparity), max(z.size, 11)))
    out[:, :z.size] = z
    t = np.linspace(-1.0, 1.0, 129)
    x, y = np.meshgrid(t, t)
    for k, dz in enumerate(disparity_to_image_depth(np.asarray(disparity, np.float64), cfg)):
        c = fit_zernike(defocus_waves(cfg, x, y, float(dz)), x, y, jmax=11, modes=(1, 4, 11))
        out[k, 3] += c[3]
        out[k, 10] += c[10]
    return out


def favour_sharper(labels: np.ndarray, zernikes: np.ndarray, grow: int) -> np.ndarray:
    """``labels`` (0/1) with the layer of the smaller wavefront (r.m.s. over Noll 4-45 of
    ``zernikes`` ``(2, J)``) grown by ``grow`` view samples (a square dilation)."""
    from scipy.ndimage import binary_dilation

    from metasensor.dao.wavefront import zernike_rms

    lab = np.asarray(labels).astype(bool)
    if grow <= 0:
        return lab.astype(np.uint8)
    sharp = int(np.argmin([zernike_rms(z) for z in zernikes]))
    mine = lab if sharp == 1 else ~lab
    grown = binary_dilation(mine, np.ones((2 * grow + 1,) * 2, bool))
    return (grown if sharp == 1 else ~grown).astype(np.uint8)


def layer_weights(labels: np.ndarray, geometry, feather_px: float) -> np.ndarray:
    """``(2, Ny, Nx)`` float32 soft masks of layers 0 and 1 on the operator's domain.

    ``labels`` ``(h, w)`` on the window's view grid (sample Y covers image pixels ``Y·d`` to
    ``Y·d + d − 1``), continued by its edge values beyond the window, Gaussian-feathered by
    ``feather_px`` pixels; non-negative, summing to 1 at every pixel."""
    from scipy.ndimage import gaussian_filter

    d = geometry.d
    lab = np.repeat(np.repeat(np.asarray(labels, np.float32), d, axis=0), d, axis=1)
    ny, nx = geometry.domain
    oy, ox = geometry.offset
    iy = np.clip(np.arange(ny) - oy, 0, lab.shape[0] - 1)
    ix = np.clip(np.arange(nx) - ox, 0, lab.shape[1] - 1)
    near = np.clip(gaussian_filter(lab[iy][:, ix], feather_px, mode="nearest"), 0.0, 1.0)
    return np.stack([1.0 - near, near]).astype(np.float32)


def layered_operator(task, window: np.ndarray, zernike, rows, cols, guide=None):
    """The block's two-layer operator and the layers' disparities, or None where the block is
    one layer (``task.layers``: :class:`DepthLayers`; ``zernike``: the block's Noll vector;
    ``guide``: the block's one-bank image on the view grid, :func:`find_layers`).
    Each layer's bank is ``task.psf_fn``'s or ``view_psfs``' of its Noll vector, in a window
    sized by its ray reach (:func:`metasensor.dao.banks.psf_window`)."""
    from metasensor.dao.banks import psf_window
    from metasensor.phasespace.operator import make_geometry
    from metasensor.phasespace.space_variant import SpaceVariantOperator, pad_banks
    from metasensor.recon.block import default_psfs

    d = task.cfg.scan_step_px
    region = task.block.region_samples(d)
    found = find_layers(window, task.cfg, zernike, region, task.layers, task.device,
                        guide)
    if found is None:
        return None
    zernikes = layer_zernikes(task.cfg, zernike, found.disparity)
    labels = favour_sharper(found.labels, zernikes, task.layers.grow_samples)
    banks = []
    for z in zernikes:
        bank = (task.psf_fn(task.cfg, z, task.device) if task.psf_fn is not None
                else default_psfs(task.cfg, z, task.device, size=psf_window(task.cfg, z)))
        banks.append(np.asarray(bank, np.float32)[rows, cols])
    banks = pad_banks(banks)
    geometry = make_geometry(window.shape[-2:], d, banks[0].shape[-1] // 2, pad=task.pad)
    weights = layer_weights(labels, geometry, task.layers.feather_px)
    return SpaceVariantOperator(banks, weights, geometry, device=task.device), found


def layers_fit_better(labels, region: tuple[slice, slice], one, two, disparity,
                      ratio: float = 1.0) -> bool:
    """Whether the two-layer model fits the data of the layer it defocuses most better than
    one bank.

    Parameters
    ----------
    labels : (h, w) array of 0/1
        The layers on the window's view grid (:class:`LayerMap`).
    region : (slice, slice)
        The block's region in the window's view samples (where the fits are compared).
    one, two : (h, w) float
        The r.m.s. misfit over the views at each view sample of the one-bank and the
        two-layer solves (:func:`metasensor.recon.block.misfit_map`).
    disparity : (2,) float
        The layers' disparities relative to the block's wavefront (:class:`LayerMap`): the
        layer of the larger magnitude is the one the model gives a defocus the one bank lacks.
    ratio : float
        The largest r.m.s. misfit of the two-layer fit in that layer, over the one-bank fit's.

    Returns
    -------
    bool
        True where that layer holds samples in the region and the two-layer fit's r.m.s.
        misfit over them is at most ``ratio`` times the one-bank fit's. The other layer is not
        compared: the one bank is (nearly) its own, and each solve's data weight follows its
        own fit's misfit over the whole block, so its misfit there moves either way.
    """
    k = int(np.argmax(np.abs(np.asarray(disparity, np.float64))))
    inside = (np.asarray(labels).astype(bool) == bool(k))[region]
    if not inside.any():
        return False
    one, two = np.asarray(one, np.float64)[region], np.asarray(two, np.float64)[region]
    return bool(np.sqrt(np.mean(two[inside] ** 2))
                <= ratio * np.sqrt(np.mean(one[inside] ** 2)))
