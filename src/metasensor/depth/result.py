"""The result of :func:`metasensor.depth.estimate_depth`: disparity, confidence, validity and
metric depth on the view grid.

Disparity → image-side depth ``z = δ · d · mla_focal``; with the main-lens focal length and
focus distance, → object distance by the thin-lens equation (``metasensor.depth.geometry``
states the signs).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from metasensor.backend import to_numpy
from metasensor.config import SystemConfig
from metasensor.depth import geometry

__all__ = ["DepthResult", "depth_result"]


@dataclass(frozen=True)
class DepthResult:
    """Result of :func:`metasensor.depth.estimate_depth`; every map is ``(H, W)`` on the view
    grid.

    disparity : float32, view pixels per view step; view (u, v) content at
        ``p + disparity · (u − c, v − c)`` equals the centre view's at ``p``.
    confidence : float32 in [0, 1] (peak ratio of the cost curve that decided the pixel:
        window-aggregated or semi-global).
    image_depth : float32 metres, image-side depth ``z = disparity · d · mla_focal`` (``z > 0``:
        focused in front of the MLA, towards the main lens; d = nnum // scan).
    object_distance : float32 metres from the main lens (thin lens), or ``None`` without
        ``focal_length`` and ``focus_distance``; NaN where no real object maps there.
    depth : the metric depth of the public contract: ``object_distance`` when the main-lens
        geometry is known, else ``None`` (``image_depth`` is there either way);
        ``depth_kind`` says which metric maps exist (``"object"`` or ``"image"`` only).
    candidates : the candidate disparities of the plane sweep (view px per view step).
    valid : bool, pixels whose estimate the data support (confidence at least the fill
        threshold and not on an end of the span); elsewhere ``disparity`` is filled from the
        confident neighbours or kept as the sweep found it, and is a guess.
    span_source : ``"measured"`` (coarse wide search, :mod:`metasensor.depth.span`) or
        ``"given"``.
    saturated : shares (low end, high end) of the pixels whose cost still falls at an end of the
        final span (:func:`metasensor.depth.span.saturation`: the true disparity may lie
        beyond); for a given span, at least the shares of the coarse wide search's confident
        estimates below and above it.
    config : the system configuration used.
    views_used : bool ``(nnum, nnum)``, the views the estimate used, or None where not known.
    """

    disparity: np.ndarray
    confidence: np.ndarray
    image_depth: np.ndarray
    object_distance: np.ndarray | None
    depth: np.ndarray | None
    depth_kind: str
    candidates: np.ndarray
    config: SystemConfig
    valid: np.ndarray | None = None
    span_source: str = "given"
    saturated: tuple[float, float] = (0.0, 0.0)
    views_used: np.ndarray | None = None

    def __repr__(self) -> str:  # the maps by shape and dtype, not their values
        from metasensor.summary import short_repr

        return short_repr(self)


def depth_result(disp, conf, idx, fill_threshold: float, cands, cfg, lens, span_source,
                 sat, views_used=None) -> DepthResult:
    """The :class:`DepthResult` of the estimate.

    Parameters
    ----------
    disp, conf : torch.Tensor
        Final disparities [view px per view step] and confidences ``(H, W)``.
    idx : torch.Tensor
        The sweep's winning candidate per pixel (a pixel on an end of the span is not valid).
    fill_threshold : float
        The confidence a valid pixel has at least.
    cands : numpy.ndarray
        The candidate disparities of the last sweep.
    cfg : SystemConfig
        The system (image-side depth ``z = disparity · d · mla_focal``).
    lens : (float, float) or None
        Main-lens focal length and focus distance [m] (then the object distance by the thin
        lens), or None.
    span_source : str
        ``"given"`` or ``"measured"``.
    sat : (float, float)
        Saturated shares (low, high) of the span.
    views_used : numpy.ndarray, optional
        Boolean ``(nnum, nnum)`` mask of the views the estimate used.

    Returns
    -------
    DepthResult
        float32 maps on the view grid; ``object_distance`` and ``depth`` None without ``lens``.
    """
    ends = (idx == 0) | (idx == len(cands) - 1)
    valid = to_numpy((conf >= fill_threshold) & ~ends).astype(bool)
    disparity = to_numpy(disp).astype(np.float32)
    confidence = to_numpy(conf).astype(np.float32)
    z = geometry.disparity_to_image_depth(disparity, cfg).astype(np.float32)
    obj = None
    if lens is not None:
        obj = geometry.image_depth_to_object_distance(z, *lens).astype(np.float32)
    return DepthResult(
        disparity=disparity, confidence=confidence, image_depth=z, object_distance=obj,
        depth=obj, depth_kind="object" if obj is not None else "image",
        candidates=cands, config=cfg, valid=valid, span_source=span_source, saturated=sat,
        views_used=None if views_used is None else np.array(views_used, dtype=bool),
    )
