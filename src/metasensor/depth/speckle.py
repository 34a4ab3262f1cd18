"""Removing speckles from a disparity map: small isolated segments whose disparity no neighbour
shares.

A plane sweep leaves a few pixels, alone or in twos and threes, far from every neighbour
(a wrong minimum where the views see a pixel half covered, or a background strip no view sees
clear); semi-global matching's peak filter (Hirschmüller, PAMI 2008, sec. 3.4) removes such
segments. Here: the map is split into segments of 4-connected pixels whose disparities differ
by at most ``step`` between neighbours (OpenCV's ``filterSpeckles``), segments of at most
``size`` pixels are speckles, and each speckle pixel takes the median of its non-speckle 3 x 3
neighbours (repeated inwards for pixels with none). So a speckle takes a value the map holds
next to it; a thin structure (a segment longer than ``size`` pixels) is kept. With
``Speckles.confidence`` set, only the speckle pixels that the estimator is unsure of (confidence
below it) are replaced; a confident lone pixel (e.g. of a thin bar the sweep found in pieces)
stays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

__all__ = ["Speckles", "remove_speckles", "speckle_mask"]

_SCALE = 1000.0  # disparity -> int16 for OpenCV (±32 view px per view step at 1e-3 steps)


@dataclass(frozen=True)
class Speckles:
    """Settings of :func:`remove_speckles`.

    size : largest segment removed [px].
    step : neighbours differing by at most this much belong to one segment [outermost-view
        px: the disparity step times the largest view offset].
    confidence : replace only speckle pixels whose confidence (in [0, 1]) is below this; None:
        every speckle pixel.
    """

    size: int = 4
    step: float = 0.75
    confidence: float | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.size, int) and 1 <= self.size <= 64):
            raise ValueError(f"size must be an integer in [1, 64], got {self.size!r}")
        if not (isinstance(self.step, int | float) and 0 < self.step < float("inf")):
            raise ValueError(f"step must be a positive number, got {self.step!r}")
        c = self.confidence
        if c is not None and not (isinstance(c, int | float) and 0 < c <= 1):
            raise ValueError(f"confidence must be a number in (0, 1] or None, got {c!r}")


def speckle_mask(disparity: torch.Tensor, amax: float,
                 options: Speckles = Speckles()) -> torch.Tensor | None:
    """The speckles of a map (module docstring; every small segment: ``options.confidence`` is
    applied by :func:`remove_speckles`): boolean ``(H, W)`` on the map's device, or None where
    the map is not finite or beyond the int16 range of OpenCV's segmentation.

    Parameters
    ----------
    disparity : ``(H, W)`` map [view px per view step] (not modified).
    amax : the largest view offset used, which converts ``options.step`` to disparity.
    options : :class:`Speckles`.
    """
    import cv2

    d = disparity.detach().cpu().numpy().astype(np.float64)
    limit = float(np.iinfo(np.int16).max - 1) / _SCALE
    if not np.isfinite(d).all() or np.abs(d).max() > limit:
        return None
    img = np.round(d * _SCALE).astype(np.int16)
    mark = np.iinfo(np.int16).min
    diff = max(1, int(round(options.step / max(amax, 1e-12) * _SCALE)))
    img, _ = cv2.filterSpeckles(img, mark, options.size, diff)
    return torch.from_numpy(img == mark).to(disparity.device)


def remove_speckles(disparity: torch.Tensor, amax: float,
                    options: Speckles = Speckles(),
                    confidence: torch.Tensor | None = None) -> torch.Tensor:
    """The map with its speckles replaced by their neighbours' median (module docstring).

    Parameters
    ----------
    disparity : ``(H, W)`` map [view px per view step] (not modified).
    amax : the largest view offset used (``max |u − c|, |v − c|``), which converts
        ``options.step`` to disparity.
    options : :class:`Speckles`.
    confidence : ``(H, W)`` confidence of the estimator in [0, 1]; needed where
        ``options.confidence`` is set (only speckle pixels below it are replaced).

    Returns
    -------
    torch.Tensor ``(H, W)``, the same dtype and device.
    """
    if options.confidence is not None and confidence is None:
        raise ValueError("Speckles.confidence is set: the estimator's confidence map is needed")
    speck = speckle_mask(disparity, amax, options)
    if speck is None:
        return disparity.clone()  # beyond int16 at this resolution: left as it is
    if options.confidence is not None:
        if tuple(confidence.shape) != tuple(disparity.shape):
            raise ValueError(f"confidence must have the map's shape {tuple(disparity.shape)}, "
                             f"got {tuple(confidence.shape)}")
        speck &= confidence.to(speck.device) < options.confidence
    out = disparity.clone()
    valid = ~speck
    for _ in range(options.size + 1):
        if bool(valid.all()):
            break
        nan = torch.full_like(out, float("nan"))
        pad = F.pad(torch.where(valid, out, nan)[None, None], (1, 1, 1, 1), mode="replicate")
        med = torch.nanmedian(F.unfold(pad, 3)[0], 0).values.reshape(out.shape)
        fill = ~valid & torch.isfinite(med)
        out = torch.where(fill, med, out)
        valid |= fill
    return out
