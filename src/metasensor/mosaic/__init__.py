"""Gigapixel mosaics with one lens (Extended Data Fig. 7 of the paper): tile layout in the lens's
field, sub-pixel registration of the tiles on their overlaps, blending into an OME-Zarr pyramid."""

from metasensor.mosaic.blend import blend_tiles, feather, open_mosaic
from metasensor.mosaic.layout import MosaicLayout
from metasensor.mosaic.register import PairOffset, register_pair, register_tiles, solve_positions

__all__ = ["MosaicLayout", "PairOffset", "register_pair", "register_tiles", "solve_positions",
           "blend_tiles", "feather", "open_mosaic"]
