"""Disparity and depth from the views (multi-view stereo over the view grid).

Public: :func:`estimate_depth` and :class:`DepthResult` (``metasensor.depth.estimate``),
:class:`SemiGlobal` (its semi-global matching penalties), :class:`EdgeSnap` (its
re-decision of depth-edge pixels), :class:`EdgeRefiner` (its optional learned choice of their
layer), :class:`Speckles` (its removal of small isolated segments), :class:`Visibility` (its
re-decision of background pixels given an occluder's disparity); the geometry conversions
in ``metasensor.depth.geometry``; the aberration warp in ``metasensor.depth.aberration``;
geometric test scenes in ``metasensor.depth.synthetic``.
"""

from metasensor.depth.edges import EdgeSnap
from metasensor.depth.estimate import DepthResult, estimate_depth
from metasensor.depth.learned import EdgeRefiner
from metasensor.depth.sgm import SemiGlobal
from metasensor.depth.speckle import Speckles
from metasensor.depth.visibility import Visibility

__all__ = ["DepthResult", "EdgeRefiner", "EdgeSnap", "SemiGlobal", "Speckles", "Visibility",
           "estimate_depth"]
